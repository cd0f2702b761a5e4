//! The spatial importance map on compute pipelines (SPEC IM1, paper §3.2).
//!
//! Reads a volume, writes ΔD = G∗V − V as float. Passes: `upload`, `gauss_x`, `gauss_y`, `gauss_z`,
//! `subtract`, `readback`, each timed. The volume lives in R32F 3D storage images rather than
//! buffers: lavapipe caps a storage-buffer binding at 128 MiB, and the paper's CT head is 312 MB in
//! float. Three images suffice: src → A (x), A → B (y), B → A (z), then A = A − src in place.

use crate::passes::volume_image::extent_of;
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;
use vellum_error::{Error, Result};
use vellum_gpu::commands::clear_image;
use vellum_gpu::pipeline::group_count;
use vellum_gpu::profiler::PassTime;
use vellum_gpu::transfer::{record_readback, record_upload, staging_buffer};
use vellum_gpu::Format;
use vellum_gpu::{
    submit_timed, Access, Bind, BindingKind, Buffer, ComputePipeline, Context, Frame, Frames,
    FramesDesc, Image, ImageDesc,
};
use vellum_volume::reference::gaussian::gaussian_kernel;
use vellum_volume::{Volume, VoxelData};

/// Push constants of `importance/gauss1d.comp` (GLSL twin: `GaussPush` in glsl/common/importance.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GaussPush {
    /// Volume size in voxels.
    pub dims: [i32; 3],
    /// The pass's axis: 0 x, 1 y, 2 z.
    pub axis: i32,
    /// R: taps −R..R.
    pub radius: i32,
    /// Padding to a multiple of 16 bytes, the block's std430 alignment (from its ivec3).
    pub pad: [i32; 3],
}

/// Push constants of `importance/subtract.comp` (GLSL twin: `SubtractPush`).
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct SubtractPush {
    /// Volume size in voxels.
    pub dims: [i32; 3],
    /// Padding to 16 bytes, the block's std430 alignment.
    pub pad: i32,
}

/// Workgroup shape, as IMPORTANCE_LOCAL_* in importance.glsl.
pub(crate) const LOCAL_SIZE: [u32; 3] = [64, 2, 2];

/// Texels (four voxels each) each Gaussian invocation filters along x (specialisation constant
/// SEGMENT_X). Measured on lavapipe: 3..6 are equal, 8 is slower.
pub(crate) const SEGMENT_X: u32 = 4;

/// Texels each Gaussian invocation filters along y or z (specialisation constant SEGMENT). Its
/// private array holds SEGMENT + 2R texels; lavapipe keeps such an array in vector registers only
/// up to about 23 entries (measured: at R = 10, SEGMENT 3 runs in half the time of SEGMENT 4), and
/// short segments beat long ones below that, so take 4 and shrink it for large radii.
pub(crate) fn segment(radius_voxels: u32) -> u32 {
    (23u32.saturating_sub(2 * radius_voxels)).clamp(1, 4)
}

/// Texels per Gaussian invocation: `yz` along y and z (SEGMENT), `x` along x (SEGMENT_X).
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct Segments {
    /// Texels each invocation filters along y or z (SEGMENT).
    pub(crate) yz: u32,
    /// Texels each invocation filters along x (SEGMENT_X).
    pub x: u32,
}

impl Segments {
    /// The lengths for a device of `device_type` at `radius_voxels`: lavapipe's (`segment`,
    /// `SEGMENT_X`) on a CPU; on a GPU, where the private array stays in registers, longer
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
pub(crate) const GAUSS_LOCAL_X: u32 = 64;

/// A normalised volume texture as the filters read it: the image, its size in voxels, and the
/// nearest-texel sampler it is read through.
#[derive(Copy, Clone)]
struct TextureSource<'a> {
    image: &'a Image,
    dims: [usize; 3],
    sampler: &'a vellum_gpu::Sampler,
}

/// Names of the three filter passes, by axis.
pub const GAUSS_PASSES: [&str; 3] = ["gauss_x", "gauss_y", "gauss_z"];

