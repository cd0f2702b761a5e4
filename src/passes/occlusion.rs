//! The occlusion spectrum on compute (SPEC OS1–OS3, occlusion paper §3).
//!
//! Pass `occlusion` computes O(x), the mean of the visibility mapping M over a neighbourhood of
//! radius R. Pass `spectrum` is the 2D histogram of (intensity, occlusion).
//!
//! - **Ball neighbourhood:** exact and O(R²) per voxel rather than brute force's O(R³). A first
//!   dispatch maps M and writes its prefix sums along x. A second sums the ball as x-runs, one per
//!   (dy, dz) in the disk of radius R, each a difference of two prefix sums.
//! - **Gaussian neighbourhood:** O(R) per voxel, as three separable passes over (M, 1).
//! - **Resolution:** the output can be coarser than the data (`stride`). Each output voxel is exact
//!   at the input voxel it samples.
//! - **Neighbours outside the volume** are left out of both sum and count (the paper does not say;
//!   treating them as empty would darken every border).

pub use crate::classify::mapping::{parse_mapping, Neighbourhood};
use crate::error::{Error, Result};
use crate::gpu::commands::memory_transition;
use crate::gpu::pipeline::group_count;
use crate::gpu::profiler::PassTime;
use crate::gpu::resources::BufferLocation;
use crate::gpu::transfer::{record_readback, record_upload, staging_buffer};
use crate::gpu::{
    submit_once, Access, Bind, BindingKind, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, Profiler,
};
use crate::passes::volume_image::extent_of;
use crate::volume::reference::occlusion::Visibility;
use crate::volume::{Volume, VoxelData};
use ash::vk;
use std::sync::Arc;

/// Push constants of the occlusion passes (GLSL twin: `OcclusionPush` in occlusion.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct OcclusionPush {
    pub dims: [i32; 3],
    pub radius: i32,
    pub out_dims: [i32; 3],
    pub stride: i32,
    pub mapping: i32,
    pub axis: i32,
    pub t0: f32,
    pub t1: f32,
}

/// Push constants of the spectrum pass (GLSL twin: `SpectrumPush`).
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SpectrumPush {
    pub dims: [i32; 3],
    pub stride: i32,
    pub bins_x: i32,
    pub bins_y: i32,
    pub pad0: i32,
    pub pad1: i32,
}

/// Workgroup shape of the per-voxel passes (OCCLUSION_LOCAL_* in occlusion.glsl).
pub const LOCAL_SIZE: [u32; 3] = [64, 2, 2];

/// What to compute.
#[derive(Clone, Debug)]
pub struct OcclusionParams {
    pub radius: u32,
    pub visibility: Visibility,
    pub neighbourhood: Neighbourhood,
    /// Output voxel o samples input voxel o · stride (1 = full resolution).
    pub stride: u32,
    /// Spectrum bins (intensity, occlusion), or `None` for no spectrum.
    pub spectrum_bins: Option<[u32; 2]>,
}

/// The 2D histogram of (intensity, occlusion): `counts[o * bins[0] + i]`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Spectrum {
    pub bins: [u32; 2],
    pub counts: Vec<u32>,
    /// The data values at intensity 0 and 1.
    pub intensity_range: [f64; 2],
}

impl Spectrum {
    /// Writes the non-empty bins as CSV (intensity in data units, occlusion in [0, 1]), atomically.
    pub fn write_csv(&self, path: &std::path::Path) -> Result<()> {
        use std::io::Write;
        let [bx, by] = self.bins.map(|b| b as usize);
        let [lo, hi] = self.intensity_range;
        let width = (hi - lo) / bx as f64;
        crate::output::write_atomic(path, |w| {
            writeln!(
                w,
                "intensity_lo,intensity_hi,occlusion_lo,occlusion_hi,count"
            )?;
            for y in 0..by {
                for x in 0..bx {
                    let n = self.counts[y * bx + x];
                    if n > 0 {
                        let (o0, o1) = (y as f64 / by as f64, (y + 1) as f64 / by as f64);
                        writeln!(
                            w,
                            "{},{},{o0},{o1},{n}",
                            lo + x as f64 * width,
                            lo + (x + 1) as f64 * width
                        )?;
                    }
                }
            }
            Ok(())
        })
    }
}

