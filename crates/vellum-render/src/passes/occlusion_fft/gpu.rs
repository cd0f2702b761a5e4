//! The FFT method on compute: a mixed-radix (2, 3, 4, 5) Stockham FFT in shared memory, one line
//! per workgroup (glsl/common/fft.glsl), organised as VkFFT organises its passes: one dispatch per
//! axis, the whole line resident in shared memory, no transposes.
//!
//! The fields live in 3D images rather than buffers: lavapipe binds at most 128 MiB of a storage
//! buffer, while a 256³ volume at R = 64 already needs a 132 MB half spectrum. Images have no
//! such limit (4096 per axis) and stay within the 2 GiB heap up to about 400³.
//!
//! Passes (x fastest, half = Px/2 + 1):
//! 1. `fft_x`: M (or the wrapped kernel) to half spectra along x, two real rows per complex
//!    transform.
//! 2. `fft_y` forward, in place.
//! 3. `fft_z`: for the kernel, the forward transform's real part is stored once; for the data,
//!    forward, product with the kernel spectrum and inverse are fused per line, and only the
//!    sampled planes are written to `result`.
//! 4. `fft_y` inverse on `result`, in place.
//! 5. `fft_x_inverse`: two sampled rows per complex transform, then the exact denominator.

use super::{check_pad, reach, Denominator, Kernel};
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::{
    Access, Bind, BindingKind, Buffer, ComputePipeline, Context, Frame, Image, ImageDesc,
};
use vellum_gpu::{CommandBuffer, Format};

/// Push constants of the FFT passes (GLSL twin: `FftPush` in occlusion.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct FftPush {
    /// Volume size N in voxels.
    pub dims: [i32; 3],
    /// `fft_x`: 0 data, 1 ball kernel, 2 Gaussian kernel; `fft_z`: 0 kernel spectrum, 1 convolve.
    pub mode: i32,
    /// Transform size P per axis.
    pub pad: [i32; 3],
    /// R in voxels.
    pub radius: i32,
    /// Rows (y) and planes (z) that hold data; those at or beyond are read as zero.
    pub(crate) live: [i32; 3],
    /// Output voxel o samples voxel o · stride.
    pub stride: i32,
    /// min(R, N − 1) per axis: how far the kernel reaches within the volume.
    pub(crate) reach: [i32; 3],
    /// Length of this pass's transforms (P along its axis).
    pub n: i32,
    /// Output size: N / stride, rounded up.
    pub(crate) out_dims: [i32; 3],
    /// Radix stages of a transform of length n.
    pub(crate) stages: i32,
    /// Radices of stages 0–7, 4 bits each, stage 0 in the lowest bits.
    pub(crate) radices0: i32,
    /// Radices of stages 8–15, packed as `radices0`.
    pub(crate) radices1: i32,
    /// Index in the twiddle table of the first twiddle of length n.
    pub(crate) twiddle_base: i32,
    /// The visibility mapping M: 0 linear ramp, 1 truncated ramp, 2 a transfer function's opacity.
    pub mapping: i32,
    /// The truncated ramp's lower cut-off, in normalised intensity.
    pub t0: f32,
    /// The truncated ramp's upper cut-off, in normalised intensity.
    pub t1: f32,
    /// 1 / (Px · Py · Pz): the normalisation of the inverse transform.
    pub norm: f32,
    /// −1 forward, +1 inverse: the sign of the twiddles' exponent.
    pub dir: f32,
    /// Boundary classes per axis of the exact denominator's table.
    pub(crate) classes: [i32; 3],
    /// Padding to 128 bytes, a multiple of the block's 16-byte std430 alignment.
    pub(crate) pad0: i32,
}

/// Longest transform: one line of complex f32 in 32 KiB of shared memory (FFT_MAX_N).
pub(crate) const MAX_LENGTH: usize = 4096;
/// Shared memory the passes declare.
pub(crate) const SHARED_BYTES: u32 = (MAX_LENGTH * 8) as u32;

/// The radix stages of a transform of length n: fours first, then 2, 3 and 5.
pub(crate) fn radices(mut n: usize) -> Vec<u32> {
    let mut out = Vec::new();
    for r in [4, 2, 3, 5] {
        while n.is_multiple_of(r) && n > 1 {
            out.push(r as u32);
            n /= r;
        }
    }
    out
}

