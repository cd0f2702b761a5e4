//! The spatial importance map on compute pipelines (SPEC IM1, paper §3.2).
//!
//! Reads a volume, writes ΔD = G∗V − V as float. Passes: `upload`, `gauss_x`, `gauss_y`, `gauss_z`,
//! `subtract`, `readback`, each timed. The volume lives in R32F 3D storage images rather than
//! buffers: lavapipe caps a storage-buffer binding at 128 MiB, and the paper's CT head is 312 MB in
//! float. Three images suffice: src → A (x), A → B (y), B → A (z), then B = A − src.

use crate::error::{Error, Result};
use crate::gpu::pipeline::group_count;
use crate::gpu::profiler::PassTime;
use crate::gpu::transfer::{record_readback, record_upload, staging_buffer};
use crate::gpu::{
    submit_timed, Access, Bind, BindingKind, Buffer, ComputePipeline, Context, Frame, Image,
    ImageDesc,
};
use crate::passes::volume_image::extent_of;
use crate::volume::reference::gaussian::gaussian_kernel;
use crate::volume::{Volume, VoxelData};
use ash::vk;
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;

/// Push constants of `importance/gauss1d.comp` (GLSL twin: `GaussPush` in glsl/common/importance.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GaussPush {
    pub dims: [i32; 3],
    pub axis: i32,
    pub radius: i32,
    pub pad: [i32; 3],
}

/// Push constants of `importance/subtract.comp` (GLSL twin: `SubtractPush`).
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SubtractPush {
    pub dims: [i32; 3],
    pub pad: i32,
}

/// Workgroup shape, as IMPORTANCE_LOCAL_* in importance.glsl.
pub const LOCAL_SIZE: [u32; 3] = [64, 2, 2];

/// Texels (four voxels each) each Gaussian invocation filters along x (specialisation constant
/// SEGMENT_X). Measured on lavapipe: 3..6 are equal, 8 is slower.
pub const SEGMENT_X: u32 = 4;

/// Texels each Gaussian invocation filters along y or z (specialisation constant SEGMENT). Its
/// private array holds SEGMENT + 2R texels; lavapipe keeps such an array in vector registers only
/// up to about 23 entries (measured: at R = 10, SEGMENT 3 runs in half the time of SEGMENT 4), and
/// short segments beat long ones below that, so take 4 and shrink it for large radii.
pub fn segment(radius_voxels: u32) -> u32 {
    (23u32.saturating_sub(2 * radius_voxels)).clamp(1, 4)
}

/// Texels per Gaussian invocation: `yz` along y and z (SEGMENT), `x` along x (SEGMENT_X).
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct Segments {
    pub yz: u32,
    pub x: u32,
}

impl Segments {
    /// The lengths for a device of `device_type` at `radius_voxels`: lavapipe's ([`segment`],
    /// [`SEGMENT_X`]) on a CPU; on a GPU, where the private array stays in registers, longer
    /// segments re-read less halo (BENCHMARKS.md, "On a GPU"). `VELLUM_GAUSS_SEGMENTS=YZ,X`
    /// overrides both, for measuring.
    pub fn choose(device_type: &str, radius_voxels: u32) -> Segments {
        if let Some(s) = std::env::var("VELLUM_GAUSS_SEGMENTS")
            .ok()
            .and_then(|v| Segments::parse(&v))
        {
            return s;
        }
        match device_type {
            "CPU" => Segments {
                yz: segment(radius_voxels),
                x: SEGMENT_X,
            },
            _ => Segments {
                yz: GPU_SEGMENT_YZ,
                x: GPU_SEGMENT_X,
            },
        }
    }

    fn parse(v: &str) -> Option<Segments> {
        let (yz, x) = v.split_once(',')?;
        let (yz, x) = (yz.trim().parse().ok()?, x.trim().parse().ok()?);
        ((1..=64).contains(&yz) && (1..=64).contains(&x)).then_some(Segments { yz, x })
    }
}