/// The compiled pipelines; build once, run on many volumes.
pub struct ImportanceMap {
    ctx: Arc<Context>,
    /// Gaussian pipelines and their weights by radius, built on first use: R is a
    /// specialisation constant.
    gauss: HashMap<u32, Gauss>,
    choice: KernelChoice,
    subtract: ComputePipeline,
    /// The bench's yardstick (`record_copy`).
    copy: ComputePipeline,
    pack: ComputePipeline,
    unpack: ComputePipeline,
}

/// ΔD where the renderer samples it: an R32F volume in normalised intensity units, and max |ΔD|
/// over the volume as the bits of a non-negative float in a storage buffer (never read back).
pub struct ImportanceVolume {
    /// ΔD = G∗V − V, R32F, one float per voxel.
    pub delta_d: Image,
    /// Max |ΔD| over the volume: one u32 holding the bits of a non-negative float, so that an
    /// atomic max finds it. The shaders read it; the host never does.
    pub max_abs: Buffer,
}

/// A chunk staged for [`ImportanceMap::run`] by `ImportanceMap::stage`; its ΔD comes back by
/// [`StagedImportance::delta_d`].
pub struct StagedImportance {
    images: ImportanceImages,
    staging: Buffer,
    dims: [usize; 3],
    spacing: [f64; 3],
    geometry: vellum_volume::geometry::Geometry,
}

impl StagedImportance {
    /// ΔD, once [`ImportanceMap::run`] has read it back (host work, beside other threads').
    pub fn delta_d(&self) -> Result<Volume> {
        Self::read(&self.staging, self.dims, self.spacing, self.geometry)
    }

    /// ΔD over the box `lo .. lo + size` of the chunk, read row by row from the readback
    /// without the whole chunk's first (a chunked pass keeps only its chunk of the box it
    /// reads with a halo); with the chunk's spacing.
    pub fn delta_d_in(&self, (lo, size): ([usize; 3], [usize; 3])) -> Result<Volume> {
        let packed = Self::packed(&self.staging)?;
        let (d, px) = (self.dims, self.dims[0].div_ceil(4) * 4);
        if packed.len() < px * d[1] * d[2] || (0..3).any(|a| lo[a] + size[a] > d[a]) {
            return Err(Error::Invalid(format!(
                "a box at {lo:?} of {size:?} does not lie in the {d:?} ΔD read back"
            )));
        }
        let kept = super::box_rows(packed, (px, d[1]), (lo, size));
        Volume::new(size, self.spacing, VoxelData::F32(kept))
    }

    /// The floats `staging` holds once read back (ΔD packed as `pack_rows` packs).
    fn packed(staging: &Buffer) -> Result<&[f32]> {
        let out = staging
            .mapped()
            .ok_or_else(|| Error::Invalid("readback buffer is not host-visible".into()))?;
        bytemuck::try_cast_slice(out)
            .map_err(|e| Error::Invalid(format!("readback memory does not hold floats: {e}")))
    }

    fn read(
        staging: &Buffer,
        dims: [usize; 3],
        spacing: [f64; 3],
        geometry: vellum_volume::geometry::Geometry,
    ) -> Result<Volume> {
        let delta = unpack_rows(Self::packed(staging)?, dims);
        Volume::new(dims, spacing, VoxelData::F32(delta))?.with_geometry(geometry)
    }
}

/// Which shaders filter along each axis.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum GaussKernel {
    /// `gauss1d.comp`: each invocation filters a segment of its line from a private array read
    /// straight from the image. Lavapipe's: its SIMD lanes gather, and shared memory gains nothing.
    Segments(Segments),
    /// `gauss_tile_x.comp` and `gauss_tile_yz.comp`: workgroup tiles staged through shared memory,
    /// the y pass's and the z pass's (see [`Tile`]). GPUs': a warp's loads are contiguous and the
    /// halo is read once per tile.
    /// `x` is the x pass's tile width in texels.
    Tiled {
        /// The x pass's tile width in texels.
        x: u32,
        /// The y pass's tile.
        y: Tile,
        /// The z pass's tile.
        z: Tile,
    },
}