/// Forward twiddles of every stage of length n (see fft.glsl for the indexing), in double
/// precision rounded to f32.
pub(crate) fn twiddles(n: usize) -> Vec<[f32; 2]> {
    let mut out = Vec::with_capacity(n.saturating_sub(1));
    let mut ns = 1usize;
    for r in radices(n) {
        let r = r as usize;
        for k in 0..ns {
            for i in 1..r {
                let a = -2.0 * std::f64::consts::PI * (i * k) as f64 / (ns * r) as f64;
                out.push([a.cos() as f32, a.sin() as f32]);
            }
        }
        ns *= r;
    }
    out
}

/// Bytes of device memory the GPU method holds for `dims` padded to `pad` (besides the input and
/// output images): the half spectrum, the kernel spectrum, the sampled-plane result and the
/// denominator table.
pub fn gpu_bytes(dims: [usize; 3], pad: [usize; 3], stride: usize, den_entries: usize) -> u64 {
    let half = (pad[0] / 2 + 1) as u64;
    let plane = half * pad[1] as u64;
    plane * pad[2] as u64 * 8
        + plane * pad[2] as u64 * 4
        + plane * dims[2].div_ceil(stride) as u64 * 8
        + den_entries as u64 * 4
}

/// The FFT pipelines.
pub struct FftGpu {
    x: ComputePipeline,
    y: ComputePipeline,
    z: ComputePipeline,
    x_inverse: ComputePipeline,
}

/// Why the GPU method cannot run on this device, if it cannot.
pub(crate) fn unavailable(ctx: &Context) -> Option<String> {
    if !ctx.info.storage_image_extended_formats {
        return Some(format!(
            "{} cannot store two-channel float images (shaderStorageImageExtendedFormats), which `method` fft-gpu needs; use `method` fft-cpu",
            ctx.info.name
        ));
    }
    if ctx.info.max_compute_shared_memory < SHARED_BYTES {
        return Some(format!(
            "{} offers {} bytes of compute shared memory but `method` fft-gpu needs {SHARED_BYTES}; use `method` fft-cpu",
            ctx.info.name, ctx.info.max_compute_shared_memory
        ));
    }
    None
}

impl FftGpu {
    /// Builds the four pipelines; refused where `unavailable` gives a reason.
    pub fn new(ctx: &Arc<Context>) -> Result<Self> {
        if let Some(why) = unavailable(ctx) {
            return Err(Error::Invalid(why));
        }
        use BindingKind::*;
        let push = std::mem::size_of::<FftPush>() as u32;
        let p = |name: &str, kinds: &[BindingKind]| ComputePipeline::new(ctx, name, kinds, push);
        Ok(FftGpu {
            x: p(
                "occlusion/fft_x.comp",
                &[StorageImage, StorageImage, StorageBuffer, StorageBuffer],
            )?,
            y: p("occlusion/fft_y.comp", &[StorageImage, StorageBuffer])?,
            z: p(
                "occlusion/fft_z.comp",
                &[StorageImage, StorageImage, StorageBuffer, StorageImage],
            )?,
            x_inverse: p(
                "occlusion/fft_x_inverse.comp",
                &[StorageImage, StorageImage, StorageBuffer, StorageBuffer],
            )?,
        })
    }

    /// Checks that `dims` padded to `pad` fits this device: transform lengths, image sizes and
    /// memory. The error names what it would need and the limit.
    pub fn check(
        ctx: &Context,
        dims: [usize; 3],
        pad: [usize; 3],
        stride: usize,
        den_entries: usize,
    ) -> Result<()> {
        if let Some(why) = unavailable(ctx) {
            return Err(Error::Invalid(why));
        }
        let longest = *pad.iter().max().unwrap_or(&0);
        let max_dim = ctx.info.max_image_dimension_3d as usize;
        if longest > MAX_LENGTH.min(max_dim) {
            return Err(Error::Invalid(format!(
                "`method` fft-gpu would need transforms of {longest} points (the volume plus the radius, padded to {pad:?}) but handles at most {}; use a smaller `radius` or `method` fft-cpu",
                MAX_LENGTH.min(max_dim)
            )));
        }
        let volume = dims.iter().map(|&d| d as u64).product::<u64>() * 4;
        let need = gpu_bytes(dims, pad, stride, den_entries) + 2 * volume;
        let heap = ctx.info.device_local_heap_bytes;
        if need > heap {
            return Err(Error::Invalid(format!(
                "`method` fft-gpu would need {:.0} MiB of device memory for {dims:?} padded to {pad:?} but {} has {:.0} MiB; use a smaller `radius` or `method` fft-cpu",
                need as f64 / 1048576.0,
                ctx.info.name,
                heap as f64 / 1048576.0
            )));
        }
        let entries = den_entries + dims.iter().sum::<usize>();
        if entries as u64 * 4 > ctx.info.max_storage_buffer_range as u64 {
            return Err(Error::Invalid(format!(
                "`method` fft-gpu would need a {:.0} MiB denominator table but {} binds at most {:.0} MiB; use a smaller `radius` or `method` fft-cpu",
                entries as f64 * 4.0 / 1048576.0,
                ctx.info.name,
                ctx.info.max_storage_buffer_range as f64 / 1048576.0
            )));
        }
        Ok(())
    }
}

