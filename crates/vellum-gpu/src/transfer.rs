//! Staging transfers between host bytes and images. The record functions put the copies into a
//! command buffer the caller owns (so they can be timed as passes beside compute work); the
//! `upload`/`readback` helpers wrap them in one submission each.

use crate::barrier::Access;
use crate::commands::memory_transition;
use crate::context::Context;
use crate::frame::submit_once;
use crate::resources::{Buffer, BufferDesc, BufferLocation, BufferSlice, Image};
use ash::vk;
use std::sync::Arc;
use vellum_error::{Error, Result};

fn region(image: &Image, buffer_offset: u64) -> vk::BufferImageCopy {
    let [w, h, d] = image.desc.extent;
    vk::BufferImageCopy::default()
        .buffer_offset(buffer_offset)
        .buffer_row_length(0)
        .buffer_image_height(0)
        .image_subresource(vk::ImageSubresourceLayers {
            aspect_mask: image.aspect(),
            mip_level: 0,
            base_array_layer: 0,
            layer_count: 1,
        })
        .image_extent(vk::Extent3D {
            width: w,
            height: h,
            depth: d,
        })
}

/// A host-visible buffer that serves as both upload source and readback destination, sized for
/// `bytes`. One buffer for both halves a round trip's host memory.
pub fn staging_buffer(ctx: &Arc<Context>, name: &str, bytes: usize) -> Result<Buffer> {
    Buffer::new(
        ctx,
        name,
        &BufferDesc {
            size: bytes as u64,
            usage: vk::BufferUsageFlags::TRANSFER_SRC | vk::BufferUsageFlags::TRANSFER_DST,
            location: BufferLocation::Readback,
        },
    )
}

/// Records a copy of the whole of `staging` into `image`, then a transition to `next`.
pub fn record_upload(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    staging: &Buffer,
    image: &Image,
    next: Access,
) {
    record_upload_from(ctx, cmd, staging.slice(), image, next)
}

/// Records a copy of the texels at `src` (tightly packed, for example a slice of a frame's staging
/// ring) into `image`, then a transition to `next`. Counted as an upload of `image`.
pub fn record_upload_from(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    src: BufferSlice,
    image: &Image,
    next: Access,
) {
    ctx.count_transfer(&image.name, true, image.byte_size() as u64);
    image.discard();
    image.transition(cmd, Access::TransferWrite);
    copy_into(ctx, cmd, src, image, &[region(image, src.offset)]);
    image.transition(cmd, next);
}

/// Records `regions` of `src`'s buffer into `image`, which is ready for transfer writes.
fn copy_into(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    src: BufferSlice,
    image: &Image,
    regions: &[vk::BufferImageCopy],
) {
    if regions.is_empty() {
        return;
    }
    unsafe {
        ctx.device.cmd_copy_buffer_to_image(
            cmd,
            src.raw,
            image.raw,
            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
            regions,
        );
    }
}

/// A box of texels tightly packed in a staging slice (x fastest), and where it goes in an image.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct TexelBox {
    /// Where the box's texels start, in bytes into the slice.
    pub from: u64,
    /// The image texel of the box's first texel.
    pub origin: [u32; 3],
    /// Texels along x, y, z.
    pub extent: [u32; 3],
}

/// Records copies of `boxes` of `src` (a slice of a staging ring) into `image`, which the caller
/// has made ready for transfer writes ([`Access::TransferWrite`]) and orders after them. A box
/// that lies outside the slice or the image is refused, and nothing is recorded. Counted as an
/// upload of `image`.
pub fn record_upload_boxes(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    src: BufferSlice,
    image: &Image,
    boxes: &[TexelBox],
) -> Result<()> {
    let texel = crate::resources::format_size(image.desc.format) as u64;
    let bytes = |b: &TexelBox| b.extent.iter().map(|&e| e as u64).product::<u64>() * texel;
    let outside = |b: &&TexelBox| {
        b.from + bytes(b) > src.size
            || (0..3).any(|a| b.origin[a] as u64 + b.extent[a] as u64 > image.desc.extent[a] as u64)
    };
    if let Some(b) = boxes.iter().find(outside) {
        return Err(Error::Invalid(format!(
            "a box of {:?} texels at {:?} from byte {} lies outside its {}-byte source or the image {} of {:?}",
            b.extent, b.origin, b.from, src.size, image.name, image.desc.extent
        )));
    }
    let regions: Vec<vk::BufferImageCopy> = boxes
        .iter()
        .map(|b| {
            region(image, src.offset + b.from)
                .image_offset(vk::Offset3D {
                    x: b.origin[0] as i32,
                    y: b.origin[1] as i32,
                    z: b.origin[2] as i32,
                })
                .image_extent(vk::Extent3D {
                    width: b.extent[0],
                    height: b.extent[1],
                    depth: b.extent[2],
                })
        })
        .collect();
    ctx.count_transfer(&image.name, true, boxes.iter().map(bytes).sum());
    copy_into(ctx, cmd, src, image, &regions);
    Ok(())
}

