//! One-shot command recording: record a closure into a fresh command buffer, submit it, wait.
//! Every pass in the CLI and the tests is a short batch of dispatches, so a transient pool per
//! submission is simpler than pooling, and costs microseconds.

use crate::error::{Result, VkContext};
use crate::gpu::context::Context;
use ash::vk;

/// Destroys the transient pool and fence however the submission ends.
struct Transient<'a> {
    ctx: &'a Context,
    pool: vk::CommandPool,
    fence: vk::Fence,
}

impl Drop for Transient<'_> {
    fn drop(&mut self) {
        unsafe {
            if self.fence != vk::Fence::null() {
                self.ctx.device.destroy_fence(self.fence, None);
            }
            // Destroying the pool frees its command buffers.
            self.ctx.device.destroy_command_pool(self.pool, None);
        }
    }
}

/// Records `record` into a new primary command buffer, submits it and waits for it to finish.
/// `what` names the work in error messages.
pub fn submit_once<R>(
    ctx: &Context,
    what: &str,
    record: impl FnOnce(vk::CommandBuffer) -> Result<R>,
) -> Result<R> {
    let pool_info = vk::CommandPoolCreateInfo::default()
        .queue_family_index(ctx.queue_family)
        .flags(vk::CommandPoolCreateFlags::TRANSIENT);
    let pool = unsafe { ctx.device.create_command_pool(&pool_info, None) }
        .vk(format!("creating a command pool for {what}"))?;
    let mut t = Transient {
        ctx,
        pool,
        fence: vk::Fence::null(),
    };
    let alloc = vk::CommandBufferAllocateInfo::default()
        .command_pool(pool)
        .level(vk::CommandBufferLevel::PRIMARY)
        .command_buffer_count(1);
    let cmd = unsafe { ctx.device.allocate_command_buffers(&alloc) }
        .vk(format!("allocating a command buffer for {what}"))?[0];
    ctx.set_name(cmd, what);
    let begin =
        vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
    unsafe { ctx.device.begin_command_buffer(cmd, &begin) }
        .vk(format!("beginning commands for {what}"))?;
    let out = record(cmd)?;
    unsafe { ctx.device.end_command_buffer(cmd) }.vk(format!("ending commands for {what}"))?;

    t.fence = unsafe {
        ctx.device
            .create_fence(&vk::FenceCreateInfo::default(), None)
    }
    .vk("creating a fence")?;
    let cmd_infos = [vk::CommandBufferSubmitInfo::default().command_buffer(cmd)];
    let submit = [vk::SubmitInfo2::default().command_buffer_infos(&cmd_infos)];
    {
        let queue = ctx.queue();
        unsafe { ctx.device.queue_submit2(*queue, &submit, t.fence) }
            .vk(format!("submitting {what}"))?;
    }
    unsafe { ctx.device.wait_for_fences(&[t.fence], true, u64::MAX) }
        .vk(format!("waiting for {what}"))?;
    Ok(out)
}

/// Records a global memory barrier from `prev` to `next` (the barrier table decides stages and
/// access masks); used for buffers, which do not track their accesses like images do.
pub fn memory_transition(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    prev: crate::gpu::Access,
    next: crate::gpu::Access,
) {
    if let Some(b) = crate::gpu::barrier::memory_barrier(prev, next) {
        unsafe {
            ctx.device
                .cmd_pipeline_barrier2(cmd, &vk::DependencyInfo::default().memory_barriers(&[b]))
        };
    }
}