/// The images and tables of one FFT occlusion configuration (dims, pad, kernel, stride). The
/// kernel spectrum is computed by the first recording and kept for the next.
pub struct FftWork {
    /// Volume size N in voxels.
    pub dims: [usize; 3],
    /// Transform size P per axis.
    pub pad: [usize; 3],
    /// The neighbourhood's kernel, whose spectrum is kept once recorded.
    pub kernel: Kernel,
    /// Output voxel o samples voxel o · stride.
    pub stride: usize,
    spectrum: Image,
    kernel_hat: Image,
    result: Image,
    twiddles: Buffer,
    /// (twiddle base, stages, radices0, radices1) per axis.
    lengths: [(i32, i32, i32, i32); 3],
    den: Buffer,
    classes: [usize; 3],
    /// Whether a recorded frame has filled `kernel_hat`.
    kernel_ready: bool,
}

impl FftWork {
    /// Allocates the images and tables for `dims` padded to `pad` (twiddles, radix plans, the exact
    /// denominator); refused where [`FftGpu::check`] refuses.
    pub fn new(
        ctx: &Arc<Context>,
        dims: [usize; 3],
        pad: [usize; 3],
        kernel: Kernel,
        stride: usize,
    ) -> Result<Self> {
        check_pad(dims, pad, kernel.radius())?;
        let den = Denominator::new(dims, kernel);
        FftGpu::check(ctx, dims, pad, stride, den.table.len())?;
        let half = (pad[0] / 2 + 1) as u32;
        let [py, pz] = [pad[1] as u32, pad[2] as u32];
        let nzo = dims[2].div_ceil(stride) as u32;
        let image =
            |name: &str, format, extent| Image::new(ctx, name, &ImageDesc::new_3d(format, extent));
        let mut table: Vec<[f32; 2]> = Vec::new();
        let mut lengths = [(0, 0, 0, 0); 3];
        for a in 0..3 {
            let n = pad[a];
            let base = match (0..a).find(|&b| pad[b] == n) {
                Some(b) => lengths[b].0,
                None => {
                    let base = table.len() as i32;
                    table.extend(twiddles(n));
                    base
                }
            };
            let r = radices(n);
            let pack = |s: &[u32]| s.iter().rev().fold(0i32, |acc, &r| (acc << 4) | r as i32);
            lengths[a] = (
                base,
                r.len() as i32,
                pack(&r[..r.len().min(8)]),
                pack(&r[r.len().min(8)..]),
            );
        }
        if table.is_empty() {
            table.push([1.0, 0.0]);
        }
        let mut den_words: Vec<u32> =
            Vec::with_capacity(dims.iter().sum::<usize>() + den.table.len());
        for a in 0..3 {
            den_words.extend(&den.class[a]);
        }
        den_words.extend(den.table.iter().map(|v| v.to_bits()));
        Ok(FftWork {
            dims,
            pad,
            kernel,
            stride,
            // RG32F: the half spectrum and the result are complex floats (re, im).
            // R32F: the kernel is real and even, so its spectrum is real.
            spectrum: image("fft spectrum", Format::R32G32_SFLOAT, [half, py, pz])?,
            kernel_hat: image("fft kernel spectrum", Format::R32_SFLOAT, [half, py, pz])?,
            result: image("fft result", Format::R32G32_SFLOAT, [half, py, nzo])?,
            twiddles: Buffer::storage_from_bytes(
                ctx,
                "fft twiddles",
                bytemuck::cast_slice(&table),
            )?,
            lengths,
            den: Buffer::storage_from_bytes(
                ctx,
                "fft denominator",
                bytemuck::cast_slice(&den_words),
            )?,
            classes: den.classes,
            kernel_ready: false,
        })
    }