/// Records a copy of `image` into `staging`, made visible to the host. The copy first waits for
/// earlier copies that read `staging` in the same command buffer (a staging buffer often serves
/// as upload source and readback destination of one submission).
pub fn record_readback(ctx: &Context, cmd: vk::CommandBuffer, image: &Image, staging: &Buffer) {
    ctx.count_transfer(&image.name, false, image.byte_size() as u64);
    image.transition(cmd, Access::TransferRead);
    memory_transition(ctx, cmd, Access::TransferRead, Access::TransferWrite);
    unsafe {
        ctx.device.cmd_copy_image_to_buffer(
            cmd,
            image.raw,
            vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
            staging.raw,
            &[region(image, 0)],
        );
    }
    memory_transition(ctx, cmd, Access::TransferWrite, Access::HostRead);
}

fn check_len(image: &Image, len: usize) -> Result<()> {
    if len != image.byte_size() {
        return Err(Error::Invalid(format!(
            "image {} holds {} bytes but {len} were given",
            image.name,
            image.byte_size()
        )));
    }
    Ok(())
}

/// Uploads `bytes` (tightly packed texels) into `image` and leaves it in `next`.
pub fn upload(ctx: &Arc<Context>, image: &Image, bytes: &[u8], next: Access) -> Result<()> {
    check_len(image, bytes.len())?;
    let mut staging = staging_buffer(ctx, &format!("{} staging", image.name), bytes.len())?;
    staging.write(bytes)?;
    submit_once(ctx, &format!("upload of {}", image.name), |f| {
        record_upload(ctx, f.cmd, &staging, image, next);
        Ok(())
    })
}

/// Reads the texels of `image` back to the host.
pub fn readback(ctx: &Arc<Context>, image: &Image) -> Result<Vec<u8>> {
    let staging = staging_buffer(ctx, &format!("{} readback", image.name), image.byte_size())?;
    submit_once(ctx, &format!("readback of {}", image.name), |f| {
        record_readback(ctx, f.cmd, image, &staging);
        Ok(())
    })?;
    let bytes = staging
        .mapped()
        .ok_or_else(|| Error::Invalid("readback buffer is not host-visible".into()))?;
    Ok(bytes.to_vec())
}

/// Reads the bytes of a (device-local) buffer back to the host, in one submission.
pub fn readback_buffer(ctx: &Arc<Context>, buffer: &Buffer) -> Result<Vec<u8>> {
    let staging = staging_buffer(
        ctx,
        &format!("{} readback", buffer.name),
        buffer.size as usize,
    )?;
    ctx.count_transfer(&buffer.name, false, buffer.size);
    submit_once(ctx, &format!("readback of {}", buffer.name), |f| {
        let cmd = f.cmd;
        memory_transition(ctx, cmd, Access::ComputeReadWrite, Access::TransferRead);
        let region = vk::BufferCopy::default().size(buffer.size);
        unsafe {
            ctx.device
                .cmd_copy_buffer(cmd, buffer.raw, staging.raw, &[region])
        };
        memory_transition(ctx, cmd, Access::TransferWrite, Access::HostRead);
        Ok(())
    })?;
    staging
        .mapped()
        .map(<[u8]>::to_vec)
        .ok_or_else(|| Error::Invalid("readback buffer is not host-visible".into()))
}

/// IEEE half-precision bits to f32 (for reading back R16F/RGBA16F images).
pub fn f16_to_f32(bits: u16) -> f32 {
    let sign = if bits & 0x8000 != 0 { -1.0f32 } else { 1.0 };
    let exp = ((bits >> 10) & 0x1f) as i32;
    let mant = (bits & 0x3ff) as f32;
    match exp {
        0 => sign * mant * 2f32.powi(-24),
        31 if mant == 0.0 => sign * f32::INFINITY,
        31 => f32::NAN,
        e => sign * (1.0 + mant / 1024.0) * 2f32.powi(e - 15),
    }
}

#[cfg(test)]
mod tests {
    use super::f16_to_f32;

    #[test]
    fn half_floats() {
        assert_eq!(f16_to_f32(0x3c00), 1.0);
        assert_eq!(f16_to_f32(0xc000), -2.0);
        assert_eq!(f16_to_f32(0x7bff), 65504.0);
        assert_eq!(f16_to_f32(0x0001), 2f32.powi(-24));
        assert_eq!(f16_to_f32(0x3555), 0.33325195);
        assert!(f16_to_f32(0x7c00).is_infinite() && f16_to_f32(0x7e00).is_nan());
    }
}