/// Segment lengths on a GPU (see [`Segments::choose`]): 8 and 8 were the best or within noise of
/// it on every Table 1 case swept on an H100 (4..32 along y/z, 2..8 along x; BENCHMARKS.md),
/// 10–40 % faster than lavapipe's 4 and 4 at R = 10, where the halo is the larger share.
const GPU_SEGMENT_YZ: u32 = 8;
const GPU_SEGMENT_X: u32 = 8;

/// Lines per Gaussian workgroup (GAUSS_LOCAL_X in importance.glsl).
pub const GAUSS_LOCAL_X: u32 = 64;

/// A normalised volume texture as the filters read it: the image, its size in voxels, and the
/// nearest-texel sampler it is read through.
#[derive(Copy, Clone)]
struct TextureSource<'a> {
    image: &'a Image,
    dims: [usize; 3],
    sampler: &'a crate::gpu::Sampler,
}

/// Names of the three filter passes, by axis.
pub const GAUSS_PASSES: [&str; 3] = ["gauss_x", "gauss_y", "gauss_z"];

/// The compiled pipelines; build once, run on many volumes.
pub struct ImportanceMap {
    ctx: Arc<Context>,
    /// Gaussian pipelines and their weights by radius, built on first use: R is a
    /// specialisation constant.
    gauss: HashMap<u32, Gauss>,
    subtract: ComputePipeline,
    pack: ComputePipeline,
    unpack: ComputePipeline,
}

/// ΔD where the renderer samples it: an R32F volume in normalised intensity units, and max |ΔD|
/// over the volume as the bits of a non-negative float in a storage buffer (never read back).
pub struct ImportanceVolume {
    pub delta_d: Image,
    pub max_abs: Buffer,
    pub radius_voxels: u32,
}

/// A Gaussian pipeline specialised for one radius, and its weights.
#[derive(Clone)]
struct Gauss {
    pipeline: Arc<ComputePipeline>,
    weights: Arc<Buffer>,
    segments: Segments,
}

/// The images of the importance map for one volume size, kept on the GPU: `src` holds the volume
/// as float, four x-neighbours per RGBA32F texel (see [`pack_rows`]); after
/// [`ImportanceMap::record`], `a` holds ΔD in the same packing and `b` is scratch.
pub struct ImportanceImages {
    pub src: Image,
    pub a: Image,
    pub b: Image,
    pub dims: [usize; 3],
}

impl ImportanceImages {
    /// Allocates the three images for a volume of `dims`.
    pub fn new(ctx: &Arc<Context>, dims: [usize; 3]) -> Result<Self> {
        // Three float images; checked on the volume's own dims so that a refusal names them.
        ctx.check_image_3d(dims, 4, 3)?;
        // They hold four voxels per texel along x.
        let extent = extent_of(ctx, [dims[0].div_ceil(4), dims[1], dims[2]], 16, 3)?;
        let desc = ImageDesc::new_3d(vk::Format::R32G32B32A32_SFLOAT, extent);
        Ok(ImportanceImages {
            src: Image::new(ctx, "importance src", &desc)?,
            a: Image::new(ctx, "importance a", &desc)?,
            b: Image::new(ctx, "importance b", &desc)?,
            dims,
        })
    }

    /// ΔD, once recorded.
    pub fn delta_d(&self) -> &Image {
        &self.a
    }
}

/// ΔD with its timings.
#[derive(Clone, Debug)]
pub struct ImportanceOutput {
    /// ΔD as a float volume with the input's dims and spacing.
    pub delta_d: Volume,
    /// GPU time of each pass (upload, prepare, gauss_x, gauss_y, gauss_z, subtract, readback, and
    /// `copy` when a bandwidth reference was asked for). `prepare` clears the work images: on CPU
    /// devices it absorbs the page faults of fresh memory.
    pub passes: Vec<PassTime>,
    /// Wall time of the whole computation as the paper's "Total": conversion to float, allocation,
    /// upload, passes, readback and conversion back into a volume.
    pub total_ms: f64,
}

