//! Barriers as transitions between named accesses. [`Access`] says how a resource is used;
//! [`access_info`] is the one table that turns it into synchronization2 stage, access mask and
//! image layout. The one other place that writes barrier flags is `swapchain.rs`: the two
//! transitions of a swapchain image around a frame's drawing (to a colour attachment after
//! acquire, to presentation after), whose images are the presentation engine's and not
//! [`crate::Image`]s. Semaphore waits and timestamps name stages too, but no barrier.

use ash::vk;

/// How a resource is being used. Images remember their last `Access`, so a transition only names
/// the next one.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum Access {
    /// Nothing yet; contents may be discarded.
    Undefined,
    /// Source of a copy.
    TransferRead,
    /// Destination of a copy or clear.
    TransferWrite,
    /// Read as a storage image or buffer in a compute shader.
    ComputeRead,
    /// Written as a storage image or buffer in a compute shader.
    ComputeWrite,
    /// Read and written as storage in a compute shader (atomics, in-place updates).
    ComputeReadWrite,
    /// Sampled in a compute shader.
    ComputeSampled,
    /// Sampled in a fragment shader.
    FragmentSampled,
    /// Read as a storage buffer in a fragment shader.
    FragmentStorageRead,
    /// Written as a colour attachment.
    ColorAttachment,
    /// Read and written as a depth attachment (depth test and write).
    DepthAttachment,
    /// Read on the host after the GPU wrote it.
    HostRead,
    /// Read as the arguments of an indirect dispatch and as storage by the dispatched shader.
    IndirectRead,
}

/// The synchronization2 view of an [`Access`].
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(crate) struct AccessInfo {
    /// The pipeline stages that wait or are waited for.
    pub(crate) stage: vk::PipelineStageFlags2,
    /// The memory accesses made available or visible.
    pub(crate) access: vk::AccessFlags2,
    /// The layout an image is in for this access (`UNDEFINED` for buffers).
    pub(crate) layout: vk::ImageLayout,
}

/// The table.
pub(crate) fn access_info(a: Access) -> AccessInfo {
    use vk::AccessFlags2 as A;
    use vk::ImageLayout as L;
    use vk::PipelineStageFlags2 as S;
    let (stage, access, layout) = match a {
        Access::Undefined => (S::NONE, A::NONE, L::UNDEFINED),
        Access::TransferRead => (S::COPY, A::TRANSFER_READ, L::TRANSFER_SRC_OPTIMAL),
        Access::TransferWrite => (
            S::COPY | S::CLEAR,
            A::TRANSFER_WRITE,
            L::TRANSFER_DST_OPTIMAL,
        ),
        Access::ComputeRead => (S::COMPUTE_SHADER, A::SHADER_STORAGE_READ, L::GENERAL),
        Access::ComputeWrite => (S::COMPUTE_SHADER, A::SHADER_STORAGE_WRITE, L::GENERAL),
        Access::ComputeReadWrite => (
            S::COMPUTE_SHADER,
            A::SHADER_STORAGE_READ | A::SHADER_STORAGE_WRITE,
            L::GENERAL,
        ),
        Access::ComputeSampled => (
            S::COMPUTE_SHADER,
            A::SHADER_SAMPLED_READ,
            L::SHADER_READ_ONLY_OPTIMAL,
        ),
        Access::FragmentSampled => (
            S::FRAGMENT_SHADER,
            A::SHADER_SAMPLED_READ,
            L::SHADER_READ_ONLY_OPTIMAL,
        ),
        Access::FragmentStorageRead => (S::FRAGMENT_SHADER, A::SHADER_STORAGE_READ, L::GENERAL),
        Access::ColorAttachment => (
            S::COLOR_ATTACHMENT_OUTPUT,
            A::COLOR_ATTACHMENT_READ | A::COLOR_ATTACHMENT_WRITE,
            L::COLOR_ATTACHMENT_OPTIMAL,
        ),
        Access::DepthAttachment => (
            S::EARLY_FRAGMENT_TESTS | S::LATE_FRAGMENT_TESTS,
            A::DEPTH_STENCIL_ATTACHMENT_READ | A::DEPTH_STENCIL_ATTACHMENT_WRITE,
            L::DEPTH_ATTACHMENT_OPTIMAL,
        ),
        Access::HostRead => (S::HOST, A::HOST_READ, L::GENERAL),
        Access::IndirectRead => (
            S::DRAW_INDIRECT | S::COMPUTE_SHADER,
            A::INDIRECT_COMMAND_READ | A::SHADER_STORAGE_READ,
            L::GENERAL,
        ),
    };
    AccessInfo {
        stage,
        access,
        layout,
    }
}

/// True when `a` writes (so a later access of any kind must wait for it).
pub(crate) fn is_write(a: Access) -> bool {
    matches!(
        a,
        Access::TransferWrite
            | Access::ComputeWrite
            | Access::ComputeReadWrite
            | Access::ColorAttachment
            | Access::DepthAttachment
    )
}