/// Occlusion volume, spectrum and timings.
#[derive(Clone, Debug)]
pub struct OcclusionOutput {
    /// O in [0, 1], at the output resolution (spacing scaled by the stride).
    pub occlusion: Volume,
    pub spectrum: Option<Spectrum>,
    pub passes: Vec<PassTime>,
    pub intensity_range: [f64; 2],
}

/// The occlusion pipelines.
pub struct Occlusion {
    ctx: Arc<Context>,
    prefix: ComputePipeline,
    ball: ComputePipeline,
    gauss_axis: ComputePipeline,
    gauss_finish: ComputePipeline,
    to_float: ComputePipeline,
    spectrum: ComputePipeline,
}

impl Occlusion {
    /// Builds the pipelines.
    pub fn new(ctx: &Arc<Context>) -> Result<Self> {
        use BindingKind::*;
        let push = std::mem::size_of::<OcclusionPush>() as u32;
        Ok(Occlusion {
            ctx: ctx.clone(),
            prefix: ComputePipeline::new(
                ctx,
                "occlusion/prefix_x.comp",
                &[StorageImage, StorageImage, StorageImage, StorageBuffer],
                push,
            )?,
            ball: ComputePipeline::new(
                ctx,
                "occlusion/ball.comp",
                &[StorageImage, StorageImage],
                push,
            )?,
            gauss_axis: ComputePipeline::new(
                ctx,
                "occlusion/gauss_axis.comp",
                &[StorageImage, StorageImage, StorageImage],
                push,
            )?,
            gauss_finish: ComputePipeline::new(
                ctx,
                "occlusion/gauss_finish.comp",
                &[StorageImage, StorageImage],
                push,
            )?,
            to_float: ComputePipeline::new(
                ctx,
                "occlusion/to_float.comp",
                &[SampledImage, StorageImage],
                push,
            )?,
            spectrum: ComputePipeline::new(
                ctx,
                "occlusion/spectrum.comp",
                &[StorageImage, StorageImage, StorageBuffer],
                std::mem::size_of::<SpectrumPush>() as u32,
            )?,
        })
    }