/// The y and z passes' tile in `gauss_tile_yz.comp`: `tx` texels along x by `depth` lines across,
/// `length` outputs along the axis, filtered by `lanes` lanes per line.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct Tile {
    /// Texels along x the tile spans.
    pub tx: u32,
    /// Lines across the axis, side by side.
    pub depth: u32,
    /// Lanes that filter each line.
    pub lanes: u32,
    /// Outputs along the axis; a multiple of `lanes`.
    pub length: u32,
}

impl Tile {
    /// Bytes of shared memory the tile stages at `radius_voxels` (RGBA32F texels).
    pub(crate) fn shared_bytes(self, radius_voxels: u32) -> u32 {
        (self.length + 2 * radius_voxels) * self.depth * self.tx * 16
    }

    /// `VELLUM_GAUSS_TILE=TX,DEPTH,LANES,LENGTH`, for measuring.
    fn from_env() -> Option<Tile> {
        let v = std::env::var("VELLUM_GAUSS_TILE").ok()?;
        let n: Vec<u32> = v
            .split(',')
            .map(|x| x.trim().parse().ok())
            .collect::<Option<_>>()?;
        let &[tx, depth, lanes, length] = n.as_slice() else {
            return None;
        };
        let ok = tx * depth * lanes <= 1024 && lanes > 0 && length % lanes == 0;
        ok.then_some(Tile {
            tx,
            depth,
            lanes,
            length,
        })
    }
}

const fn tile(tx: u32, depth: u32, lanes: u32, length: u32) -> Tile {
    Tile {
        tx,
        depth,
        lanes,
        length,
    }
}

/// The x pass's tile width in texels (`gauss_tile_x.comp`): 32 was 1–4 % faster than 64 and 128 on
/// an H100, and 256 30 % slower (BENCHMARKS.md, "On a GPU").
const TILE_X: u32 = 32;

/// The tiles a GPU tries for the pass along `axis` (1 = y, 2 = z) at `radius_voxels`, best first;
/// the first that fits the device's shared memory is taken, and the last two fit lavapipe's
/// 32 KiB up to R = 32. Swept on an H100 over Table 1's CT head (BENCHMARKS.md, "On a GPU"): a
/// warp's loads cover few texels along x and several rows, the blocks a GPU's optimal tiling
/// stores together; and at larger radii each lane filters more outputs (a longer window per
/// halo) from a longer tile.
fn gpu_tiles(axis: usize, radius_voxels: u32) -> [Tile; 3] {
    let best = match (axis, radius_voxels) {
        (1, 0..=5) => tile(8, 1, 32, 64),
        (1, _) => tile(4, 1, 32, 128),
        (_, 0..=2) => tile(4, 8, 16, 64),
        _ => tile(8, 2, 16, 64),
    };
    [best, tile(32, 1, 8, 32), tile(16, 1, 8, 32)]
}

/// What [`ImportanceMap::set_kernel`] asks for.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum KernelChoice {
    /// Tiles on a GPU where they fit in its shared memory, segments on a CPU.
    Auto,
    /// [`GaussKernel::Segments`] on any device.
    Segments,
    /// [`GaussKernel::Tiled`] where a tile fits the device's shared memory, segments elsewhere.
    Tiled,
    /// This tile (segments where it does not fit).
    Tile(Tile),
}

impl GaussKernel {
    /// The kernel for `choice` on a device with `device_type` and `shared_bytes` of shared
    /// memory per workgroup, at `radius_voxels`. `VELLUM_GAUSS_KERNEL=segments|tiled` overrides
    /// `Auto`, for measuring. Tiles fall back to segments where no tile fits.
    pub fn choose(
        choice: KernelChoice,
        device_type: &str,
        shared_bytes: u32,
        radius_voxels: u32,
    ) -> GaussKernel {
        let segments = GaussKernel::Segments(Segments::choose(device_type, radius_voxels));
        let env = std::env::var("VELLUM_GAUSS_KERNEL").ok();
        let tiled = match choice {
            KernelChoice::Segments => false,
            KernelChoice::Tiled | KernelChoice::Tile(_) => true,
            KernelChoice::Auto => match env.as_deref() {
                Some("segments") => false,
                Some("tiled") => true,
                _ => device_type != "CPU",
            },
        };
        if !tiled {
            return segments;
        }
        let pick = |axis: usize| -> Option<Tile> {
            let tiles = match choice {
                KernelChoice::Tile(t) => vec![t],
                _ => Tile::from_env()
                    .into_iter()
                    .chain(gpu_tiles(axis, radius_voxels))
                    .collect(),
            };
            tiles
                .into_iter()
                .find(|t| t.shared_bytes(radius_voxels) <= shared_bytes)
        };
        // `VELLUM_GAUSS_TILE_X=N`, for measuring.
        let x = std::env::var("VELLUM_GAUSS_TILE_X")
            .ok()
            .and_then(|v| v.parse().ok())
            .filter(|n| (1..=256).contains(n))
            .unwrap_or(TILE_X);
        match (pick(1), pick(2)) {
            (Some(y), Some(z)) => GaussKernel::Tiled { x, y, z },
            _ => segments,
        }
    }