/// An image barrier from `prev` to `next`, or `None` when neither a hazard nor a layout change
/// requires one (read after read in the same layout). Write after read gets an execution-only
/// dependency (no source access).
///
/// With `discard_contents`, the old layout is UNDEFINED (the contents may be dropped), but the
/// barrier still waits for `prev`: a write after a discarded write or read is still a hazard.
pub(crate) fn image_barrier(
    image: vk::Image,
    aspect: vk::ImageAspectFlags,
    prev: Access,
    next: Access,
    discard_contents: bool,
) -> Option<vk::ImageMemoryBarrier2<'static>> {
    let (p, n) = (access_info(prev), access_info(next));
    let old_layout = if discard_contents {
        vk::ImageLayout::UNDEFINED
    } else {
        p.layout
    };
    if !is_write(prev) && !is_write(next) && old_layout == n.layout && prev != Access::Undefined {
        return None;
    }
    Some(
        vk::ImageMemoryBarrier2::default()
            .src_stage_mask(p.stage)
            .src_access_mask(if is_write(prev) {
                p.access
            } else {
                vk::AccessFlags2::NONE
            })
            .dst_stage_mask(n.stage)
            .dst_access_mask(n.access)
            .old_layout(old_layout)
            .new_layout(n.layout)
            .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .image(image)
            .subresource_range(vk::ImageSubresourceRange {
                aspect_mask: aspect,
                base_mip_level: 0,
                level_count: vk::REMAINING_MIP_LEVELS,
                base_array_layer: 0,
                layer_count: vk::REMAINING_ARRAY_LAYERS,
            }),
    )
}

/// A global memory barrier from `prev` to `next` (buffers), or `None` for read after read.
pub(crate) fn memory_barrier(prev: Access, next: Access) -> Option<vk::MemoryBarrier2<'static>> {
    if !is_write(prev) && !is_write(next) {
        return None;
    }
    let (p, n) = (access_info(prev), access_info(next));
    Some(
        vk::MemoryBarrier2::default()
            .src_stage_mask(p.stage)
            .src_access_mask(if is_write(prev) {
                p.access
            } else {
                vk::AccessFlags2::NONE
            })
            .dst_stage_mask(n.stage)
            .dst_access_mask(n.access),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn discarding_contents_still_waits_for_the_last_write() {
        let b = image_barrier(
            vk::Image::null(),
            vk::ImageAspectFlags::COLOR,
            Access::TransferWrite,
            Access::ComputeWrite,
            true,
        )
        .expect("WAW");
        assert_eq!(b.old_layout, vk::ImageLayout::UNDEFINED);
        assert_eq!(b.src_access_mask, vk::AccessFlags2::TRANSFER_WRITE);
        assert_ne!(b.src_stage_mask, vk::PipelineStageFlags2::NONE);
    }

    #[test]
    fn write_after_read_waits_for_the_reads() {
        let b = image_barrier(
            vk::Image::null(),
            vk::ImageAspectFlags::COLOR,
            Access::ComputeRead,
            Access::ComputeWrite,
            false,
        )
        .expect("WAR");
        assert_eq!(b.src_stage_mask, vk::PipelineStageFlags2::COMPUTE_SHADER);
        assert_eq!(b.src_access_mask, vk::AccessFlags2::NONE);
        assert!(memory_barrier(Access::ComputeRead, Access::ComputeWrite).is_some());
    }

    #[test]
    fn read_after_read_needs_no_barrier() {
        assert!(image_barrier(
            vk::Image::null(),
            vk::ImageAspectFlags::COLOR,
            Access::ComputeRead,
            Access::ComputeRead,
            false
        )
        .is_none());
        assert!(memory_barrier(Access::ComputeRead, Access::TransferRead).is_none());
    }

    #[test]
    fn write_then_read_waits_on_the_write() {
        let b = image_barrier(
            vk::Image::null(),
            vk::ImageAspectFlags::COLOR,
            Access::ComputeWrite,
            Access::FragmentSampled,
            false,
        )
        .expect("hazard");
        assert_eq!(b.src_stage_mask, vk::PipelineStageFlags2::COMPUTE_SHADER);
        assert_eq!(b.src_access_mask, vk::AccessFlags2::SHADER_STORAGE_WRITE);
        assert_eq!(b.dst_stage_mask, vk::PipelineStageFlags2::FRAGMENT_SHADER);
        assert_eq!(b.new_layout, vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL);
        assert_eq!(b.old_layout, vk::ImageLayout::GENERAL);
    }

    #[test]
    fn layout_change_after_read_is_kept_but_waits_on_nothing() {
        let b = image_barrier(
            vk::Image::null(),
            vk::ImageAspectFlags::COLOR,
            Access::FragmentSampled,
            Access::ComputeWrite,
            false,
        )
        .expect("layout change");
        assert_eq!(b.src_access_mask, vk::AccessFlags2::NONE);
        assert_eq!(b.old_layout, vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL);
        assert_eq!(b.new_layout, vk::ImageLayout::GENERAL);
    }

    #[test]
    fn every_write_access_has_a_write_mask() {
        for a in [
            Access::TransferWrite,
            Access::ComputeWrite,
            Access::ComputeReadWrite,
            Access::ColorAttachment,
            Access::DepthAttachment,
        ] {
            assert!(is_write(a));
            assert_ne!(access_info(a).access, vk::AccessFlags2::NONE);
        }
    }
}
