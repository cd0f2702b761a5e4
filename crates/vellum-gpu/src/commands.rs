//! Small command helpers. One-shot submission lives in `gpu/frame.rs` (`submit_once`), built on
//! the same frame type as frames in flight.

use crate::context::Context;
use ash::vk;

/// Records a global memory barrier from `prev` to `next` (the barrier table decides stages and
/// access masks); used for buffers, which do not track their accesses like images do.
pub fn memory_transition(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    prev: crate::Access,
    next: crate::Access,
) {
    if let Some(b) = crate::barrier::memory_barrier(prev, next) {
        unsafe {
            ctx.device
                .cmd_pipeline_barrier2(cmd, &vk::DependencyInfo::default().memory_barriers(&[b]))
        };
    }
}