impl ImportanceMap {
    /// Builds the pipelines.
    pub fn new(ctx: &Arc<Context>) -> Result<Self> {
        use BindingKind::*;
        let subtract = ComputePipeline::new(
            ctx,
            "importance/subtract.comp",
            &[StorageImage, StorageImage],
            std::mem::size_of::<SubtractPush>() as u32,
        )?;
        let push = std::mem::size_of::<SubtractPush>() as u32;
        Ok(ImportanceMap {
            ctx: ctx.clone(),
            gauss: HashMap::new(),
            subtract,
            pack: ComputePipeline::new(
                ctx,
                "importance/pack.comp",
                &[SampledImage, StorageImage],
                push,
            )?,
            unpack: ComputePipeline::new(
                ctx,
                "importance/unpack.comp",
                &[StorageImage, StorageImage, StorageBuffer],
                push,
            )?,
        })
    }

    /// The Gaussian pipeline and weights for `radius_voxels` (built on first use).
    fn gauss(&mut self, radius_voxels: u32) -> Result<Gauss> {
        if radius_voxels > MAX_RADIUS {
            return Err(Error::Invalid(format!(
                "radius {radius_voxels} is too large; the importance map supports R up to {MAX_RADIUS} voxels"
            )));
        }
        if let Some(g) = self.gauss.get(&radius_voxels) {
            return Ok(g.clone());
        }
        let kernel: Vec<f32> = gaussian_kernel(radius_voxels)?
            .iter()
            .map(|&w| w as f32)
            .collect();
        let segments = Segments::choose(&self.ctx.info.device_type, radius_voxels);
        let g = Gauss {
            segments,
            pipeline: Arc::new(ComputePipeline::with_constants(
                &self.ctx,
                "importance/gauss1d.comp",
                &[
                    BindingKind::StorageImage,
                    BindingKind::StorageImage,
                    BindingKind::StorageBuffer,
                ],
                std::mem::size_of::<GaussPush>() as u32,
                &[radius_voxels, segments.yz, segments.x],
            )?),
            weights: Arc::new(Buffer::from_bytes(
                &self.ctx,
                "gaussian weights",
                vk::BufferUsageFlags::STORAGE_BUFFER,
                bytemuck::cast_slice(&kernel),
            )?),
        };
        self.gauss.insert(radius_voxels, g.clone());
        Ok(g)
    }

    /// Records passes `gauss_x`, `gauss_y`, `gauss_z` and `subtract`: ΔD of `images.src` into
    /// `images.a`, on images that stay on the GPU.
    pub fn record(
        &mut self,
        frame: &mut Frame,
        images: &ImportanceImages,
        radius_voxels: u32,
    ) -> Result<()> {
        self.record_passes(frame, images, radius_voxels, true)
    }

    /// The three filter passes (G∗V into `images.a`), then `subtract` when asked.
    fn record_passes(
        &mut self,
        frame: &mut Frame,
        images: &ImportanceImages,
        radius_voxels: u32,
        subtract: bool,
    ) -> Result<()> {
        let gauss = self.gauss(radius_voxels)?;
        let (cmd, profiler) = (frame.cmd, &mut *frame.profiler);
        let (src, a, b) = (&images.src, &images.a, &images.b);
        let extent = src.desc.extent;
        let dims = images.dims.map(|d| d as i32);
        // x: src → a, y: a → b, z: b → a.
        let chain = [(src, a), (a, b), (b, a)];
        for (axis, (input, output)) in chain.into_iter().enumerate() {
            profiler.begin(cmd, GAUSS_PASSES[axis]);
            input.transition(cmd, Access::ComputeRead);
            output.discard();
            output.transition(cmd, Access::ComputeWrite);
            let push = GaussPush {
                dims,
                axis: axis as i32,
                radius: radius_voxels as i32,
                pad: [0; 3],
            };
            gauss.pipeline.dispatch(
                cmd,
                &[
                    Bind::StorageImage(input),
                    Bind::StorageImage(output),
                    Bind::StorageBuffer(&gauss.weights),
                ],
                &push,
                gauss_groups(extent, axis, gauss.segments),
            )?;
            profiler.end(cmd);
        }
        if !subtract {
            return Ok(());
        }
        profiler.begin(cmd, "subtract");
        // Subtract writes over the blurred image in place: a holds G∗V, and ΔD goes to a.
        src.transition(cmd, Access::ComputeRead);
        a.transition(cmd, Access::ComputeReadWrite);
        self.subtract.dispatch(
            cmd,
            &[Bind::StorageImage(src), Bind::StorageImage(a)],
            &SubtractPush { dims, pad: 0 },
            group_count(extent, LOCAL_SIZE),
        )?;
        profiler.end(cmd);
        Ok(())
    }