    /// Whether this work serves (dims, pad, kernel, stride).
    pub(crate) fn serves(
        &self,
        dims: [usize; 3],
        pad: [usize; 3],
        kernel: Kernel,
        stride: usize,
    ) -> bool {
        self.dims == dims && self.pad == pad && self.kernel == kernel && self.stride == stride
    }
}

/// The visibility mapping as push-constant fields (mapping, t0, t1).
pub struct Mapping {
    /// 0 linear ramp, 1 truncated ramp, 2 a transfer function's opacity (the visibility table).
    pub mapping: i32,
    /// The truncated ramp's lower cut-off, in normalised intensity.
    pub t0: f32,
    /// The truncated ramp's upper cut-off, in normalised intensity.
    pub t1: f32,
}

impl FftGpu {
    fn push(&self, w: &FftWork, axis: usize, m: &Mapping) -> FftPush {
        let i = |v: [usize; 3]| v.map(|d| d as i32);
        let (base, stages, r0, r1) = w.lengths[axis];
        let r = w.kernel.radius();
        FftPush {
            dims: i(w.dims),
            mode: 0,
            pad: i(w.pad),
            radius: r as i32,
            live: i(w.dims),
            stride: w.stride as i32,
            reach: i([0, 1, 2].map(|a| reach(r, w.dims[a]))),
            n: w.pad[axis] as i32,
            out_dims: i(w.dims.map(|d| d.div_ceil(w.stride))),
            stages,
            radices0: r0,
            radices1: r1,
            twiddle_base: base,
            mapping: m.mapping,
            t0: m.t0,
            t1: m.t1,
            norm: (1.0 / (w.pad.iter().map(|&p| p as f64).product::<f64>())) as f32,
            dir: -1.0,
            classes: i(w.classes),
            pad0: 0,
        }
    }

    /// Records `fft_x` and the forward `fft_y` into the half spectrum: of the kernel (`mode` 1 or
    /// 2, every row live) or of M (`mode` 0, rows and planes beyond the volume left unwritten).
    fn forward_xy(
        &self,
        cmd: CommandBuffer,
        w: &FftWork,
        input: &MappedInput,
        mode: i32,
        live: [usize; 3],
    ) -> Result<()> {
        let MappedInput {
            intensity,
            visibility,
            mapping,
        } = *input;
        let s = &w.spectrum;
        let live = live.map(|d| d as i32);
        let half = (w.pad[0] / 2 + 1) as u32;
        s.discard();
        s.transition(cmd, Access::ComputeWrite);
        self.x.dispatch(
            cmd,
            &[
                Bind::StorageImage(intensity),
                Bind::StorageImage(s),
                Bind::StorageBuffer(&w.twiddles),
                Bind::StorageBuffer(visibility),
            ],
            &FftPush {
                mode,
                live,
                ..self.push(w, 0, mapping)
            },
            [(live[1] as u32).div_ceil(2), live[2] as u32, 1],
        )?;
        s.transition(cmd, Access::ComputeReadWrite);
        self.y.dispatch(
            cmd,
            &[Bind::StorageImage(s), Bind::StorageBuffer(&w.twiddles)],
            &FftPush {
                live,
                ..self.push(w, 1, mapping)
            },
            [half, live[2] as u32, 1],
        )?;
        s.transition(cmd, Access::ComputeRead);
        Ok(())
    }

    /// Records `fft_z` in `mode` 0 (kernel spectrum) or 1 (convolve into `result`).
    fn z_pass(
        &self,
        cmd: CommandBuffer,
        w: &FftWork,
        mapping: &Mapping,
        mode: i32,
        live: [usize; 3],
    ) -> Result<()> {
        let half = (w.pad[0] / 2 + 1) as u32;
        self.z.dispatch(
            cmd,
            &[
                Bind::StorageImage(&w.spectrum),
                Bind::StorageImage(&w.kernel_hat),
                Bind::StorageBuffer(&w.twiddles),
                Bind::StorageImage(&w.result),
            ],
            &FftPush {
                mode,
                live: live.map(|d| d as i32),
                ..self.push(w, 2, mapping)
            },
            [half, w.pad[1] as u32, 1],
        )
    }

