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
//! - **FFT convolution** (`passes::occlusion_fft`): the same O for either neighbourhood at a cost
//!   that does not grow with R, on the GPU (`FftGpu`) or the CPU (`fft-cpu`). [`Method`] picks one;
//!   `auto` follows the cost model in [`estimate_ms`].

pub use crate::classify::mapping::{parse_mapping, Neighbourhood};
use crate::passes::occlusion_fft::{
    cpu::{CpuFft, HalfSpectrum},
    gpu::{FftGpu, FftWork, Mapping},
    Denominator, Kernel,
};
use crate::passes::volume_image::extent_of;
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::commands::memory_transition;
use vellum_gpu::pipeline::group_count;
use vellum_gpu::profiler::PassTime;
use vellum_gpu::transfer::{record_readback, record_upload, staging_buffer};
use vellum_gpu::Format;
use vellum_gpu::{
    submit_timed, Access, Bind, BindingKind, Buffer, BufferDesc, ComputePipeline, Context, Frame,
    Image, ImageDesc,
};
use vellum_volume::reference::occlusion::Visibility;
use vellum_volume::{Volume, VoxelData};

/// Push constants of the occlusion passes (GLSL twin: `OcclusionPush` in occlusion.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct OcclusionPush {
    /// Input volume size in voxels.
    pub dims: [i32; 3],
    /// R in voxels.
    pub radius: i32,
    /// Output size: `dims` / `stride`, rounded up.
    pub(crate) out_dims: [i32; 3],
    /// Output voxel o covers input voxel o · stride.
    pub stride: i32,
    /// The visibility mapping M (SPEC OS2): 0 linear ramp, 1 truncated ramp, 2 a transfer
    /// function's opacity (the visibility table).
    pub mapping: i32,
    /// The Gaussian pass's axis: 0 x, 1 y, 2 z.
    pub axis: i32,
    /// The truncated ramp's lower cut-off, in normalised intensity.
    pub t0: f32,
    /// The truncated ramp's upper cut-off, in normalised intensity.
    pub t1: f32,
}

/// Push constants of the spectrum pass (GLSL twin: `SpectrumPush`).
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct SpectrumPush {
    /// Intensity volume size in voxels.
    pub dims: [i32; 3],
    /// The occlusion volume's stride: voxel p reads occlusion voxel p / stride.
    pub stride: i32,
    /// Intensity bins.
    pub(crate) bins_x: i32,
    /// Occlusion bins.
    pub(crate) bins_y: i32,
    /// Padding to a multiple of 16 bytes, the block's std430 alignment (from its ivec3).
    pub(crate) pad0: i32,
    /// Padding, as `pad0`.
    pub(crate) pad1: i32,
}

/// Workgroup shape of the per-voxel passes (OCCLUSION_LOCAL_* in occlusion.glsl).
pub(crate) const LOCAL_SIZE: [u32; 3] = [64, 2, 2];

/// How the neighbourhood sum is computed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// The cheapest by [`estimate_ms`] on this device.
    #[default]
    Auto,
    /// Direct sums on the GPU: x-runs of prefix sums for the ball (O(R²) per voxel), separable
    /// passes for the Gaussian (O(R)).
    Runs,
    /// FFT convolution on compute.
    FftGpu,
    /// FFT convolution on the CPU (realfft, rayon).
    FftCpu,
}

impl Method {
    /// The names [`Method::parse`] takes, as error messages list them.
    pub(crate) const NAMES: &'static str = "auto, runs, fft-gpu or fft-cpu";

    /// Parses a method name (`Method::NAMES`).
    pub fn parse(s: &str) -> Result<Self> {
        Ok(match s {
            "auto" => Method::Auto,
            "runs" => Method::Runs,
            "fft-gpu" => Method::FftGpu,
            "fft-cpu" => Method::FftCpu,
            _ => {
                return Err(Error::Invalid(format!(
                    "occlusion method '{s}' is unknown; expected {}",
                    Self::NAMES
                )))
            }
        })
    }

    /// The name [`Method::parse`] takes (kebab-case, as serialised).
    pub fn name(self) -> &'static str {
        match self {
            Method::Auto => "auto",
            Method::Runs => "runs",
            Method::FftGpu => "fft-gpu",
            Method::FftCpu => "fft-cpu",
        }
    }
}