    /// Records ΔD of the renderer's normalised volume texture, on the GPU from end to end: pass
    /// `pack` (R16 texture → packed float, sampled with the nearest-texel `sampler`), the four
    /// filter passes, and `unpack` (packed → R32F volume, with the max |ΔD| reduction). The work
    /// images are released once the frame completes.
    pub fn record_from_texture(
        &mut self,
        frame: &mut Frame,
        tex: &crate::passes::normals::VolumeTextures,
        sampler: &crate::gpu::Sampler,
        radius_voxels: u32,
    ) -> Result<ImportanceVolume> {
        let source = TextureSource {
            image: &tex.intensity,
            dims: tex.dims,
            sampler,
        };
        let (delta_d, max_abs) = self.record_filter(frame, &source, radius_voxels, true)?;
        Ok(ImportanceVolume {
            delta_d,
            max_abs,
            radius_voxels,
        })
    }

    /// Records G∗V of a normalised volume texture (R16 or R32F, read texel by texel through the
    /// nearest-texel `sampler`) as an R32F volume on the same scale: `pack`, the three filter
    /// passes and `unpack`. Line extraction smooths noisy data with it.
    pub fn record_blur_of_texture(
        &mut self,
        frame: &mut Frame,
        source: &Image,
        dims: [usize; 3],
        sampler: &crate::gpu::Sampler,
        radius_voxels: u32,
    ) -> Result<Image> {
        let source = TextureSource {
            image: source,
            dims,
            sampler,
        };
        let (blurred, _) = self.record_filter(frame, &source, radius_voxels, false)?;
        Ok(blurred)
    }

    /// `pack` of `source`, the filter passes (with `subtract`: ΔD, else G∗V) and `unpack` into a
    /// new R32F volume, with the max |value| reduction.
    fn record_filter(
        &mut self,
        frame: &mut Frame,
        texture: &TextureSource,
        radius_voxels: u32,
        subtract: bool,
    ) -> Result<(Image, Buffer)> {
        let TextureSource {
            image: source,
            dims: dims_in,
            sampler,
        } = *texture;
        let ctx = &self.ctx.clone();
        self.gauss(radius_voxels)?;
        let images = ImportanceImages::new(ctx, dims_in)?;
        let extent = images.src.desc.extent;
        let dims = dims_in.map(|d| d as i32);
        let cmd = frame.cmd;
        frame.profiler.begin(cmd, "pack");
        source.transition(cmd, Access::ComputeSampled);
        images.src.discard();
        images.src.transition(cmd, Access::ComputeWrite);
        self.pack.dispatch(
            cmd,
            &[
                Bind::Sampled(source, sampler),
                Bind::StorageImage(&images.src),
            ],
            &SubtractPush { dims, pad: 0 },
            group_count(extent, LOCAL_SIZE),
        )?;
        frame.profiler.end(cmd);
        self.record_passes(frame, &images, radius_voxels, subtract)?;
        let delta_d = Image::new(
            ctx,
            if subtract {
                "importance delta_d"
            } else {
                "smoothed volume"
            },
            &ImageDesc::new_3d(vk::Format::R32_SFLOAT, extent_of(ctx, dims_in, 4, 1)?),
        )?;
        let max_abs = Buffer::new(ctx, "importance max", &crate::gpu::BufferDesc::storage(4))?;
        frame.profiler.begin(cmd, "unpack");
        unsafe {
            ctx.device
                .cmd_fill_buffer(cmd, max_abs.raw, 0, vk::WHOLE_SIZE, 0)
        };
        crate::gpu::commands::memory_transition(
            ctx,
            cmd,
            Access::TransferWrite,
            Access::ComputeReadWrite,
        );
        images.a.transition(cmd, Access::ComputeRead);
        delta_d.discard();
        delta_d.transition(cmd, Access::ComputeWrite);
        self.unpack.dispatch(
            cmd,
            &[
                Bind::StorageImage(&images.a),
                Bind::StorageImage(&delta_d),
                Bind::StorageBuffer(&max_abs),
            ],
            &SubtractPush { dims, pad: 0 },
            group_count(delta_d.desc.extent, LOCAL_SIZE),
        )?;
        frame.profiler.end(cmd);
        Ok((delta_d, max_abs))
    }

