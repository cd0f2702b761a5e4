//! Small command helpers, so that the layers above record transfers and draws without naming
//! Vulkan's structures. One-shot submission lives in `frame.rs` (`submit_once`), built on the
//! same frame type as frames in flight.

use crate::context::Context;
use crate::resources::{Buffer, Image};
use crate::Access;
use crate::VkContext;
use ash::vk;
use std::sync::Arc;
use vellum_error::Result;

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

/// Records a clear of `image` to zero (leaves it in TransferWrite).
pub fn clear_image(ctx: &Context, cmd: vk::CommandBuffer, image: &Image) {
    image.discard();
    image.transition(cmd, Access::TransferWrite);
    let range = vk::ImageSubresourceRange {
        aspect_mask: image.aspect(),
        base_mip_level: 0,
        level_count: 1,
        base_array_layer: 0,
        layer_count: 1,
    };
    unsafe {
        ctx.device.cmd_clear_color_image(
            cmd,
            image.raw,
            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
            &vk::ClearColorValue { float32: [0.0; 4] },
            &[range],
        );
    }
}

/// Records a whole-image copy of `src` into `dst` (same extent and format): the bandwidth reference.
pub fn copy_image(ctx: &Context, cmd: vk::CommandBuffer, src: &Image, dst: &Image) {
    src.transition(cmd, Access::TransferRead);
    dst.discard();
    dst.transition(cmd, Access::TransferWrite);
    let [w, h, d] = src.desc.extent;
    let layers = vk::ImageSubresourceLayers {
        aspect_mask: src.aspect(),
        mip_level: 0,
        base_array_layer: 0,
        layer_count: 1,
    };
    let region = vk::ImageCopy::default()
        .src_subresource(layers)
        .dst_subresource(layers)
        .extent(vk::Extent3D {
            width: w,
            height: h,
            depth: d,
        });
    unsafe {
        ctx.device.cmd_copy_image(
            cmd,
            src.raw,
            vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
            dst.raw,
            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
            &[region],
        );
    }
}

/// Records a copy of the first `size` bytes of `src` into the start of `dst`.
pub fn copy_buffer(ctx: &Context, cmd: vk::CommandBuffer, src: &Buffer, dst: &Buffer, size: u64) {
    let region = vk::BufferCopy::default().size(size);
    unsafe {
        ctx.device
            .cmd_copy_buffer(cmd, src.raw, dst.raw, std::slice::from_ref(&region))
    };
}

/// Records a copy of `src` (a slice of a staging buffer) into the start of `dst`; the caller
/// orders it with [`memory_transition`].
pub fn copy_slice_to_buffer(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    src: &crate::resources::BufferSlice,
    dst: &Buffer,
) {
    let region = vk::BufferCopy::default()
        .src_offset(src.offset)
        .size(src.size.min(dst.size));
    unsafe {
        ctx.device
            .cmd_copy_buffer(cmd, src.raw, dst.raw, std::slice::from_ref(&region))
    };
}

/// Records copies of parts of `src` (a slice of a staging buffer) into `dst`: per region,
/// `size` bytes from `from` bytes into the slice to `to` bytes into `dst`. A region that lies
/// outside either is refused, and nothing is recorded; the caller orders the copies with
/// [`memory_transition`].
pub fn copy_slice_regions(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    src: &crate::resources::BufferSlice,
    dst: &Buffer,
    regions: &[CopyRegion],
) -> Result<()> {
    let outside = |r: &&CopyRegion| r.from + r.size > src.size || r.to + r.size > dst.size;
    if let Some(r) = regions.iter().find(outside) {
        return Err(vellum_error::Error::Invalid(format!(
            "a copy of {} bytes from {} to {} lies outside its {}-byte source or the {}-byte buffer {}",
            r.size, r.from, r.to, src.size, dst.size, dst.name
        )));
    }
    let regions: Vec<vk::BufferCopy> = regions
        .iter()
        .map(|r| {
            vk::BufferCopy::default()
                .src_offset(src.offset + r.from)
                .dst_offset(r.to)
                .size(r.size)
        })
        .collect();
    if !regions.is_empty() {
        unsafe { ctx.device.cmd_copy_buffer(cmd, src.raw, dst.raw, &regions) };
    }
    Ok(())
}