    /// Workgroups of the pass along `axis` over an image of `extent` texels (x holds four voxels
    /// per texel).
    pub(crate) fn groups(self, extent: [u32; 3], axis: usize) -> [u32; 3] {
        match (self, axis) {
            (GaussKernel::Segments(s), _) => gauss_groups(extent, axis, s),
            (GaussKernel::Tiled { x, .. }, 0) => [
                extent[0].div_ceil(x),
                extent[1].div_ceil(2),
                extent[2].div_ceil(2),
            ],
            (GaussKernel::Tiled { y, z, .. }, _) => {
                let (along, across, t) = if axis == 1 { (1, 2, y) } else { (2, 1, z) };
                [
                    extent[along].div_ceil(t.length),
                    extent[0].div_ceil(t.tx),
                    extent[across].div_ceil(t.depth),
                ]
            }
        }
    }
}

/// The Gaussian pipelines specialised for one radius, by axis (one and the same for segments), and
/// the weights.
#[derive(Clone)]
struct Gauss {
    axes: [Arc<ComputePipeline>; 3],
    weights: Arc<Buffer>,
    kernel: GaussKernel,
}

/// The images of the importance map for one volume size, kept on the GPU: `src` holds the volume
/// as float, four x-neighbours per RGBA32F texel (see `pack_rows`); after
/// [`ImportanceMap::record`], `a` holds ΔD in the same packing and `b` is scratch.
pub struct ImportanceImages {
    /// The volume as float, four x-neighbours per texel.
    pub src: Image,
    /// ΔD after [`ImportanceMap::record`], packed as `src`; a work image before.
    pub a: Image,
    /// Scratch for the filter passes.
    pub b: Image,
    /// The volume's size in voxels (the images are a quarter as wide, rounded up).
    pub dims: [usize; 3],
}