    /// Computes ΔD of `v` with radius `radius_voxels`: allocation, upload, the passes and
    /// readback, timed as the paper's "Total". With `copy_reference`, the submission also times a
    /// plain image copy of one float volume (pass `copy`), the bandwidth bound of a 1D pass.
    pub fn compute(
        &mut self,
        v: &Volume,
        radius_voxels: u32,
        copy_reference: bool,
    ) -> Result<ImportanceOutput> {
        let start = Instant::now();
        let ctx = &self.ctx.clone();
        // Fails early on a bad radius, before any allocation.
        self.gauss(radius_voxels)?;
        v.check_finite("the input volume")?;
        let images = ImportanceImages::new(ctx, v.dims)?;
        let mut staging = staging_buffer(ctx, "importance staging", images.src.byte_size())?;
        // Conversion to float (paper step 1), in parallel, straight into the staging memory and
        // packed four voxels per texel.
        let mapped = staging
            .mapped_mut()
            .ok_or_else(|| Error::Invalid("staging buffer is not host-visible".into()))?;
        let floats: &mut [f32] = bytemuck::try_cast_slice_mut(mapped)
            .map_err(|e| Error::Invalid(format!("staging memory cannot hold floats: {e}")))?;
        pack_rows_into(v, floats);
        let ((), passes) = submit_timed(ctx, "importance map", |f| {
            let cmd = f.cmd;
            f.profiler.pass(cmd, "upload", |cmd| {
                record_upload(ctx, cmd, &staging, &images.src, Access::ComputeRead)
            });
            // First writes to fresh memory pay page faults on CPU devices; take them here, in
            // their own pass, so that neither the filters nor the copy reference carry them.
            f.profiler.pass(cmd, "prepare", |cmd| {
                for image in [&images.a, &images.b] {
                    clear_image(ctx, cmd, image);
                }
            });
            if copy_reference {
                f.profiler.pass(cmd, "copy", |cmd| {
                    copy_image(ctx, cmd, &images.src, &images.b)
                });
            }
            self.record(f, &images, radius_voxels)?;
            f.profiler.pass(cmd, "readback", |cmd| {
                record_readback(ctx, cmd, images.delta_d(), &staging)
            });
            Ok(())
        })?;
        let out = staging
            .mapped()
            .ok_or_else(|| Error::Invalid("readback buffer is not host-visible".into()))?;
        let packed: &[f32] = bytemuck::try_cast_slice(out)
            .map_err(|e| Error::Invalid(format!("readback memory does not hold floats: {e}")))?;
        let delta = unpack_rows(packed, v.dims);
        let delta_d =
            Volume::new(v.dims, v.spacing, VoxelData::F32(delta))?.with_geometry(v.geometry)?;
        Ok(ImportanceOutput {
            delta_d,
            passes,
            total_ms: start.elapsed().as_secs_f64() * 1e3,
        })
    }
}

/// Largest radius: R sizes private arrays in the shader (a specialisation constant).
pub const MAX_RADIUS: u32 = 32;

/// The voxels of `v` as f32, each x row padded to a multiple of four with its last voxel, so that
/// an RGBA32F texel holds four x-neighbours and padding behaves like the clamped border.
pub fn pack_rows(v: &Volume) -> Vec<f32> {
    let mut out = vec![0f32; v.dims[0].div_ceil(4) * 4 * v.dims[1] * v.dims[2]];
    pack_rows_into(v, &mut out);
    out
}