    /// Records the passes: the kernel spectrum when `work` does not hold it yet, then O of
    /// `intensity` (normalised R32F) into `occlusion` (R32F, the output grid). `visibility` is the
    /// 256-entry opacity table of the tf mapping (bound for every mapping).
    pub fn record(
        &self,
        frame: &mut Frame,
        work: &mut FftWork,
        intensity: &Image,
        visibility: &Buffer,
        mapping: &Mapping,
        occlusion: &Image,
    ) -> Result<()> {
        let (cmd, w) = (frame.cmd, work);
        let half = (w.pad[0] / 2 + 1) as u32;
        let out = w.dims.map(|d| d.div_ceil(w.stride) as u32);
        let (k, res) = (&w.kernel_hat, &w.result);
        let input = MappedInput {
            intensity,
            visibility,
            mapping,
        };
        intensity.transition(cmd, Access::ComputeRead);
        if !w.kernel_ready {
            // Kernel: every row may hold weight, so nothing is pruned.
            let mode = match w.kernel {
                Kernel::Ball(_) => 1,
                Kernel::Gaussian(_) => 2,
            };
            self.forward_xy(cmd, w, &input, mode, w.pad)?;
            k.discard();
            k.transition(cmd, Access::ComputeWrite);
            res.transition(cmd, Access::ComputeWrite);
            self.z_pass(cmd, w, mapping, 0, w.pad)?;
            w.kernel_ready = true;
        }
        // Data: rows and planes beyond the volume are zero and never touched.
        self.forward_xy(cmd, w, &input, 0, w.dims)?;
        k.transition(cmd, Access::ComputeRead);
        res.discard();
        res.transition(cmd, Access::ComputeWrite);
        self.z_pass(cmd, w, mapping, 1, w.dims)?;
        res.transition(cmd, Access::ComputeReadWrite);
        self.y.dispatch(
            cmd,
            &[Bind::StorageImage(res), Bind::StorageBuffer(&w.twiddles)],
            &FftPush {
                live: w.pad.map(|d| d as i32),
                dir: 1.0,
                ..self.push(w, 1, mapping)
            },
            [half, out[2], 1],
        )?;
        res.transition(cmd, Access::ComputeRead);
        occlusion.discard();
        occlusion.transition(cmd, Access::ComputeWrite);
        self.x_inverse.dispatch(
            cmd,
            &[
                Bind::StorageImage(res),
                Bind::StorageImage(occlusion),
                Bind::StorageBuffer(&w.twiddles),
                Bind::StorageBuffer(&w.den),
            ],
            &self.push(w, 0, mapping),
            [out[1].div_ceil(2), out[2], 1],
        )
    }
}

/// The input of the forward transforms: the normalised intensity, the tf mapping's visibility
/// table and the mapping that turns one into M.
#[derive(Copy, Clone)]
struct MappedInput<'a> {
    intensity: &'a Image,
    visibility: &'a Buffer,
    mapping: &'a Mapping,
}

#[cfg(test)]
mod tests {
    use super::*;
    use vellum_gpu::interface::assert_glsl_layout;

    #[test]
    fn push_constants_match_glsl() {
        assert_glsl_layout!(
            FftPush,
            "occlusion.glsl",
            "FftPush",
            [
                dims,
                mode,
                pad,
                radius,
                live,
                stride,
                reach,
                n,
                out_dims,
                stages,
                radices0,
                radices1,
                twiddle_base,
                mapping,
                t0,
                t1,
                norm,
                dir,
                classes,
                pad0
            ]
        );
        assert_eq!(std::mem::size_of::<FftPush>(), 128);
    }

    #[test]
    fn radix_plans_cover_smooth_lengths() {
        for n in [1usize, 2, 3, 4, 5, 6, 48, 320, 360, 4096, 3125, 2187] {
            let r = radices(n);
            assert_eq!(r.iter().map(|&r| r as usize).product::<usize>(), n);
            assert!(r.len() <= 16);
            assert_eq!(twiddles(n).len(), n - 1);
        }
    }
}