impl ImportanceImages {
    /// Allocates the three images for a volume of `dims`.
    pub fn new(ctx: &Arc<Context>, dims: [usize; 3]) -> Result<Self> {
        // Three float images; checked on the volume's own dims so that a refusal names them.
        ctx.check_image_3d(dims, 4, 3)?;
        // They hold four voxels per texel along x.
        let extent = extent_of(ctx, [dims[0].div_ceil(4), dims[1], dims[2]], 16, 3)?;
        // RGBA32F: four x-neighbours in float per texel, so that one fetch reads four voxels.
        let desc = ImageDesc::new_3d(Format::R32G32B32A32_SFLOAT, extent);
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
            choice: KernelChoice::Auto,
            subtract,
            copy: ComputePipeline::new(
                ctx,
                "importance/copy.comp",
                &[StorageImage, StorageImage],
                push,
            )?,
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

    /// Which Gaussian shaders to use from now on (default [`KernelChoice::Auto`]).
    pub fn set_kernel(&mut self, choice: KernelChoice) {
        if choice != self.choice {
            self.choice = choice;
            self.gauss.clear();
        }
    }

    /// The kernel the passes use at `radius_voxels`.
    pub fn kernel(&mut self, radius_voxels: u32) -> Result<GaussKernel> {
        Ok(self.gauss(radius_voxels)?.kernel)
    }

    /// The Gaussian pipelines and weights for `radius_voxels` (built on first use).
    fn gauss(&mut self, radius_voxels: u32) -> Result<Gauss> {
        if radius_voxels > MAX_RADIUS {
            return Err(Error::Invalid(format!(
                "radius {radius_voxels} is too large; the importance map supports R up to {MAX_RADIUS} voxels"
            )));
        }
        if let Some(g) = self.gauss.get(&radius_voxels) {
            return Ok(g.clone());
        }
        let taps: Vec<f32> = gaussian_kernel(radius_voxels)?
            .iter()
            .map(|&w| w as f32)
            .collect();
        let info = &self.ctx.info;
        let kernel = GaussKernel::choose(
            self.choice,
            &info.device_type,
            info.max_compute_shared_memory,
            radius_voxels,
        );
        let bindings = [
            BindingKind::StorageImage,
            BindingKind::StorageImage,
            BindingKind::StorageBuffer,
        ];
        let push = std::mem::size_of::<GaussPush>() as u32;
        let pipeline = |shader: &str, constants: &[u32]| -> Result<Arc<ComputePipeline>> {
            Ok(Arc::new(ComputePipeline::with_constants(
                &self.ctx, shader, &bindings, push, constants,
            )?))
        };
        let yz = |t: Tile| {
            pipeline(
                "importance/gauss_tile_yz.comp",
                &[radius_voxels, t.tx, t.depth, t.lanes, t.length],
            )
        };
        let axes = match kernel {
            GaussKernel::Segments(s) => {
                let p = pipeline("importance/gauss1d.comp", &[radius_voxels, s.yz, s.x])?;
                [p.clone(), p.clone(), p]
            }
            GaussKernel::Tiled { x, y, z } => [
                pipeline("importance/gauss_tile_x.comp", &[radius_voxels, x])?,
                yz(y)?,
                yz(z)?,
            ],
        };
        let g = Gauss {
            axes,
            kernel,
            weights: Arc::new(Buffer::storage_from_bytes(
                &self.ctx,
                "gaussian weights",
                bytemuck::cast_slice(&taps),
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

    /// Pass `copy`: the source volume's texels copied into `images.b` by `importance/copy.comp`,
    /// with subtract's images, workgroups and access and no arithmetic: the bandwidth a 1D pass
    /// (one volume read, one written) cannot beat, measured beside it. The driver's own copies are
    /// no such yardstick: on an H200 `vkCmdCopyImage` between these 3D images took 5.5 ms for the
    /// CT head's 311 MB, and `vkCmdCopyBuffer` of as many bytes 0.74 ms, where the passes take
    /// about 0.23 ms.
    fn record_copy(&self, frame: &mut Frame, images: &ImportanceImages) -> Result<()> {
        let (cmd, profiler) = (frame.cmd, &mut *frame.profiler);
        let (src, b) = (&images.src, &images.b);
        profiler.begin(cmd, "copy");
        src.transition(cmd, Access::ComputeRead);
        b.discard();
        b.transition(cmd, Access::ComputeWrite);
        let dims = images.dims.map(|d| d as i32);
        self.copy.dispatch(
            cmd,
            &[Bind::StorageImage(src), Bind::StorageImage(b)],
            &SubtractPush { dims, pad: 0 },
            group_count(src.desc.extent, LOCAL_SIZE),
        )?;
        profiler.end(cmd);
        Ok(())
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
            gauss.axes[axis].dispatch(
                cmd,
                &[
                    Bind::StorageImage(input),
                    Bind::StorageImage(output),
                    Bind::StorageBuffer(&gauss.weights),
                ],
                &push,
                gauss.kernel.groups(extent, axis),
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
    /// images are released once the frame completes. `intensity` is the renderer's texture
    /// (`VolumeTextures::intensity`) of `dims` voxels.
    pub(crate) fn record_from_texture(
        &mut self,
        frame: &mut Frame,
        intensity: &Image,
        dims: [usize; 3],
        sampler: &vellum_gpu::Sampler,
        radius_voxels: u32,
    ) -> Result<ImportanceVolume> {
        let source = TextureSource {
            image: intensity,
            dims,
            sampler,
        };
        let (delta_d, max_abs) = self.record_filter(frame, &source, radius_voxels, true)?;
        Ok(ImportanceVolume { delta_d, max_abs })
    }

    /// Records G∗V of a normalised volume texture (R16 or R32F, read texel by texel through the
    /// nearest-texel `sampler`) as an R32F volume on the same scale: `pack`, the three filter
    /// passes and `unpack`. Line extraction smooths noisy data with it.
    pub(crate) fn record_blur_of_texture(
        &mut self,
        frame: &mut Frame,
        source: &Image,
        dims: [usize; 3],
        sampler: &vellum_gpu::Sampler,
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
            // R32F: ΔD is signed, and G∗V keeps the volume's scale; one float per voxel, unpacked.
            &ImageDesc::new_3d(Format::R32_SFLOAT, extent_of(ctx, dims_in, 4, 1)?),
        )?;
        let max_abs = Buffer::new(ctx, "importance max", &vellum_gpu::BufferDesc::storage(4))?;
        frame.profiler.begin(cmd, "unpack");
        vellum_gpu::commands::fill_buffer(ctx, cmd, &max_abs, 0);
        vellum_gpu::commands::memory_transition(
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

    /// The images for `v` and a staging buffer holding `v` as float, packed four voxels per
    /// texel (paper step 1, in parallel, straight into the staging memory). Fails early on a bad
    /// radius, before any allocation.
    fn staged(&mut self, v: &Volume, radius_voxels: u32) -> Result<(ImportanceImages, Buffer)> {
        self.gauss(radius_voxels)?;
        let staged = Self::stage(&self.ctx, v)?;
        Ok((staged.images, staged.staging))
    }

    /// The host's part before a chunk's passes (no recording, so it may run beside another
    /// thread's passes): `v` checked, its images allocated and its voxels packed into a staging
    /// buffer.
    pub(crate) fn stage(ctx: &Arc<Context>, v: &Volume) -> Result<StagedImportance> {
        v.check_finite("the input volume")?;
        let images = ImportanceImages::new(ctx, v.dims)?;
        let mut staging = staging_buffer(ctx, "importance staging", images.src.byte_size())?;
        let mapped = staging
            .mapped_mut()
            .ok_or_else(|| Error::Invalid("staging buffer is not host-visible".into()))?;
        let floats: &mut [f32] = bytemuck::try_cast_slice_mut(mapped)
            .map_err(|e| Error::Invalid(format!("staging memory cannot hold floats: {e}")))?;
        pack_rows_into(v, floats);
        Ok(StagedImportance {
            images,
            staging,
            dims: v.dims,
            spacing: v.spacing,
            geometry: v.geometry,
        })
    }

    /// The passes of a staged chunk (upload, the filters, readback), in one submission: the
    /// only part that records, for the caller to serialise.
    pub fn run(&mut self, s: &StagedImportance, radius_voxels: u32) -> Result<Vec<PassTime>> {
        self.gauss(radius_voxels)?;
        let ctx = &self.ctx.clone();
        let ((), passes) = submit_timed(ctx, "importance map", |f| {
            let cmd = f.cmd;
            f.profiler.pass(cmd, "upload", |cmd| {
                record_upload(ctx, cmd, &s.staging, &s.images.src, Access::ComputeRead)
            });
            self.record(f, &s.images, radius_voxels)?;
            f.profiler.pass(cmd, "readback", |cmd| {
                record_readback(ctx, cmd, s.images.delta_d(), &s.staging)
            });
            Ok(())
        })?;
        Ok(passes)
    }

    /// Computes ΔD of `v` with radius `radius_voxels`: allocation, upload, the passes and
    /// readback, timed as the paper's "Total". With `copy_reference`, the submission also times a
    /// plain copy of one float volume (pass `copy`: `record_copy`), the bandwidth bound of a 1D
    /// pass.
    pub fn compute(
        &mut self,
        v: &Volume,
        radius_voxels: u32,
        copy_reference: bool,
    ) -> Result<ImportanceOutput> {
        let start = Instant::now();
        let ctx = &self.ctx.clone();
        let (images, staging) = self.staged(v, radius_voxels)?;
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
                self.record_copy(f, &images)?;
            }
            self.record(f, &images, radius_voxels)?;
            f.profiler.pass(cmd, "readback", |cmd| {
                record_readback(ctx, cmd, images.delta_d(), &staging)
            });
            Ok(())
        })?;
        let delta_d = StagedImportance::read(&staging, v.dims, v.spacing, v.geometry)?;
        Ok(ImportanceOutput {
            delta_d,
            passes,
            total_ms: start.elapsed().as_secs_f64() * 1e3,
        })
    }
}

impl ImportanceMap {
    /// Median GPU ms of `gauss_x`, `gauss_y`, `gauss_z`, `subtract` and a plain copy of the
    /// volume (`copy`, after each round: `record_copy`) under sustained load:
    /// `v` is uploaded once, then `submissions` submissions (and more until `WARM_SECONDS`
    /// have passed) each record `rounds` rounds of the four passes back to back, and the medians
    /// come from the last submission. A GPU lowers its clocks while the host works between
    /// frames (BENCHMARKS.md, "On a GPU"); this is the rate of a device kept busy, the yardstick
    /// for bandwidth.
    pub fn sustained(
        &mut self,
        v: &Volume,
        radius_voxels: u32,
        rounds: usize,
        submissions: usize,
    ) -> Result<[f64; 5]> {
        let ctx = &self.ctx.clone();
        let (images, staging) = self.staged(v, radius_voxels)?;
        submit_timed(ctx, "importance upload", |f| {
            record_upload(ctx, f.cmd, &staging, &images.src, Access::ComputeRead);
            for image in [&images.a, &images.b] {
                clear_image(ctx, f.cmd, image);
            }
            Ok(())
        })?;
        let desc = FramesDesc::one_shot("importance sustained", 5 * rounds as u32 + 4);
        let mut passes = Vec::new();
        // At least `submissions`, and on for half a second: after the host's packing the GPU
        // takes that long to raise its clocks again (seen on an H100: a CT-head pass ran at two
        // thirds of its rate through three submissions of 40 rounds right after the upload).
        let start = Instant::now();
        let mut done = 0;
        while done < submissions.max(1) || start.elapsed().as_secs_f64() < WARM_SECONDS {
            done += 1;
            let mut frames = Frames::new(ctx, &desc)?;
            frames.frame(|f| {
                (0..rounds.max(1)).try_for_each(|_| {
                    self.record(f, &images, radius_voxels)?;
                    self.record_copy(f, &images)
                })
            })?;
            passes = frames.finish()?;
        }
        let med = |name: &str| {
            let mut t: Vec<f64> = passes
                .iter()
                .filter(|p| p.name == name)
                .map(|p| p.ms)
                .collect();
            t.sort_by(f64::total_cmp);
            t.get(t.len() / 2).copied().unwrap_or(f64::NAN)
        };
        Ok([
            med(GAUSS_PASSES[0]),
            med(GAUSS_PASSES[1]),
            med(GAUSS_PASSES[2]),
            med("subtract"),
            med("copy"),
        ])
    }
}

/// How long [`ImportanceMap::sustained`] keeps the device busy before the submission it reports.
pub(crate) const WARM_SECONDS: f64 = 0.5;

/// Largest radius: R sizes private arrays in the shader (a specialisation constant).
pub(crate) const MAX_RADIUS: u32 = 32;

/// The voxels of `v` as f32, each x row padded to a multiple of four with its last voxel, so that
/// an RGBA32F texel holds four x-neighbours and padding behaves like the clamped border.
#[cfg(test)]
pub(crate) fn pack_rows(v: &Volume) -> Vec<f32> {
    let mut out = vec![0f32; v.dims[0].div_ceil(4) * 4 * v.dims[1] * v.dims[2]];
    pack_rows_into(v, &mut out);
    out
}

/// [`pack_rows`] into `out` (for example mapped staging memory), one parallel task per row.
pub(crate) fn pack_rows_into(v: &Volume, out: &mut [f32]) {
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
pub(crate) fn unpack_rows(packed: &[f32], dims: [usize; 3]) -> Vec<f32> {
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
pub(crate) fn gauss_groups(extent: [u32; 3], axis: usize, segments: Segments) -> [u32; 3] {
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

#[cfg(test)]
mod tests {
    use super::*;
    use vellum_gpu::interface::assert_glsl_layout;

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
            "/../../glsl/common/importance.glsl"
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