/// [`pack_rows`] into `out` (for example mapped staging memory), one parallel task per row.
pub fn pack_rows_into(v: &Volume, out: &mut [f32]) {
    fn rows<T: Copy + Send + Sync>(
        src: &[T],
        nx: usize,
        out: &mut [f32],
        f: impl Fn(T) -> f32 + Sync,
    ) {
        let px = nx.div_ceil(4) * 4;
        out.par_chunks_mut(px)
            .zip(src.par_chunks(nx))
            .for_each(|(dst, row)| {
                for (d, &s) in dst.iter_mut().zip(row) {
                    *d = f(s);
                }
                let last = f(row[nx - 1]);
                dst[nx..].fill(last);
            });
    }
    let nx = v.dims[0];
    match &v.data {
        VoxelData::U8(d) => rows(d, nx, out, |x| x as f32),
        VoxelData::U16(d) => rows(d, nx, out, |x| x as f32),
        VoxelData::I16(d) => rows(d, nx, out, |x| x as f32),
        VoxelData::F32(d) => rows(d, nx, out, |x| x),
    }
}

/// Inverse of [`pack_rows`]: drops the padding of each row.
pub fn unpack_rows(packed: &[f32], dims: [usize; 3]) -> Vec<f32> {
    let px = dims[0].div_ceil(4) * 4;
    let mut out = vec![0f32; dims[0] * dims[1] * dims[2]];
    out.par_chunks_mut(dims[0])
        .zip(packed.par_chunks(px))
        .for_each(|(dst, row)| dst.copy_from_slice(&row[..dims[0]]));
    out
}

/// Workgroups of the Gaussian pass along `axis` (as in gauss1d.comp). `extent` is in texels (x
/// holds four voxels per texel). x: lanes over (segment, y), groups over z. y and z: lanes over
/// (texel x, the other axis), groups over segments.
pub fn gauss_groups(extent: [u32; 3], axis: usize, segments: Segments) -> [u32; 3] {
    match axis {
        0 => [
            (extent[0].div_ceil(segments.x) * extent[1]).div_ceil(GAUSS_LOCAL_X),
            extent[2],
            1,
        ],
        1 => [
            (extent[0] * extent[2]).div_ceil(GAUSS_LOCAL_X),
            extent[1].div_ceil(segments.yz),
            1,
        ],
        _ => [
            (extent[0] * extent[1]).div_ceil(GAUSS_LOCAL_X),
            extent[2].div_ceil(segments.yz),
            1,
        ],
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::interface::assert_glsl_layout;

    #[test]
    fn packing_round_trips_and_pads_with_the_edge() {
        let data: Vec<f32> = (0..5 * 2 * 3).map(|i| i as f32).collect();
        let v = Volume::new([5, 2, 3], [1.0; 3], VoxelData::F32(data.clone())).unwrap();
        let packed = pack_rows(&v);
        assert_eq!(packed.len(), 8 * 2 * 3);
        assert_eq!(&packed[..8], &[0.0, 1.0, 2.0, 3.0, 4.0, 4.0, 4.0, 4.0]);
        assert_eq!(unpack_rows(&packed, v.dims), data);
    }

    #[test]
    fn push_constants_match_glsl() {
        assert_glsl_layout!(
            GaussPush,
            "importance.glsl",
            "GaussPush",
            [dims, axis, radius, pad]
        );
        assert_glsl_layout!(SubtractPush, "importance.glsl", "SubtractPush", [dims, pad]);
    }

    #[test]
    fn local_size_matches_glsl() {
        let src = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/glsl/common/importance.glsl"
        ))
        .unwrap();
        for (axis, n) in ["X", "Y", "Z"].iter().zip(LOCAL_SIZE) {
            assert!(
                src.contains(&format!("#define IMPORTANCE_LOCAL_{axis} {n}")),
                "IMPORTANCE_LOCAL_{axis} != {n}"
            );
        }
    }
}