/// Measured cost constants (BENCHMARKS.md, "Ambient occlusion by FFT").
struct Costs {
    /// ns per output voxel per x-run (ball runs).
    runs: f64,
    /// ns per voxel per tap, three separable passes (Gaussian runs).
    taps: f64,
    /// ns per padded point per log2(padded points), one transform (GPU FFT).
    fft_gpu: f64,
    /// ns per output voxel for what follows the passes on the host: mapping and copying the
    /// readback (on an H100's host: 50–60 ms for 256³ outputs, 670 ms for 512³, against 19 and
    /// 120 ms of FFT passes).
    readback: f64,
}

/// Costs on this device kind. The CPU kinds (lavapipe) were measured on the 2-core development
/// machine, their constants including the readback. The GPU kinds were measured on an H100
/// (`bench occlusion --methods runs,fft-gpu` on the bonsai and a 512³ phantom, BENCHMARKS.md "On
/// a GPU"): the runs pass took 0.0013–0.0018 ns per output voxel per disk row (R = 16..100), the
/// FFT passes 0.0065–0.010 ns per point per log2 per transform; the Gaussian neighbourhood's taps
/// were not measured there and stay scaled from the runs.
fn costs(device_type: &str) -> Costs {
    match device_type {
        "CPU" => Costs {
            runs: 1.9,
            taps: 3.0,
            fft_gpu: 4.3,
            readback: 0.0,
        },
        _ => Costs {
            runs: 0.0017,
            taps: 0.0014,
            fft_gpu: 0.0075,
            readback: 3.3,
        },
    }
}

/// The CPU FFT's constant: ns per padded point per log2(padded points) per transform, on one
/// core (measured on the development machine; divided by the rayon threads).
const FFT_CPU_NS: f64 = 0.3;

/// Estimated milliseconds of `method` (not `Auto`) for `dims` at radius and stride on a device
/// of `device_type`. Transforms: the forward of the data and the inverse count about 2.5 full
/// transforms with pruning, the kernel spectrum one more.
pub fn estimate_ms(
    method: Method,
    device_type: &str,
    dims: [usize; 3],
    p: &OcclusionParams,
) -> f64 {
    let c = costs(device_type);
    let r = p.radius as f64;
    let out: f64 = dims
        .iter()
        .map(|&d| d.div_ceil(p.stride as usize) as f64)
        .product();
    let voxels: f64 = dims.iter().map(|&d| d as f64).product();
    let pad = p
        .pad
        .unwrap_or_else(|| crate::passes::occlusion_fft::padded_dims(dims, p.radius));
    let points: f64 = pad.iter().map(|&d| d as f64).product();
    let transforms = 3.5 * points * points.log2().max(1.0);
    let ns = match method {
        Method::Runs => match p.neighbourhood {
            // The disk of runs, clipped by the volume's extent in y and z.
            Neighbourhood::Ball => {
                let (ry, rz) = (r.min(dims[1] as f64), r.min(dims[2] as f64));
                out * std::f64::consts::PI * ry * rz.max(1.0) * c.runs + out * c.readback
            }
            Neighbourhood::Gaussian => voxels * 3.0 * (2.0 * r + 1.0) * c.taps + out * c.readback,
        },
        Method::FftGpu => transforms * c.fft_gpu + out * c.readback,
        Method::FftCpu => transforms * FFT_CPU_NS / rayon::current_num_threads() as f64,
        Method::Auto => 0.0,
    };
    ns / 1e6
}

/// What to compute.
#[derive(Clone, Debug)]
pub struct OcclusionParams {
    /// R, the neighbourhood's radius in voxels (1..=1024, [`check_radius_stride`]).
    pub radius: u32,
    /// The visibility mapping M applied to normalised intensity (SPEC OS2).
    pub visibility: Visibility,
    /// Ball or Gaussian weights over the neighbourhood (SPEC OS2).
    pub neighbourhood: Neighbourhood,
    /// Output voxel o samples input voxel o · stride (1 = full resolution).
    pub stride: u32,
    /// Spectrum bins (intensity, occlusion), or `None` for no spectrum.
    pub spectrum_bins: Option<[u32; 2]>,
    /// How the neighbourhood sum is computed; `Auto` picks by [`estimate_ms`].
    pub method: Method,
    /// The FFT's padded size, when a sweep shares one larger than this radius needs.
    pub pad: Option<[usize; 3]>,
}