/// One region of [`copy_slice_regions`], in bytes.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct CopyRegion {
    /// Where the bytes start in the source slice.
    pub from: u64,
    /// Where they go in the destination buffer.
    pub to: u64,
    /// How many.
    pub size: u64,
}

/// Records a write of `bytes` (at most 65,536, a multiple of 4) at the start of `buffer`, in
/// the command buffer itself; the caller orders it with [`memory_transition`].
pub fn update_buffer(ctx: &Context, cmd: vk::CommandBuffer, buffer: &Buffer, bytes: &[u8]) {
    unsafe { ctx.device.cmd_update_buffer(cmd, buffer.raw, 0, bytes) };
}

/// Records a fill of the whole of `buffer` with the 32-bit word `value`; the caller orders it
/// with [`memory_transition`].
pub fn fill_buffer(ctx: &Context, cmd: vk::CommandBuffer, buffer: &Buffer, value: u32) {
    unsafe {
        ctx.device
            .cmd_fill_buffer(cmd, buffer.raw, 0, vk::WHOLE_SIZE, value)
    };
}

/// Records a fill of `size` bytes of `buffer` from `offset` (both multiples of 4) with the
/// 32-bit word `value`; the caller orders it with [`memory_transition`].
pub fn fill_buffer_range(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    buffer: &Buffer,
    (offset, size): (u64, u64),
    value: u32,
) {
    unsafe {
        ctx.device
            .cmd_fill_buffer(cmd, buffer.raw, offset, size, value)
    };
}

/// Records a draw of `vertices` vertices, from `vertex_buffer` (its offset) when given.
pub fn draw(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    vertex_buffer: Option<&crate::resources::BufferSlice>,
    vertices: u32,
) {
    unsafe {
        if let Some(b) = vertex_buffer {
            ctx.device
                .cmd_bind_vertex_buffers(cmd, 0, &[b.raw], &[b.offset]);
        }
        ctx.device.cmd_draw(cmd, vertices, 1, 0, 0);
    }
}

/// Records a scissor of `rect` (x, y, width, height in pixels) for the draws that follow.
pub fn set_scissor(ctx: &Context, cmd: vk::CommandBuffer, rect: [u32; 4]) {
    let scissor = vk::Rect2D {
        offset: vk::Offset2D {
            x: rect[0] as i32,
            y: rect[1] as i32,
        },
        extent: vk::Extent2D {
            width: rect[2],
            height: rect[3],
        },
    };
    unsafe { ctx.device.cmd_set_scissor(cmd, 0, &[scissor]) };
}

/// A command pool of its own for a library that records and submits its own commands (egui's
/// renderer uploads its textures through one); its buffers may be reset one by one. Dropped, it
/// waits for the device to go idle and is destroyed.
pub struct CommandPool {
    ctx: Arc<Context>,
    /// The Vulkan pool, for the library that takes it.
    pub raw: vk::CommandPool,
}

impl CommandPool {
    /// A pool on the context's queue family; `name` says whose it is in an error.
    pub fn new(ctx: &Arc<Context>, name: &str) -> Result<Self> {
        let info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(ctx.queue_family)
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        let raw = unsafe { ctx.device.create_command_pool(&info, None) }
            .vk(format!("creating {name}'s command pool"))?;
        Ok(CommandPool {
            ctx: ctx.clone(),
            raw,
        })
    }
}

impl Drop for CommandPool {
    fn drop(&mut self) {
        unsafe {
            let _ = self.ctx.device.device_wait_idle();
            self.ctx.device.destroy_command_pool(self.raw, None);
        }
    }
}