    /// The context the pipelines were built on.
    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }

    /// Computes O for `v` (and the spectrum when asked): upload, the passes, readback.
    pub fn compute(&self, v: &Volume, p: &OcclusionParams) -> Result<OcclusionOutput> {
        let mut profiler = Profiler::new(&self.ctx, 1)?;
        let input = OcclusionInput::upload(&self.ctx, v, &mut profiler)?;
        let mut out = self.compute_on(&input, p)?;
        let mut passes = profiler.results()?;
        passes.append(&mut out.passes);
        out.passes = passes;
        Ok(out)
    }

    /// Computes O (and the spectrum when asked) for a volume already on the GPU and reads the
    /// results back. Occlusion selection and sensitivity call this many times on one upload.
    pub fn compute_on(
        &self,
        input: &OcclusionInput,
        p: &OcclusionParams,
    ) -> Result<OcclusionOutput> {
        let ctx = &self.ctx;
        let targets = self.targets(input, p)?;
        let readback = staging_buffer(ctx, "occlusion readback", targets.occlusion.byte_size())?;
        let mut profiler = Profiler::new(ctx, 3)?;
        submit_once(ctx, "occlusion", |cmd| {
            profiler.reset(cmd);
            self.record(cmd, &mut profiler, input, &targets, p)?;
            profiler.pass(cmd, "readback", |cmd| {
                record_readback(ctx, cmd, &targets.occlusion, &readback)
            });
            Ok(())
        })?;
        let passes = profiler.results()?;
        let o: Vec<f32> = bytemuck::pod_collect_to_vec(
            readback
                .mapped()
                .ok_or_else(|| Error::Invalid("readback buffer is not host-visible".into()))?,
        );
        let spacing = input.spacing.map(|s| s * p.stride as f64);
        let spectrum =
            match (&targets.spectrum, p.spectrum_bins) {
                (Some(h), Some(bins)) => Some(Spectrum {
                    bins,
                    counts: bytemuck::pod_collect_to_vec(h.mapped().ok_or_else(|| {
                        Error::Invalid("spectrum buffer is not host-visible".into())
                    })?),
                    intensity_range: input.range,
                }),
                _ => None,
            };
        Ok(OcclusionOutput {
            // Output voxel o samples input voxel o·stride: the same origin and directions, the
            // spacing scaled by the stride.
            occlusion: Volume::new(targets.out_dims, spacing, VoxelData::F32(o))?
                .with_geometry(input.geometry)?,
            spectrum,
            passes,
            intensity_range: input.range,
        })
    }

    /// Checks `p` and allocates the work images and buffers for `input`.
    pub fn targets(&self, input: &OcclusionInput, p: &OcclusionParams) -> Result<OcclusionTargets> {
        let ctx = &self.ctx;
        check_radius_stride(p.radius, p.stride)?;
        let extent = extent_of(ctx, input.dims, 4, 4)?;
        let out_dims: [usize; 3] = input.dims.map(|d| d.div_ceil(p.stride as usize));
        let r32 = |name: &str, e: [u32; 3]| {
            Image::new(ctx, name, &ImageDesc::new_3d(vk::Format::R32_SFLOAT, e))
        };
        let gauss = if p.neighbourhood == Neighbourhood::Gaussian {
            extent_of(ctx, input.dims, 16, 2)?;
            let rgba = |name: &str| {
                Image::new(
                    ctx,
                    name,
                    &ImageDesc::new_3d(vk::Format::R32G32B32A32_SFLOAT, extent),
                )
            };
            Some((rgba("occlusion gauss a")?, rgba("occlusion gauss b")?))
        } else {
            None
        };
        let table = match &p.visibility {
            Visibility::Table(t) => t.clone(),
            _ => vec![0f32; 256],
        };
        if table.len() != 256 {
            return Err(Error::Invalid(
                "a transfer-function visibility table needs 256 entries".into(),
            ));
        }
        let visibility = Buffer::from_bytes(
            ctx,
            "visibility table",
            vk::BufferUsageFlags::STORAGE_BUFFER,
            bytemuck::cast_slice(&table),
        )?;
        let spectrum = match p.spectrum_bins {
            Some([bx, by]) => {
                if bx == 0 || by == 0 || bx > 4096 || by > 4096 {
                    return Err(Error::Invalid(format!(
                        "spectrum bins {bx}x{by} are invalid; expected 1..=4096 each"
                    )));
                }
                Some(Buffer::new(
                    ctx,
                    "spectrum",
                    &BufferDesc {
                        size: bx as u64 * by as u64 * 4,
                        usage: vk::BufferUsageFlags::STORAGE_BUFFER
                            | vk::BufferUsageFlags::TRANSFER_DST
                            | vk::BufferUsageFlags::TRANSFER_SRC,
                        location: BufferLocation::Readback,
                    },
                )?)
            }
            None => None,
        };
        Ok(OcclusionTargets {
            prefix: r32("occlusion prefix", extent)?,
            mapped: r32("occlusion mapped", extent)?,
            occlusion: r32("occlusion", out_dims.map(|d| d as u32))?,
            gauss,
            visibility,
            spectrum,
            out_dims,
        })
    }

    /// Records pass `occlusion` (and `spectrum` when `targets` has a histogram) into `cmd`. The
    /// occlusion volume stays in `targets.occlusion`; its next user transitions it from the
    /// compute write (or the spectrum's read) to its own access.
    pub fn record(
        &self,
        cmd: vk::CommandBuffer,
        profiler: &mut Profiler,
        input: &OcclusionInput,
        targets: &OcclusionTargets,
        p: &OcclusionParams,
    ) -> Result<()> {
        let ctx = &self.ctx;
        let (mapping, t0, t1) = match &p.visibility {
            Visibility::Ramp => (0, 0.0, 1.0),
            Visibility::Truncated { t0, t1 } => (1, *t0, *t1),
            Visibility::Table(_) => (2, 0.0, 1.0),
        };
        let dims = input.dims.map(|d| d as i32);
        let extent = input.intensity.desc.extent;
        let out_extent = targets.occlusion.desc.extent;
        let push = OcclusionPush {
            dims,
            radius: p.radius as i32,
            out_dims: targets.out_dims.map(|d| d as i32),
            stride: p.stride as i32,
            mapping,
            axis: 0,
            t0,
            t1,
        };
        let (prefix, mapped, occlusion) = (&targets.prefix, &targets.mapped, &targets.occlusion);
        profiler.begin(cmd, "occlusion");
        input.intensity.transition(cmd, Access::ComputeRead);
        for img in [prefix, mapped, occlusion] {
            img.discard();
            img.transition(cmd, Access::ComputeWrite);
        }
        let rows = (input.dims[1] * input.dims[2]) as u32;
        self.prefix.dispatch(
            cmd,
            &[
                Bind::StorageImage(&input.intensity),
                Bind::StorageImage(prefix),
                Bind::StorageImage(mapped),
                Bind::StorageBuffer(&targets.visibility),
            ],
            &push,
            [rows.div_ceil(64), 1, 1],
        )?;
        match &targets.gauss {
            None => {
                prefix.transition(cmd, Access::ComputeRead);
                self.ball.dispatch(
                    cmd,
                    &[Bind::StorageImage(prefix), Bind::StorageImage(occlusion)],
                    &push,
                    [out_extent[0].div_ceil(64), out_extent[1], out_extent[2]],
                )?;
            }
            Some((a, b)) => {
                mapped.transition(cmd, Access::ComputeRead);
                // x: mapped → a, y: a → b, z: b → a. The x pass reads `mapped` and ignores
                // its `src` binding, which still needs an image: b, unwritten at that point.
                b.discard();
                for (axis, (src, dst)) in [(b, a), (a, b), (b, a)].into_iter().enumerate() {
                    src.transition(cmd, Access::ComputeRead);
                    dst.discard();
                    dst.transition(cmd, Access::ComputeWrite);
                    self.gauss_axis.dispatch(
                        cmd,
                        &[
                            Bind::StorageImage(mapped),
                            Bind::StorageImage(src),
                            Bind::StorageImage(dst),
                        ],
                        &OcclusionPush {
                            axis: axis as i32,
                            ..push
                        },
                        group_count(extent, LOCAL_SIZE),
                    )?;
                }
                a.transition(cmd, Access::ComputeRead);
                self.gauss_finish.dispatch(
                    cmd,
                    &[Bind::StorageImage(a), Bind::StorageImage(occlusion)],
                    &push,
                    group_count(out_extent, LOCAL_SIZE),
                )?;
            }
        }
        profiler.end(cmd);
        if let (Some(hist), Some([bx, by])) = (&targets.spectrum, p.spectrum_bins) {
            profiler.begin(cmd, "spectrum");
            occlusion.transition(cmd, Access::ComputeRead);
            unsafe {
                ctx.device
                    .cmd_fill_buffer(cmd, hist.raw, 0, vk::WHOLE_SIZE, 0)
            };
            memory_transition(ctx, cmd, Access::TransferWrite, Access::ComputeReadWrite);
            let sp = SpectrumPush {
                dims,
                stride: p.stride as i32,
                bins_x: bx as i32,
                bins_y: by as i32,
                pad0: 0,
                pad1: 0,
            };
            self.spectrum.dispatch(
                cmd,
                &[
                    Bind::StorageImage(&input.intensity),
                    Bind::StorageImage(occlusion),
                    Bind::StorageBuffer(hist),
                ],
                &sp,
                group_count(extent, LOCAL_SIZE),
            )?;
            memory_transition(ctx, cmd, Access::ComputeReadWrite, Access::HostRead);
            profiler.end(cmd);
        }
        Ok(())
    }

    /// Records pass `to_float`: the renderer's normalised R16 texture (sampled by compute with the
    /// nearest-texel `sampler`) into a new R32F [`OcclusionInput`], without a host round trip.
    pub fn record_input_from_texture(
        &self,
        cmd: vk::CommandBuffer,
        profiler: &mut Profiler,
        tex: &crate::passes::normals::VolumeTextures,
        sampler: &crate::gpu::Sampler,
    ) -> Result<OcclusionInput> {
        let (normalised, dims, spacing, range) = (&tex.intensity, tex.dims, tex.spacing, tex.range);
        let extent = extent_of(&self.ctx, dims, 4, 4)?;
        let intensity = Image::new(
            &self.ctx,
            "occlusion intensity",
            &ImageDesc::new_3d(vk::Format::R32_SFLOAT, extent),
        )?;
        profiler.begin(cmd, "to_float");
        normalised.transition(cmd, Access::ComputeSampled);
        intensity.discard();
        intensity.transition(cmd, Access::ComputeWrite);
        self.to_float.dispatch(
            cmd,
            &[
                Bind::Sampled(normalised, sampler),
                Bind::StorageImage(&intensity),
            ],
            &OcclusionPush {
                dims: dims.map(|d| d as i32),
                ..Default::default()
            },
            group_count(extent, LOCAL_SIZE),
        )?;
        intensity.transition(cmd, Access::ComputeRead);
        profiler.end(cmd);
        Ok(OcclusionInput {
            intensity,
            dims,
            spacing,
            geometry: tex.geometry,
            range,
        })
    }
}

