//! Volumes as 3D images. Each voxel type keeps its bits exactly (integer formats for integer
//! voxels), so a round trip is bit-exact and the compute passes see the stored values.

use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::profiler::PassTime;
use vellum_gpu::transfer::{record_readback, record_upload, staging_buffer};
use vellum_gpu::Format;
use vellum_gpu::{submit_timed, Access, Context, Image, ImageDesc};
use vellum_volume::{Volume, VoxelType};

/// The image format that stores `ty` bit for bit.
pub(crate) fn format_of(ty: VoxelType) -> Format {
    match ty {
        VoxelType::U8 => Format::R8_UINT,
        VoxelType::U16 => Format::R16_UINT,
        VoxelType::I16 => Format::R16_SINT,
        VoxelType::F32 => Format::R32_SFLOAT,
    }
}

/// The extent of `v` as an image extent, after checking it against the device.
pub(crate) fn extent_of(
    ctx: &Context,
    dims: [usize; 3],
    bytes_per_voxel: usize,
    copies: usize,
) -> Result<[u32; 3]> {
    ctx.check_image_3d(dims, bytes_per_voxel, copies)?;
    Ok([dims[0] as u32, dims[1] as u32, dims[2] as u32])
}

/// Creates a 3D image for `v` (not yet filled).
pub fn create(ctx: &Arc<Context>, name: &str, v: &Volume) -> Result<Image> {
    let ty = v.voxel_type();
    let extent = extent_of(ctx, v.dims, ty.size(), 1)?;
    Image::new(ctx, name, &ImageDesc::new_3d(format_of(ty), extent))
}

/// Timings of a round trip.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RoundTrip {
    /// Whether the bytes read back equal those uploaded.
    pub bit_exact: bool,
    /// Bytes of voxel data each way.
    pub bytes: usize,
    /// GPU time of `upload` and `readback`.
    pub passes: Vec<PassTime>,
}

/// Uploads `v` into a 3D image and reads it back in one submission, with `upload` and `readback`
/// timed as passes. Returns whether the bytes came back unchanged.
pub fn round_trip(ctx: &Arc<Context>, v: &Volume) -> Result<RoundTrip> {
    let image = create(ctx, "round-trip volume", v)?;
    let bytes = v.data.as_bytes();
    let mut staging = staging_buffer(ctx, "round-trip staging", bytes.len())?;
    staging.write(bytes)?;
    // A separate readback buffer, so the comparison cannot see the uploaded bytes.
    let back = staging_buffer(ctx, "round-trip readback", bytes.len())?;
    let ((), passes) = submit_timed(ctx, "volume round trip", |f| {
        f.profiler.pass(f.cmd, "upload", |cmd| {
            record_upload(ctx, cmd, &staging, &image, Access::TransferRead)
        });
        f.profiler.pass(f.cmd, "readback", |cmd| {
            record_readback(ctx, cmd, &image, &back)
        });
        Ok(())
    })?;
    let got = back
        .mapped()
        .ok_or_else(|| Error::Invalid("readback buffer is not host-visible".into()))?;
    Ok(RoundTrip {
        bit_exact: got == bytes,
        bytes: bytes.len(),
        passes,
    })
}