impl OcclusionParams {
    /// The ball of `radius` at full resolution under the ramp mapping, no spectrum, by `method`:
    /// the paper's plain occlusion, which benches and the method choice measure.
    pub fn ball(radius: u32, method: Method) -> Self {
        OcclusionParams {
            radius,
            visibility: Visibility::Ramp,
            neighbourhood: Neighbourhood::Ball,
            stride: 1,
            spectrum_bins: None,
            method,
            pad: None,
        }
    }
}

/// The 2D histogram of (intensity, occlusion): `counts[o * bins[0] + i]`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Spectrum {
    /// Bins along intensity and along occlusion.
    pub bins: [u32; 2],
    /// Voxels per bin, `bins[0] × bins[1]` of them, intensity fastest.
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
        vellum_volume::output::write_atomic(path, |w| {
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
    /// The (intensity, occlusion) histogram, when [`OcclusionParams::spectrum_bins`] asks for one.
    pub spectrum: Option<Spectrum>,
    /// Milliseconds of each pass in order: the GPU passes as the profiler timed them, or the CPU
    /// FFT's steps by wall clock.
    pub passes: Vec<PassTime>,
    /// The data values at normalised intensity 0 and 1.
    pub intensity_range: [f64; 2],
    /// The method that ran (never `Auto`).
    pub method: Method,
}

/// The CPU FFT's kernel spectrum, kept for the next computation with the same kernel and size.
struct CpuKernel {
    kernel: Kernel,
    dims: [usize; 3],
    pad: [usize; 3],
    spectrum: Arc<Vec<f32>>,
}

/// The CPU FFT's data spectrum, kept for a radius sweep over the same input and mapping.
struct CpuData {
    host: Arc<Vec<f32>>,
    visibility: Visibility,
    pad: [usize; 3],
    spectrum: Arc<HalfSpectrum>,
}

/// The occlusion pipelines.
pub struct Occlusion {
    ctx: Arc<Context>,
    /// Built on first use (compiling them costs time on lavapipe).
    fft: Option<FftGpu>,
    /// The GPU FFT's images and kernel spectrum of the last computation.
    fft_work: Option<FftWork>,
    cpu_kernel: Option<CpuKernel>,
    cpu_data: Option<CpuData>,
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
            fft: None,
            fft_work: None,
            cpu_kernel: None,
            cpu_data: None,
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
    pub fn compute(&mut self, v: &Volume, p: &OcclusionParams) -> Result<OcclusionOutput> {
        let (input, mut passes) = OcclusionInput::upload_timed(&self.ctx, v)?;
        let mut out = self.compute_on(&input, p)?;
        passes.append(&mut out.passes);
        out.passes = passes;
        Ok(out)
    }

    /// The method `p` asks for, with `Auto` resolved by [`estimate_ms`]: runs or the GPU FFT on
    /// a GPU; on a CPU device (lavapipe), the cheapest of the three. `gpu_only` leaves the CPU
    /// method out (a recorded frame cannot run it).
    pub fn choose(&self, dims: [usize; 3], p: &OcclusionParams, gpu_only: bool) -> Result<Method> {
        if p.method != Method::Auto {
            if gpu_only && p.method == Method::FftCpu {
                return Err(Error::Invalid(
                    "occlusion recorded into a frame runs on the GPU; `method` fft-cpu is for the occlusion commands".into(),
                ));
            }
            return Ok(p.method);
        }
        let ty = self.ctx.info.device_type.as_str();
        let mut best = (Method::Runs, estimate_ms(Method::Runs, ty, dims, p));
        let pad = p
            .pad
            .unwrap_or_else(|| crate::passes::occlusion_fft::padded_dims(dims, p.radius));
        let entries = crate::passes::occlusion_fft::denominator_entries(dims, p.radius);
        let mut candidates = Vec::new();
        if FftGpu::check(&self.ctx, dims, pad, p.stride as usize, entries).is_ok() {
            candidates.push(Method::FftGpu);
        }
        if !gpu_only && ty == "CPU" {
            candidates.push(Method::FftCpu);
        }
        for m in candidates {
            let ms = estimate_ms(m, ty, dims, p);
            if ms < best.1 {
                best = (m, ms);
            }
        }
        Ok(best.0)
    }

    /// Computes O (and the spectrum when asked) for a volume already on the GPU and reads the
    /// results back. Occlusion selection and sensitivity call this many times on one upload.
    pub fn compute_on(
        &mut self,
        input: &OcclusionInput,
        p: &OcclusionParams,
    ) -> Result<OcclusionOutput> {
        self.compute_within(input, p, None)
    }

    /// [`Occlusion::compute_on`], the occlusion read back over the box `keep` (first voxel and
    /// size, at stride 1) alone when given: a chunked pass keeps only its chunk of the box it
    /// reads with a halo, and so never holds the whole box's floats.
    pub(crate) fn compute_within(
        &mut self,
        input: &OcclusionInput,
        p: &OcclusionParams,
        keep: Option<([usize; 3], [usize; 3])>,
    ) -> Result<OcclusionOutput> {
        check_radius_stride(p.radius, p.stride)?;
        let method = self.choose(input.dims, p, false)?;
        if method == Method::FftCpu {
            let mut out = self.compute_cpu(input, p)?;
            if let Some((lo, size)) = keep {
                use vellum_volume::source::BoxSource;
                out.occlusion = out.occlusion.read_box(lo, size)?;
            }
            return Ok(out);
        }
        let ctx = &self.ctx.clone();
        let mut targets = self.targets_for(input, p, method)?;
        let readback = staging_buffer(ctx, "occlusion readback", targets.occlusion.byte_size())?;
        let ((), passes) = submit_timed(ctx, "occlusion", |f| {
            self.record(f, input, &mut targets, p)?;
            f.profiler.pass(f.cmd, "readback", |cmd| {
                record_readback(ctx, cmd, &targets.occlusion, &readback)
            });
            Ok(())
        })?;
        let floats = readback
            .mapped()
            .ok_or_else(|| Error::Invalid("readback buffer is not host-visible".into()))?;
        let (out_dims, o) = kept_floats(floats, targets.out_dims, keep)?;
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
        // The FFT work (with its kernel spectrum) serves the next call with the same shape.
        if let Some(work) = targets.fft {
            self.fft_work = Some(work);
        }
        Ok(OcclusionOutput {
            // Output voxel o samples input voxel o·stride: the same origin and directions, the
            // spacing scaled by the stride.
            occlusion: Volume::new(out_dims, spacing, VoxelData::F32(o))?
                .with_geometry(input.geometry)?,
            spectrum,
            passes,
            intensity_range: input.range,
            method,
        })
    }

    /// The FFT method on the CPU for an uploaded input (which keeps its host copy).
    fn compute_cpu(
        &mut self,
        input: &OcclusionInput,
        p: &OcclusionParams,
    ) -> Result<OcclusionOutput> {
        use crate::passes::occlusion_fft::{
            available_memory, check_cpu_memory, check_pad, padded_dims,
        };
        use rayon::prelude::*;
        let host = input.host.clone().ok_or_else(|| {
            Error::Invalid(
                "the CPU FFT needs the volume on the host; this input lives only on the GPU".into(),
            )
        })?;
        let dims = input.dims;
        let stride = p.stride as usize;
        let kernel = Kernel::new(p.neighbourhood, p.radius);
        let pad = p.pad.unwrap_or_else(|| padded_dims(dims, p.radius));
        check_pad(dims, pad, p.radius)?;
        check_cpu_memory(dims, pad, stride, available_memory())?;
        let mut passes = Vec::new();
        let mut timed = |name: &str, start: std::time::Instant| {
            passes.push(PassTime {
                name: name.to_string(),
                ms: start.elapsed().as_secs_f64() * 1e3,
            })
        };
        let fft = CpuFft::new(pad);
        let t = std::time::Instant::now();
        let cached = self.cpu_data.as_ref().and_then(|c| {
            (Arc::ptr_eq(&c.host, &host) && c.visibility == p.visibility && c.pad == pad)
                .then(|| c.spectrum.clone())
        });
        let data = match cached {
            Some(d) => d,
            None => {
                let mapped: Vec<f32> = host.par_iter().map(|&s| p.visibility.apply(s)).collect();
                let d = Arc::new(fft.data_spectrum(&mapped, dims));
                self.cpu_data = Some(CpuData {
                    host: host.clone(),
                    visibility: p.visibility.clone(),
                    pad,
                    spectrum: d.clone(),
                });
                d
            }
        };
        timed("fft forward (cpu)", t);
        let t = std::time::Instant::now();
        let cached = self.cpu_kernel.as_ref().and_then(|c| {
            (c.kernel == kernel && c.dims == dims && c.pad == pad).then(|| c.spectrum.clone())
        });
        let k = match cached {
            Some(k) => k,
            None => {
                let k = Arc::new(fft.kernel_spectrum(kernel, dims));
                self.cpu_kernel = Some(CpuKernel {
                    kernel,
                    dims,
                    pad,
                    spectrum: k.clone(),
                });
                k
            }
        };
        let den = Denominator::new(dims, kernel);
        timed("kernel (cpu)", t);
        let t = std::time::Instant::now();
        let o = fft.convolve(&data, &k, dims, &den, stride);
        timed("fft inverse (cpu)", t);
        let out_dims = dims.map(|d| d.div_ceil(stride));
        let spectrum = match p.spectrum_bins {
            Some(bins) => {
                check_bins(bins)?;
                let t = std::time::Instant::now();
                let counts = vellum_volume::reference::occlusion::spectrum(
                    &host,
                    dims,
                    &o,
                    out_dims,
                    stride,
                    bins.map(|b| b as usize),
                );
                timed("spectrum (cpu)", t);
                Some(Spectrum {
                    bins,
                    counts,
                    intensity_range: input.range,
                })
            }
            None => None,
        };
        Ok(OcclusionOutput {
            occlusion: Volume::new(
                out_dims,
                input.spacing.map(|s| s * p.stride as f64),
                VoxelData::F32(o),
            )?
            .with_geometry(input.geometry)?,
            spectrum,
            passes,
            intensity_range: input.range,
            method: Method::FftCpu,
        })
    }

    /// Checks `p` and allocates the work images and buffers for `input`, for a method that runs
    /// on the GPU.
    pub fn targets(
        &mut self,
        input: &OcclusionInput,
        p: &OcclusionParams,
    ) -> Result<OcclusionTargets> {
        check_radius_stride(p.radius, p.stride)?;
        let method = self.choose(input.dims, p, true)?;
        self.targets_for(input, p, method)
    }

    /// Builds the FFT pipelines if no earlier computation did.
    fn build_fft(&mut self) -> Result<()> {
        if self.fft.is_none() {
            self.fft = Some(FftGpu::new(&self.ctx)?);
        }
        Ok(())
    }

    fn targets_for(
        &mut self,
        input: &OcclusionInput,
        p: &OcclusionParams,
        method: Method,
    ) -> Result<OcclusionTargets> {
        let ctx = &self.ctx.clone();
        check_radius_stride(p.radius, p.stride)?;
        let extent = extent_of(ctx, input.dims, 4, 4)?;
        let out_dims: [usize; 3] = input.dims.map(|d| d.div_ceil(p.stride as usize));
        let fft = match method {
            Method::FftGpu => {
                self.build_fft()?;
                let kernel = Kernel::new(p.neighbourhood, p.radius);
                let pad = p.pad.unwrap_or_else(|| {
                    crate::passes::occlusion_fft::padded_dims(input.dims, p.radius)
                });
                let stride = p.stride as usize;
                let cached = self.fft_work.take();
                Some(match cached {
                    Some(w) if w.serves(input.dims, pad, kernel, stride) => w,
                    _ => {
                        drop(cached);
                        FftWork::new(ctx, input.dims, pad, kernel, stride)?
                    }
                })
            }
            _ => None,
        };
        // R32F: one float per voxel for M, its prefix sums along x and O; a prefix sum runs over a
        // whole row, beyond what 16 bits resolve.
        let r32 = |name: &str, e: [u32; 3]| {
            Image::new(ctx, name, &ImageDesc::new_3d(Format::R32_SFLOAT, e))
        };
        let gauss = if fft.is_none() && p.neighbourhood == Neighbourhood::Gaussian {
            extent_of(ctx, input.dims, 16, 2)?;
            // RGBA32F: the Gaussian passes carry (weighted M, weight) in r and g; RG32F
            // storage would need an optional device feature.
            let rgba = |name: &str| {
                Image::new(
                    ctx,
                    name,
                    &ImageDesc::new_3d(Format::R32G32B32A32_SFLOAT, extent),
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
        let visibility =
            Buffer::storage_from_bytes(ctx, "visibility table", bytemuck::cast_slice(&table))?;
        let spectrum = match p.spectrum_bins {
            Some([bx, by]) => {
                check_bins([bx, by])?;
                Some(Buffer::new(
                    ctx,
                    "spectrum",
                    &BufferDesc::storage(bx as u64 * by as u64 * 4).host_read(),
                )?)
            }
            None => None,
        };
        let (prefix, mapped) = match fft {
            Some(_) => (None, None),
            None => (
                Some(r32("occlusion prefix", extent)?),
                Some(r32("occlusion mapped", extent)?),
            ),
        };
        Ok(OcclusionTargets {
            prefix,
            mapped,
            occlusion: r32("occlusion", out_dims.map(|d| d as u32))?,
            gauss,
            fft,
            visibility,
            spectrum,
            out_dims,
        })
    }

    /// Records pass `occlusion` (and `spectrum` when `targets` has a histogram) into `cmd`. The
    /// occlusion volume stays in `targets.occlusion`; its next user transitions it from the
    /// compute write (or the spectrum's read) to its own access. The FFT method's work in
    /// `targets` remembers that its kernel spectrum is recorded.
    pub fn record(
        &self,
        frame: &mut Frame,
        input: &OcclusionInput,
        targets: &mut OcclusionTargets,
        p: &OcclusionParams,
    ) -> Result<()> {
        let (mapping, t0, t1) = match &p.visibility {
            Visibility::Ramp => (0, 0.0, 1.0),
            Visibility::Truncated { t0, t1 } => (1, *t0, *t1),
            Visibility::Table(_) => (2, 0.0, 1.0),
        };
        let cmd = frame.cmd;
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
        frame.profiler.begin(cmd, "occlusion");
        input.intensity.transition(cmd, Access::ComputeRead);
        if let Some(work) = &mut targets.fft {
            let fft = self.fft.as_ref().ok_or_else(|| {
                Error::Invalid(
                    "occlusion targets for the FFT were made without its pipelines".into(),
                )
            })?;
            fft.record(
                frame,
                work,
                &input.intensity,
                &targets.visibility,
                &Mapping { mapping, t0, t1 },
                &targets.occlusion,
            )?;
            frame.profiler.end(cmd);
            return self.record_spectrum(frame, input, targets, p);
        }
        let occlusion = &targets.occlusion;
        let (Some(prefix), Some(mapped)) = (&targets.prefix, &targets.mapped) else {
            return Err(Error::Invalid(
                "occlusion targets lack their work images".into(),
            ));
        };
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
        frame.profiler.end(cmd);
        self.record_spectrum(frame, input, targets, p)
    }

    /// Records pass `spectrum` when `targets` has a histogram.
    fn record_spectrum(
        &self,
        frame: &mut Frame,
        input: &OcclusionInput,
        targets: &OcclusionTargets,
        p: &OcclusionParams,
    ) -> Result<()> {
        let (ctx, cmd) = (&self.ctx, frame.cmd);
        let dims = input.dims.map(|d| d as i32);
        let extent = input.intensity.desc.extent;
        let occlusion = &targets.occlusion;
        if let (Some(hist), Some([bx, by])) = (&targets.spectrum, p.spectrum_bins) {
            frame.profiler.begin(cmd, "spectrum");
            occlusion.transition(cmd, Access::ComputeRead);
            vellum_gpu::commands::fill_buffer(ctx, cmd, hist, 0);
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
            frame.profiler.end(cmd);
        }
        Ok(())
    }

    /// Records pass `to_float`: the renderer's normalised R16 texture (sampled by compute with the
    /// nearest-texel `sampler`) into a new R32F [`OcclusionInput`], without a host round trip.
    pub(crate) fn record_input_from_texture(
        &self,
        frame: &mut Frame,
        tex: &crate::passes::normals::VolumeTextures,
        sampler: &vellum_gpu::Sampler,
    ) -> Result<OcclusionInput> {
        let (normalised, dims, spacing, range) = (&tex.intensity, tex.dims, tex.spacing, tex.range);
        let cmd = frame.cmd;
        let extent = extent_of(&self.ctx, dims, 4, 4)?;
        // R32F: the passes bind their input as an r32f storage image, one float per voxel.
        let intensity = Image::new(
            &self.ctx,
            "occlusion intensity",
            &ImageDesc::new_3d(Format::R32_SFLOAT, extent),
        )?;
        frame.profiler.begin(cmd, "to_float");
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
        frame.profiler.end(cmd);
        Ok(OcclusionInput {
            intensity,
            dims,
            spacing,
            geometry: tex.geometry,
            range,
            host: None,
        })
    }
}

/// The occlusion pass's input on the GPU: intensity normalised to [0, 1] as an R32F 3D image.
pub struct OcclusionInput {
    /// The normalised intensity, R32F, `dims` voxels.
    pub intensity: Image,
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// Physical size of a voxel along x, y, z.
    pub spacing: [f64; 3],
    /// Origin and directions of the volume, which the occlusion volume keeps.
    pub geometry: vellum_volume::geometry::Geometry,
    /// The data values at 0 and 1.
    pub range: [f64; 2],
    /// The same normalised intensities on the host, when the input was uploaded from there (the
    /// CPU FFT reads them).
    pub host: Option<Arc<Vec<f32>>>,
}

impl OcclusionInput {
    /// Uploads `v` normalised to [0, 1] in float (one submission).
    pub fn upload(ctx: &Arc<Context>, v: &Volume) -> Result<Self> {
        Ok(Self::upload_timed(ctx, v)?.0)
    }

    /// [`OcclusionInput::upload`] that also returns the time of its pass, `upload`.
    pub(crate) fn upload_timed(ctx: &Arc<Context>, v: &Volume) -> Result<(Self, Vec<PassTime>)> {
        Self::upload_in_range(ctx, v, None)
    }

    /// `OcclusionInput::upload_timed` normalised over `range` instead of `v`'s own [min, max]:
    /// a chunk of a larger volume is normalised as the whole volume is.
    pub fn upload_in_range(
        ctx: &Arc<Context>,
        v: &Volume,
        range: Option<[f64; 2]>,
    ) -> Result<(Self, Vec<PassTime>)> {
        let (input, staging) = Self::stage_in_range(ctx, v, range)?;
        let passes = input.upload_staged(ctx, &staging)?;
        Ok((input, passes))
    }

    /// The host's part of [`OcclusionInput::upload_in_range`] (no recording, so it may run
    /// beside another thread's passes): the normalised voxels in a staging buffer, the image
    /// allocated; [`OcclusionInput::upload_staged`] then copies them.
    pub(crate) fn stage_in_range(
        ctx: &Arc<Context>,
        v: &Volume,
        range: Option<[f64; 2]>,
    ) -> Result<(Self, vellum_gpu::Buffer)> {
        let (intensity, range) = normalised_f32_in(v, range);
        let extent = extent_of(ctx, v.dims, 4, 4)?;
        // R32F: the passes bind their input as an r32f storage image, one float per voxel.
        let image = Image::new(
            ctx,
            "occlusion intensity",
            &ImageDesc::new_3d(Format::R32_SFLOAT, extent),
        )?;
        let mut staging = staging_buffer(ctx, "occlusion staging", intensity.len() * 4)?;
        staging.write(bytemuck::cast_slice(&intensity))?;
        let input = OcclusionInput {
            intensity: image,
            dims: v.dims,
            spacing: v.spacing,
            geometry: v.geometry,
            range,
            host: Some(Arc::new(intensity)),
        };
        Ok((input, staging))
    }

    /// Pass `upload`: `staging` (from [`OcclusionInput::stage_in_range`]) into the image.
    pub(crate) fn upload_staged(
        &self,
        ctx: &Arc<Context>,
        staging: &vellum_gpu::Buffer,
    ) -> Result<Vec<PassTime>> {
        let ((), passes) = submit_timed(ctx, "occlusion upload", |f| {
            f.profiler.pass(f.cmd, "upload", |cmd| {
                record_upload(ctx, cmd, staging, &self.intensity, Access::ComputeRead)
            });
            Ok(())
        })?;
        Ok(passes)
    }
}

/// Work images and buffers of one occlusion computation; `occlusion` holds the result.
pub struct OcclusionTargets {
    prefix: Option<Image>,
    mapped: Option<Image>,
    /// O in [0, 1] at the output resolution.
    pub occlusion: Image,
    gauss: Option<(Image, Image)>,
    /// The FFT method's images, when it runs.
    fft: Option<FftWork>,
    visibility: Buffer,
    /// The spectrum's histogram (host-visible), when asked for.
    pub spectrum: Option<Buffer>,
    /// Size of the occlusion volume: the input's dims over the stride, rounded up.
    pub(crate) out_dims: [usize; 3],
}

/// Checks spectrum bins (1..=4096 each).
fn check_bins([bx, by]: [u32; 2]) -> Result<()> {
    if bx == 0 || by == 0 || bx > 4096 || by > 4096 {
        return Err(Error::Invalid(format!(
            "spectrum bins {bx}x{by} are invalid; expected 1..=4096 each"
        )));
    }
    Ok(())
}

/// Checks an occlusion radius (1..=1024 voxels) and output stride (1..=64), the same rule for
/// every command that takes them.
pub fn check_radius_stride(radius: u32, stride: u32) -> Result<()> {
    use crate::classify::otf::{MAX_OCCLUSION_RADIUS, MAX_OCCLUSION_STRIDE};
    if radius == 0 || radius > MAX_OCCLUSION_RADIUS {
        return Err(Error::Invalid(format!(
            "occlusion radius {radius} is invalid; expected 1..={MAX_OCCLUSION_RADIUS} voxels"
        )));
    }
    if stride == 0 || stride > MAX_OCCLUSION_STRIDE {
        return Err(Error::Invalid(format!(
            "output stride {stride} is invalid; expected 1..={MAX_OCCLUSION_STRIDE}"
        )));
    }
    Ok(())
}

/// The voxels of `v` mapped linearly from [min, max] to [0, 1] as f32, and that range.
pub fn normalised_f32(v: &Volume) -> (Vec<f32>, [f64; 2]) {
    normalised_f32_in(v, None)
}

/// [`normalised_f32`] over `range` when given (values outside it go below 0 or above 1).
pub(crate) fn normalised_f32_in(v: &Volume, range: Option<[f64; 2]>) -> (Vec<f32>, [f64; 2]) {
    use rayon::prelude::*;
    let [min, max] = range.unwrap_or_else(|| v.normalised_range());
    let scale = if max > min { 1.0 / (max - min) } else { 0.0 };
    let out = (0..v.len())
        .into_par_iter()
        .map(|i| ((v.data.get_f64(i) - min) * scale) as f32)
        .collect();
    (out, [min, max])
}

/// The floats of a volume of `dims` read back as `bytes`, or of its box `keep` (first voxel and
/// size) alone, row by row; with the dims of what they hold.
fn kept_floats(
    bytes: &[u8],
    dims: [usize; 3],
    keep: Option<([usize; 3], [usize; 3])>,
) -> Result<([usize; 3], Vec<f32>)> {
    let Some((lo, size)) = keep else {
        return Ok((dims, bytemuck::pod_collect_to_vec(bytes)));
    };
    let floats: &[f32] = bytemuck::try_cast_slice(bytes)
        .map_err(|e| Error::Invalid(format!("readback memory does not hold floats: {e}")))?;
    if floats.len() != dims.iter().product::<usize>() || (0..3).any(|a| lo[a] + size[a] > dims[a]) {
        return Err(Error::Invalid(format!(
            "a box at {lo:?} of {size:?} does not lie in the {dims:?} occlusion read back"
        )));
    }
    Ok((
        size,
        super::box_rows(floats, (dims[0], dims[1]), (lo, size)),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use vellum_gpu::interface::assert_glsl_layout;

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