/// The occlusion pass's input on the GPU: intensity normalised to [0, 1] as an R32F 3D image.
pub struct OcclusionInput {
    pub intensity: Image,
    pub dims: [usize; 3],
    pub spacing: [f64; 3],
    pub geometry: crate::volume::geometry::Geometry,
    /// The data values at 0 and 1.
    pub range: [f64; 2],
}

impl OcclusionInput {
    /// Uploads `v` normalised to [0, 1] in float (pass `upload`, one submission).
    pub fn upload(ctx: &Arc<Context>, v: &Volume, profiler: &mut Profiler) -> Result<Self> {
        let (intensity, range) = normalised_f32(v);
        let extent = extent_of(ctx, v.dims, 4, 4)?;
        let image = Image::new(
            ctx,
            "occlusion intensity",
            &ImageDesc::new_3d(vk::Format::R32_SFLOAT, extent),
        )?;
        let mut staging = staging_buffer(ctx, "occlusion staging", intensity.len() * 4)?;
        staging.write(bytemuck::cast_slice(&intensity))?;
        submit_once(ctx, "occlusion upload", |cmd| {
            profiler.reset(cmd);
            profiler.pass(cmd, "upload", |cmd| {
                record_upload(ctx, cmd, &staging, &image, Access::ComputeRead)
            });
            Ok(())
        })?;
        Ok(OcclusionInput {
            intensity: image,
            dims: v.dims,
            spacing: v.spacing,
            geometry: v.geometry,
            range,
        })
    }
}

/// Work images and buffers of one occlusion computation; `occlusion` holds the result.
pub struct OcclusionTargets {
    prefix: Image,
    mapped: Image,
    /// O in [0, 1] at the output resolution.
    pub occlusion: Image,
    gauss: Option<(Image, Image)>,
    visibility: Buffer,
    /// The spectrum's histogram (host-visible), when asked for.
    pub spectrum: Option<Buffer>,
    pub out_dims: [usize; 3],
}

/// Checks an occlusion radius (1..=1024 voxels) and output stride (1..=64), the same rule for
/// every command that takes them.
pub fn check_radius_stride(radius: u32, stride: u32) -> Result<()> {
    if radius == 0 || radius > 1024 {
        return Err(Error::Invalid(format!(
            "occlusion radius {radius} is invalid; expected 1..=1024 voxels"
        )));
    }
    if stride == 0 || stride > 64 {
        return Err(Error::Invalid(format!(
            "output stride {stride} is invalid; expected 1..=64"
        )));
    }
    Ok(())
}

/// The voxels of `v` mapped linearly from [min, max] to [0, 1] as f32, and that range.
pub fn normalised_f32(v: &Volume) -> (Vec<f32>, [f64; 2]) {
    use rayon::prelude::*;
    let s = crate::volume::stats::stats(v, 0);
    let scale = if s.max > s.min {
        1.0 / (s.max - s.min)
    } else {
        0.0
    };
    let out = (0..v.len())
        .into_par_iter()
        .map(|i| ((v.data.get_f64(i) - s.min) * scale) as f32)
        .collect();
    (out, [s.min, s.max])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::interface::assert_glsl_layout;

    #[test]
    fn push_constants_match_glsl() {
        assert_glsl_layout!(
            OcclusionPush,
            "occlusion.glsl",
            "OcclusionPush",
            [dims, radius, out_dims, stride, mapping, axis, t0, t1]
        );
        assert_glsl_layout!(
            SpectrumPush,
            "occlusion.glsl",
            "SpectrumPush",
            [dims, stride, bins_x, bins_y, pad0, pad1]
        );
    }
}
