//! Object-space lines on compute (SPEC TL5, issue 11): silhouettes and suggestive contours of
//! f = τ, appended to a bounded buffer through an atomic counter. The method and its CPU twin are
//! in `volume::lines`; `glsl/lines/extract.comp` follows it step by step, so the two segment sets
//! agree to float round-off.
//!
//! Two passes, so that the cost follows the cells near τ rather than the volume:
//! `glsl/lines/cells.comp` visits every cell with 8 texel fetches and compacts those whose
//! corners straddle τ into a list, whose header is the indirect dispatch of `extract.comp`; that
//! one then runs the per-vertex derivatives and the marching tetrahedra on dense workgroups of
//! surface cells only. The list holds every visited cell up to one storage binding's reach
//! (`maxStorageBufferRange`, 33 M cells on lavapipe); it is grown with the volume, never per
//! frame.
//!
//! The buffer holds at most `capacity` segments. The counter keeps counting past it, so an
//! overflow is reported with the number of segments lost, and memory is never overrun.

use crate::passes::occlusion::OcclusionInput;
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::commands::{memory_transition, update_buffer};
use vellum_gpu::pipeline::group_count;
use vellum_gpu::Format;
use vellum_gpu::{
    submit_once, submit_timed, Access, Bind, BindingKind, Buffer, BufferDesc, ComputePipeline,
    Context, Frame, Image, ImageDesc, PipelineCache, PipelineDesc, Sampler,
};
use vellum_volume::lines::{Eye, LineParams, Segment};
use vellum_volume::Volume;

/// Push constants of `extract` (GLSL twin: `LinesPush` in lines.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct LinesPush {
    /// Volume size in voxels along x, y, z.
    pub dims: [i32; 3],
    /// Visit every `stride`-th cell along each axis (1 all, 2 the interactive mode).
    pub stride: i32,
    /// Physical size of a voxel along x, y, z.
    pub spacing: [f32; 3],
    /// τ, on the normalised [0, 1] scale of the volume texture.
    pub iso: f32,
    /// w = 0: the unit direction towards the eye; w = 1: the eye's position. Both in the
    /// physical frame (index × spacing), as [`Eye`].
    pub eye: [f32; 4],
    /// Which lines: bit 0 silhouettes, bit 1 suggestive contours.
    pub kinds: i32,
    /// cos θ_c: suggestive contours closer than θ_c to facing the viewer are dropped.
    pub(crate) cos_c: f32,
    /// t_d: the least D_w κ_r (per physical unit²) a suggestive contour needs.
    pub(crate) derivative_threshold: f32,
    /// Segments the line buffer holds; the counter goes on past it.
    pub capacity: u32,
    /// Cells the straddling-cell list holds.
    pub(crate) cell_capacity: u32,
    /// seed.comp: 0 the previous segments, 1 the strided scan.
    pub(crate) seed_mode: u32,
    /// Padding to a multiple of 16 bytes, the block's std430 alignment.
    pub(crate) pad1: u32,
    /// Padding, as `pad1`.
    pub(crate) pad2: u32,
}

impl LinesPush {
    /// The push constants of an extraction from a `dims` volume into `out`, visiting every
    /// `stride`-th cell, from lists of `cell_capacity` cells.
    fn new(
        dims: [usize; 3],
        spacing: [f32; 3],
        eye: Eye,
        params: &LineParams,
        stride: u32,
        capacity: u32,
        cell_capacity: u32,
    ) -> Self {
        LinesPush {
            dims: dims.map(|d| d as i32),
            stride: stride as i32,
            spacing,
            iso: params.iso,
            eye: match eye {
                Eye::Direction(d) => [d[0], d[1], d[2], 0.0],
                Eye::Point(p) => [p[0], p[1], p[2], 1.0],
            },
            kinds: params.silhouettes as i32 | (params.suggestive as i32) << 1,
            cos_c: params.min_angle_deg.to_radians().cos(),
            derivative_threshold: params.derivative_threshold,
            capacity,
            cell_capacity,
            seed_mode: 0,
            pad1: 0,
            pad2: 0,
        }
    }
}

/// Push constants of `raster` (GLSL twin: `RasterPush` in lines.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct RasterPush {
    /// Voxel index → clip, column-major ([`RasterView::index_to_clip`]).
    pub(crate) index_to_clip: [[f32; 4]; 4],
    /// Linear depth of voxel index p: dot(p, xyz) + w, in box units ([`RasterView::depth_terms`]).
    pub depth: [f32; 4],
    /// x: depth bias in box units; y: the value of full coverage; z: the value of zero coverage;
    /// w unused ([`RasterView`]'s `bias`, `value` and `floor`).
    pub params: [f32; 4],
    /// x: segments the buffer holds; y, z: the edge image's width and height in pixels; w unused.
    pub(crate) capacity_size: [u32; 4],
}

/// Bytes before the first segment: the rasteriser's indirect dispatch (groups, 1, 1) and the
/// segment counter.
const HEADER: u64 = 16;
/// The header before extraction: no groups yet, no segments.
const HEADER_INIT: [u32; 4] = [0, 1, 1, 0];
/// Default capacity: 1 M segments (32 MiB).
pub const DEFAULT_CAPACITY: u32 = 1 << 20;
/// Most workgroups an indirect dispatch of the line passes asks for (`LINES_MAX_GROUPS` in
/// lines.glsl).
const LINES_MAX_GROUPS: u64 = 65535;
/// Rounds of the seeded traversal per frame: how many cells a line is followed, or a search
/// walks, from where the frame's seeds are. A line found in one frame seeds the next, so longer
/// lines complete over frames.
pub(crate) const SEED_ROUNDS: u32 = 16;
/// The seeded traversal also seeds every `SEED_STRIDE`-th cell along each axis that straddles τ,
/// so that lines appear where the previous frame had none.
pub(crate) const SEED_STRIDE: u32 = 8;
/// Most cells one round's frontier holds (16 MiB); more are counted and lost.
const FRONTIER_CELLS: u64 = 1 << 22;

/// What the seeded traversal keeps between frames.
struct SeedState {
    /// One bit per voxel: the cell entered a frontier in this frame.
    visited: Buffer,
    /// The frontiers of even and odd rounds (16-byte header = the round's indirect dispatch).
    frontier: [Buffer; 2],
    /// Cells a frontier holds.
    capacity: u32,
    voxels: u64,
}

impl SeedState {
    /// The traversal's buffers, in `slot`, grown when a volume of `voxels` needs more.
    fn ensure<'a>(
        ctx: &Arc<Context>,
        slot: &'a mut Option<SeedState>,
        voxels: u64,
    ) -> Result<&'a SeedState> {
        if slot.as_ref().is_none_or(|s| s.voxels < voxels) {
            let cells = voxels
                .min(FRONTIER_CELLS)
                .min((ctx.info.max_storage_buffer_range as u64 - HEADER) / 4)
                .max(1);
            let list = |name: &str| {
                Buffer::new(
                    ctx,
                    name,
                    &BufferDesc::storage(HEADER + 4 * cells).indirect(),
                )
            };
            *slot = Some(SeedState {
                visited: Buffer::new(
                    ctx,
                    "line seeds visited",
                    &BufferDesc::storage(4 * voxels.div_ceil(32)),
                )?,
                frontier: [list("line frontier even")?, list("line frontier odd")?],
                capacity: cells as u32,
                voxels,
            });
        }
        Ok(slot.as_ref().expect("allocated above"))
    }
}

/// What the segments in a line buffer were extracted from: the seeded traversal seeds from them
/// only when its own extraction matches.
#[derive(Clone, Copy, Debug, PartialEq)]
struct SeedKey {
    /// The source image, by [`Image::id`].
    values: u64,
    dims: [usize; 3],
    iso: u32,
    kinds: u32,
}

/// What line extraction keeps from frame to frame for one view (a window, a tool's run): the
/// segment buffer, the straddling-cell list (grown to the largest volume seen, never per frame),
/// the seeded traversal's buffers, and what the last extraction was from, so that the next one
/// seeds from its segments only when they match. Its owner lends it by `&mut` to each frame.
pub struct LineState {
    /// The segments of the last extraction, read after its frame completes.
    pub buffer: LineBuffer,
    cells: Option<Buffer>,
    seed: Option<SeedState>,
    last: Option<SeedKey>,
}

impl LineState {
    /// A state whose buffer holds up to `capacity` segments.
    pub fn new(ctx: &Arc<Context>, capacity: u32) -> Result<Self> {
        Ok(LineState {
            buffer: LineBuffer::new(ctx, capacity)?,
            cells: None,
            seed: None,
            last: None,
        })
    }

    /// The straddling-cell list in `slot`, grown to hold `needed` bytes.
    fn cells<'a>(
        ctx: &Arc<Context>,
        slot: &'a mut Option<Buffer>,
        needed: u64,
    ) -> Result<&'a Buffer> {
        if slot.as_ref().is_none_or(|b| b.size < needed) {
            *slot = Some(Buffer::new(
                ctx,
                "line cells",
                &BufferDesc::storage(needed).indirect(),
            )?);
        }
        Ok(slot.as_ref().expect("allocated above"))
    }
}

/// The extracted lines.
#[derive(Clone, Debug)]
pub struct LineSet {
    /// The segments the buffer kept, in voxel index coordinates (at most its capacity).
    pub segments: Vec<Segment>,
    /// Segments found, including those the buffer could not hold.
    pub found: u64,
    /// GPU milliseconds of the smoothing and the extraction (the Hessian's precomputation apart).
    pub ms: f64,
    /// The Hessian's precomputation (0 when taken on the fly).
    pub hessian_ms: f64,
}

impl LineSet {
    /// Whether more segments were found than the buffer could keep.
    pub fn overflowed(&self) -> bool {
        self.found > self.segments.len() as u64
    }
}

/// The segment buffer: a counter and `capacity` segments, readable by the host.
pub struct LineBuffer {
    /// Host-readable storage: the 16-byte header (the raster's indirect dispatch, the counter),
    /// then the segments.
    pub buffer: Buffer,
    /// Segments the buffer holds after its header.
    pub capacity: u32,
}

impl LineBuffer {
    /// A buffer of `capacity` segments; refused when `capacity` is 0 or the buffer would exceed
    /// one storage binding's reach on this device.
    pub fn new(ctx: &Arc<Context>, capacity: u32) -> Result<Self> {
        let bytes = HEADER + capacity as u64 * std::mem::size_of::<Segment>() as u64;
        if capacity == 0 || bytes > ctx.info.max_storage_buffer_range as u64 {
            return Err(Error::Invalid(format!(
                "a line buffer of {capacity} segments is invalid; {} binds at most {} segments",
                ctx.info.name,
                (ctx.info.max_storage_buffer_range as u64 - HEADER)
                    / std::mem::size_of::<Segment>() as u64
            )));
        }
        Ok(LineBuffer {
            buffer: Buffer::new(
                ctx,
                "line segments",
                &BufferDesc::storage(bytes).indirect().host_read(),
            )?,
            capacity,
        })
    }

    /// The segments and the count after the recorded work has completed.
    pub fn read(&self) -> Result<(Vec<Segment>, u64)> {
        let bytes = self
            .buffer
            .mapped()
            .ok_or_else(|| Error::Invalid("the line buffer is not host-visible".into()))?;
        let found = u32::from_le_bytes([bytes[12], bytes[13], bytes[14], bytes[15]]) as u64;
        let kept = found.min(self.capacity as u64) as usize;
        let size = std::mem::size_of::<Segment>();
        let start = HEADER as usize;
        Ok((
            bytemuck::pod_collect_to_vec(&bytes[start..start + kept * size]),
            found,
        ))
    }
}

/// The extraction and drawing passes. The pipelines of the extraction proper come from the
/// caller's [`PipelineCache`], built on first use (they compile slowly on lavapipe and many runs
/// never need them): per kinds (1 silhouettes, 2 suggestive contours, 3 both), since the kind is
/// a specialisation constant and a frame that draws one kind does not run the other's code (a
/// CPU rasteriser would run it masked in every lane); `extract_hessian.comp` for a
/// `HessianVolume`; `hessian.comp`; and the seeded traversal's `seed.comp` and
/// `extract_seeded.comp`. What a view keeps between frames is in its [`LineState`].
pub struct LineExtractor {
    ctx: Arc<Context>,
    /// Pass 1: the cells that straddle τ, compacted into the state's cell list (16-byte header =
    /// the indirect dispatch of `extract`).
    cells_pass: ComputePipeline,
    raster: ComputePipeline,
    nearest: Sampler,
    /// The Gaussian passes that smooth a volume for [`LineParams::smooth`].
    smoother: crate::passes::importance::ImportanceMap,
}

const LINES_PUSH: u32 = std::mem::size_of::<LinesPush>() as u32;
const EXTRACT_BINDINGS: [BindingKind; 3] = [
    BindingKind::SampledImage,
    BindingKind::StorageBuffer,
    BindingKind::StorageBuffer,
];
/// `label_indicator.comp`: the label voxels, the field.
const FIELD_BINDINGS: [BindingKind; 2] = [BindingKind::StorageBuffer, BindingKind::StorageImage];

const EXTRACT_HESSIAN_BINDINGS: [BindingKind; 5] = [
    BindingKind::SampledImage,
    BindingKind::StorageBuffer,
    BindingKind::StorageBuffer,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
];
const HESSIAN_BINDINGS: [BindingKind; 3] = [
    BindingKind::SampledImage,
    BindingKind::StorageImage,
    BindingKind::StorageImage,
];
const SEED_BINDINGS: [BindingKind; 4] = [
    BindingKind::SampledImage,
    BindingKind::StorageBuffer,
    BindingKind::StorageBuffer,
    BindingKind::StorageBuffer,
];
const ROUND_BINDINGS: [BindingKind; 5] = [
    BindingKind::SampledImage,
    BindingKind::StorageBuffer,
    BindingKind::StorageBuffer,
    BindingKind::StorageBuffer,
    BindingKind::StorageBuffer,
];

/// Where the extraction takes the Hessian of f from (issue 11 asks for both, measured).
#[derive(Copy, Clone, Debug, PartialEq, Eq, Default)]
pub enum HessianSource {
    /// Central differences of the volume at every cell corner: 19 texel fetches a corner, no
    /// memory beside the volume. What the renderers use (BENCHMARKS.md says why).
    #[default]
    OnTheFly,
    /// Read from a `HessianVolume` made once per volume: 6 fetches of the volume (the
    /// gradient) and 2 of the Hessian a corner, for 32 bytes a voxel.
    Precomputed,
}

impl HessianSource {
    /// Parses `on-the-fly` or `precomputed`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "on-the-fly" => Ok(HessianSource::OnTheFly),
            "precomputed" => Ok(HessianSource::Precomputed),
            _ => Err(Error::Invalid(format!(
                "unknown Hessian source '{s}'; expected on-the-fly or precomputed"
            ))),
        }
    }

    /// The name [`HessianSource::parse`] takes.
    pub fn name(self) -> &'static str {
        match self {
            HessianSource::OnTheFly => "on-the-fly",
            HessianSource::Precomputed => "precomputed",
        }
    }
}

/// The Hessian of a line extraction's volume, per voxel and in physical units: (hxx, hyy, hzz,
/// hxy) in `a` and (hxz, hyz, 0, 0) in `b`, both RGBA32F (RG32F storage would need an optional
/// device feature).
pub(crate) struct HessianVolume {
    /// (hxx, hyy, hzz, hxy) per voxel.
    pub a: Image,
    /// (hxz, hyz, 0, 0) per voxel.
    pub b: Image,
}

/// Where the lines are drawn: the frame's geometry, in the renderer's box frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RasterView {
    /// Box → clip.
    pub view_proj: [[f32; 4]; 4],
    /// box = index · scale + offset, per axis.
    pub index_scale: [f32; 3],
    /// The offset of index → box per axis, in box units.
    pub index_offset: [f32; 3],
    /// The eye in the box frame; linear depth is measured from it.
    pub eye: [f32; 3],
    /// The unit view direction in the box frame, along which linear depth is measured.
    pub view_dir: [f32; 3],
    /// Depth bias in box units: a line pixel is drawn up to this far behind the focus.
    pub bias: f32,
    /// The value written to the edge image where a line covers a pixel fully, and what zero
    /// coverage is worth there: a pixel of coverage c gets floor + c · (value − floor), unless
    /// it already holds more.
    pub value: f32,
    /// The value of zero coverage (see `value`): 0 on a plain edge image, 1 on Canny's classes.
    pub floor: f32,
}

impl RasterView {
    /// Voxel index → clip: the renderer's box → clip after index → box (a scale and an offset
    /// per axis).
    pub(crate) fn index_to_clip(&self) -> glam::Mat4 {
        let (sc, off) = (
            glam::Vec3::from_array(self.index_scale),
            glam::Vec3::from_array(self.index_offset),
        );
        glam::Mat4::from_cols_array_2d(&self.view_proj)
            * glam::Mat4::from_translation(off)
            * glam::Mat4::from_scale(sc)
    }

    /// The linear depth of voxel index p is `dot(p, coef) + constant` (box units, as focus.depth).
    pub(crate) fn depth_terms(&self) -> ([f32; 3], f32) {
        let vd = glam::Vec3::from_array(self.view_dir);
        let coef = glam::Vec3::from_array(self.index_scale) * vd;
        let constant =
            (glam::Vec3::from_array(self.index_offset) - glam::Vec3::from_array(self.eye)).dot(vd);
        (coef.to_array(), constant)
    }

    /// The pieces of `s` that pass the rasteriser's depth test against `focus_depth` (`size`
    /// pixels, rows top to bottom), as polylines in pixel coordinates, for vector output: the
    /// segment's centre line sampled once a pixel along its major axis, each sample tested by
    /// raster.comp's rule in the pixel it falls in. (raster.comp tests every pixel its
    /// antialiased footprint covers, so a raster line may reach a pixel further at a piece's end.)
    pub fn visible_pieces(
        &self,
        s: &Segment,
        focus_depth: &[f32],
        size: [u32; 2],
    ) -> Vec<Vec<[f32; 2]>> {
        let m = self.index_to_clip();
        let (coef, constant) = self.depth_terms();
        let mut ends = [[0f32; 2]; 2];
        let mut depth = [0f32; 2];
        for (k, p) in [s.a, s.b].iter().enumerate() {
            let clip = m * glam::Vec4::new(p[0], p[1], p[2], 1.0);
            if clip.w <= 0.0 {
                return Vec::new();
            }
            ends[k] = [
                (clip.x / clip.w * 0.5 + 0.5) * size[0] as f32,
                (clip.y / clip.w * 0.5 + 0.5) * size[1] as f32,
            ];
            depth[k] = p[0] * coef[0] + p[1] * coef[1] + p[2] * coef[2] + constant;
        }
        let d = [ends[1][0] - ends[0][0], ends[1][1] - ends[0][1]];
        let steps = d[0].abs().max(d[1].abs()).ceil().clamp(1.0, 4096.0) as u32;
        let mut pieces: Vec<Vec<[f32; 2]>> = Vec::new();
        let mut open = false;
        for i in 0..=steps {
            let t = i as f32 / steps as f32;
            let q = [ends[0][0] + t * d[0], ends[0][1] + t * d[1]];
            let (x, y) = (q[0].floor() as i64, q[1].floor() as i64);
            let inside = x >= 0 && y >= 0 && x < size[0] as i64 && y < size[1] as i64;
            let z = depth[0] + t * (depth[1] - depth[0]);
            let shown = inside
                && z <= focus_depth[(y as usize) * size[0] as usize + x as usize] + self.bias;
            match (shown, open) {
                (true, false) => pieces.push(vec![q]),
                (true, true) => {
                    if let Some(last) = pieces.last_mut() {
                        last.push(q);
                    }
                }
                _ => {}
            }
            open = shown;
        }
        pieces.retain(|p| p.len() > 1);
        pieces
    }
}

/// A label volume's segments as line extraction reads them ([`LineExtractor::record_segments`]).
pub(crate) struct SegmentLines<'a> {
    /// Each voxel's index among the ids the label volume holds (`GpuLabels::voxels`).
    pub voxels: &'a Buffer,
    /// The indices of the segments whose lines are drawn.
    pub indices: &'a [u16],
    /// Per index of the label volume, the segment's bounding box: first and last voxel.
    pub boxes: &'a [[[u32; 3]; 2]],
    /// An R32F image of the volume's size, which holds one segment's field at a time.
    pub field: &'a Image,
}

/// One extraction: the normalised volume (or its smoothed copy) of `dims` voxels spaced
/// `spacing` apart, the eye, what to extract, and the precomputed Hessian when measured that way.
#[derive(Copy, Clone)]
pub struct LineRequest<'a> {
    /// The normalised volume texture (R16 or R32F), or its smoothed copy, read texel by texel.
    pub values: &'a Image,
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// Physical size of a voxel along x, y, z.
    pub spacing: [f32; 3],
    /// Where the eye is, in the physical frame (index × spacing).
    pub eye: Eye,
    /// What to extract; `params.iso` on the normalised scale of `values`.
    pub params: LineParams,
    /// The precomputed Hessian of `values` ([`HessianSource::Precomputed`]); `None` takes it by
    /// central differences at every cell corner.
    pub(crate) hessian: Option<&'a HessianVolume>,
}

impl LineExtractor {
    /// Builds the cell and raster pipelines and the smoothing passes; the extraction's own
    /// pipelines are built on first use in the caller's [`PipelineCache`].
    pub fn new(ctx: &Arc<Context>) -> Result<Self> {
        Ok(LineExtractor {
            ctx: ctx.clone(),
            cells_pass: ComputePipeline::new(
                ctx,
                "lines/cells.comp",
                &[BindingKind::SampledImage, BindingKind::StorageBuffer],
                std::mem::size_of::<LinesPush>() as u32,
            )?,
            raster: ComputePipeline::new(
                ctx,
                "lines/raster.comp",
                &[
                    BindingKind::StorageBuffer,
                    BindingKind::StorageImage,
                    BindingKind::StorageImage,
                ],
                std::mem::size_of::<RasterPush>() as u32,
            )?,
            nearest: Sampler::new(ctx, false)?,
            smoother: crate::passes::importance::ImportanceMap::new(ctx)?,
        })
    }

    /// Records G∗`values` for [`LineParams::smooth`] = `radius` (> 0): an R32F volume on the same
    /// scale, which [`LineExtractor::record`] then extracts from. Callers that draw every frame
    /// keep it (the renderer's view state) and record this once.
    pub(crate) fn record_smoothing(
        &mut self,
        frame: &mut Frame,
        values: &Image,
        dims: [usize; 3],
        radius: u32,
    ) -> Result<Image> {
        self.smoother
            .record_blur_of_texture(frame, values, dims, &self.nearest, radius)
    }

    /// Records pass `lines_hessian`: the Hessian of `values` (as [`LineExtractor::record`] reads
    /// them) into a new [`HessianVolume`], for [`HessianSource::Precomputed`].
    pub(crate) fn record_hessian(
        &self,
        frame: &mut Frame,
        pipelines: &mut PipelineCache,
        values: &Image,
        dims: [usize; 3],
        spacing: [f32; 3],
    ) -> Result<HessianVolume> {
        let (ctx, cmd) = (&self.ctx, frame.cmd);
        let pass = pipelines.get(&PipelineDesc::new(
            "lines/hessian.comp",
            &HESSIAN_BINDINGS,
            LINES_PUSH,
        ))?;
        let extent = dims.map(|d| d as u32);
        // RGBA32F: second derivatives in physical units need float; four a texel, since RG32F
        // storage is an optional feature (see `HessianVolume`).
        let desc = ImageDesc::new_3d(Format::R32G32B32A32_SFLOAT, extent);
        let h = HessianVolume {
            a: Image::new(ctx, "line hessian a", &desc)?,
            b: Image::new(ctx, "line hessian b", &desc)?,
        };
        frame.profiler.begin(cmd, "lines_hessian");
        values.transition(cmd, Access::ComputeSampled);
        for image in [&h.a, &h.b] {
            image.discard();
            image.transition(cmd, Access::ComputeWrite);
        }
        pass.dispatch(
            cmd,
            &[
                Bind::Sampled(values, &self.nearest),
                Bind::StorageImage(&h.a),
                Bind::StorageImage(&h.b),
            ],
            &LinesPush {
                dims: dims.map(|d| d as i32),
                spacing,
                ..Default::default()
            },
            group_count(extent, [4, 4, 4]),
        )?;
        frame.profiler.end(cmd);
        Ok(h)
    }

    /// Records pass `lines_draw`: the segments of `lines` (extracted earlier in this command
    /// buffer) into `edges`, antialiased and depth-tested against `focus_depth`. One invocation
    /// per stored segment, by an indirect dispatch the extraction wrote. `edges` is R32F with an
    /// R32_UINT second view (`ImageDesc::alias`), which the pass takes the atomic max in.
    pub fn record_raster(
        &self,
        frame: &mut Frame,
        lines: &LineBuffer,
        view: &RasterView,
        focus_depth: &Image,
        edges: &Image,
    ) -> Result<()> {
        let (ctx, cmd) = (&self.ctx, frame.cmd);
        frame.profiler.begin(cmd, "lines_draw");
        memory_transition(ctx, cmd, Access::ComputeReadWrite, Access::IndirectRead);
        focus_depth.transition(cmd, Access::ComputeRead);
        edges.transition(cmd, Access::ComputeReadWrite);
        let e = edges.desc.extent;
        let index_to_clip = view.index_to_clip();
        let (coef, constant) = view.depth_terms();
        self.raster.dispatch_indirect(
            cmd,
            &[
                Bind::StorageBuffer(&lines.buffer),
                Bind::StorageImage(focus_depth),
                Bind::StorageImageAlias(edges),
            ],
            &RasterPush {
                index_to_clip: index_to_clip.to_cols_array_2d(),
                depth: [coef[0], coef[1], coef[2], constant],
                params: [view.bias, view.value, view.floor, 0.0],
                capacity_size: [lines.capacity, e[0], e[1], 0],
            },
            &lines.buffer,
            0,
        )?;
        frame.profiler.end(cmd);
        Ok(())
    }

    /// Records pass `lines` into `cmd`: resets the header and extracts from `values` (a
    /// normalised volume texture, R16 or R32F, read texel by texel; `params.iso` on the same
    /// scale). With `hessian`, the Hessian is read from it (made from the same `values` by
    /// `LineExtractor::record_hessian`) instead of taken by differences. The segments go to
    /// `state.buffer`. With [`LineParams::seeded`], the seeded traversal runs instead of the
    /// visit of the cells (`record_seeded`), seeded from what the buffer holds when the last
    /// extraction into it had the same volume, τ and kinds.
    pub fn record(
        &self,
        frame: &mut Frame,
        pipelines: &mut PipelineCache,
        state: &mut LineState,
        r: &LineRequest,
    ) -> Result<()> {
        let (params, cmd) = (&r.params, frame.cmd);
        let kinds = kinds_of(params);
        let key = SeedKey {
            values: r.values.id(),
            dims: r.dims,
            iso: params.iso.to_bits(),
            kinds,
        };
        let previous = state.last == Some(key);
        // Set before recording: a failed recording is never submitted, and the next frame's
        // seeds are then merely stale cells, which the traversal tolerates.
        state.last = Some(key);
        if params.seeded {
            if r.hessian.is_some() {
                return Err(Error::Invalid(
                    "the seeded traversal takes the Hessian on the fly only".into(),
                ));
            }
            return self.record_seeded(frame, pipelines, state, r, previous);
        }
        frame.profiler.begin(cmd, "lines");
        self.record_cells(frame, pipelines, state, r, false)?;
        frame.profiler.end(cmd);
        Ok(())
    }

    /// The visit of the cells and the extraction of `r` into `state`'s buffer: after what it
    /// holds when `append`, else from empty.
    fn record_cells(
        &self,
        frame: &mut Frame,
        pipelines: &mut PipelineCache,
        state: &mut LineState,
        r: &LineRequest,
        append: bool,
    ) -> Result<()> {
        let LineRequest {
            values,
            dims,
            spacing,
            eye,
            params,
            hessian,
        } = *r;
        let params = &params;
        let (ctx, cmd) = (&self.ctx, frame.cmd);
        let kinds = kinds_of(params);
        let LineState {
            buffer: out,
            cells: cell_slot,
            ..
        } = state;
        // The previous frame's readers (the rasteriser's indirect read) are done before this
        // write; appending, the last extraction's reads of the cell list are.
        memory_transition(ctx, cmd, Access::IndirectRead, Access::TransferWrite);
        match append {
            true => memory_transition(ctx, cmd, Access::ComputeReadWrite, Access::TransferWrite),
            false => update_buffer(ctx, cmd, &out.buffer, bytemuck::cast_slice(&HEADER_INIT)),
        }
        memory_transition(ctx, cmd, Access::TransferWrite, Access::ComputeReadWrite);
        values.transition(cmd, Access::ComputeSampled);
        let s = params.stride.max(1);
        let cells = dims.map(|d| (d.saturating_sub(1) as u32).div_ceil(s));
        let visited: u64 = cells.iter().map(|&c| c as u64).product();
        if dims.iter().map(|&d| d as u64).product::<u64>() > u32::MAX as u64 {
            return Err(Error::Invalid(format!(
                "a {}x{}x{} volume has more voxels than line extraction can index (2^32)",
                dims[0], dims[1], dims[2]
            )));
        }
        // The list holds every visited cell up to what one storage binding may address; a
        // surface crossing more cells than that (hundreds of millions) loses the rest, counted.
        let max_cells = (ctx.info.max_storage_buffer_range as u64 - HEADER) / 4;
        let cell_capacity = visited.clamp(1, max_cells) as u32;
        let cell_list = LineState::cells(ctx, cell_slot, HEADER + 4 * cell_capacity as u64)?;
        update_buffer(ctx, cmd, cell_list, bytemuck::cast_slice(&HEADER_INIT));
        memory_transition(ctx, cmd, Access::TransferWrite, Access::ComputeReadWrite);
        let push = LinesPush::new(dims, spacing, eye, params, s, out.capacity, cell_capacity);
        self.cells_pass.dispatch(
            cmd,
            &[
                Bind::Sampled(values, &self.nearest),
                Bind::StorageBuffer(cell_list),
            ],
            &push,
            group_count(cells, [4, 4, 4]),
        )?;
        memory_transition(ctx, cmd, Access::ComputeReadWrite, Access::IndirectRead);
        let desc = match hessian {
            None => PipelineDesc::new("lines/extract.comp", &EXTRACT_BINDINGS, LINES_PUSH),
            Some(_) => PipelineDesc::new(
                "lines/extract_hessian.comp",
                &EXTRACT_HESSIAN_BINDINGS,
                LINES_PUSH,
            ),
        };
        let extract = pipelines.get(&desc.constants(&[kinds.max(1)]))?;
        let mut binds = vec![
            Bind::Sampled(values, &self.nearest),
            Bind::StorageBuffer(&out.buffer),
            Bind::StorageBuffer(cell_list),
        ];
        if let Some(h) = hessian {
            for image in [&h.a, &h.b] {
                image.transition(cmd, Access::ComputeSampled);
                binds.push(Bind::Sampled(image, &self.nearest));
            }
        }
        extract.dispatch_indirect(cmd, &binds, &push, cell_list, 0)?;
        Ok(())
    }

    /// Pass `lines` of a label volume's segments (issue 42): for each segment of `s.indices`,
    /// its field (its share of each 3×3×3 box of voxels, `label_indicator.comp`, into
    /// [`SegmentLines::field`]) and the lines of that field at 0.5,
    /// all appended to `state`'s buffer, so that each segment gets its own silhouettes and
    /// contours where it meets any other. `r` gives the frame and the kinds; its τ, volume and
    /// seeding are the segments'.
    pub(crate) fn record_segments(
        &self,
        frame: &mut Frame,
        pipelines: &mut PipelineCache,
        state: &mut LineState,
        r: &LineRequest,
        s: &SegmentLines,
    ) -> Result<()> {
        let (ctx, cmd) = (&self.ctx, frame.cmd);
        let fill = pipelines.get(&PipelineDesc::new(
            "lines/label_indicator.comp",
            &FIELD_BINDINGS,
            32,
        ))?;
        let dims = r.dims;
        // No extraction of another volume seeds from this one's segments.
        state.last = None;
        frame.profiler.begin(cmd, "lines");
        if s.indices.is_empty() {
            memory_transition(ctx, cmd, Access::IndirectRead, Access::TransferWrite);
            update_buffer(
                ctx,
                cmd,
                &state.buffer.buffer,
                bytemuck::cast_slice(&HEADER_INIT),
            );
            memory_transition(ctx, cmd, Access::TransferWrite, Access::ComputeReadWrite);
        }
        for (n, &index) in s.indices.iter().enumerate() {
            // The field is 0 beyond one voxel around the segment's box: cleared, then written
            // over that box only.
            let [first, last] = s.boxes.get(index as usize).copied().unwrap_or_default();
            let lo = first.map(|c| c.saturating_sub(1));
            let size: [u32; 3] =
                std::array::from_fn(|a| (last[a] + 2).min(dims[a] as u32).saturating_sub(lo[a]));
            vellum_gpu::commands::clear_image(ctx, cmd, s.field);
            s.field.transition(cmd, Access::ComputeWrite);
            let [d, l] = [dims.map(|d| d as i32), lo.map(|c| c as i32)];
            let push = [d[0], d[1], d[2], index as i32, l[0], l[1], l[2], 0];
            fill.dispatch(
                cmd,
                &[Bind::StorageBuffer(s.voxels), Bind::StorageImage(s.field)],
                &push,
                group_count(size, [4, 4, 4]),
            )?;
            let one = LineRequest {
                values: s.field,
                params: LineParams {
                    iso: 0.5,
                    seeded: false,
                    ..r.params
                },
                hessian: None,
                ..*r
            };
            self.record_cells(frame, pipelines, state, &one, n > 0)?;
        }
        frame.profiler.end(cmd);
        Ok(())
    }

    /// The seeded traversal (Burns et al.'s seed-and-traverse, rounds of indirect dispatches with
    /// no CPU round trip): the first frontier holds the cells of the segments `out` holds from
    /// the previous extraction (when `previous`: same volume, τ and kinds) and every
    /// [`SEED_STRIDE`]-th cell that straddles τ, all as searches. Each of [`SEED_ROUNDS`] rounds
    /// extracts its frontier into `out`; a line found is followed into the cells across the
    /// faces its ends lie on, and a search that finds none steps towards h = 0. Every cell is
    /// extracted at most once a frame (one visited bit per voxel).
    fn record_seeded(
        &self,
        frame: &mut Frame,
        pipelines: &mut PipelineCache,
        line_state: &mut LineState,
        r: &LineRequest,
        previous: bool,
    ) -> Result<()> {
        let LineRequest {
            values,
            dims,
            spacing,
            eye,
            params,
            ..
        } = *r;
        let params = &params;
        let (ctx, cmd) = (&self.ctx, frame.cmd);
        let voxels: u64 = dims.iter().map(|&d| d as u64).product();
        if voxels > 1 << 30 {
            return Err(Error::Invalid(format!(
                "a {}x{}x{} volume has more voxels than the seeded traversal can index (2^30)",
                dims[0], dims[1], dims[2]
            )));
        }
        let kinds = kinds_of(params);
        let seed = pipelines.get(&PipelineDesc::new(
            "lines/seed.comp",
            &SEED_BINDINGS,
            LINES_PUSH,
        ))?;
        let round = pipelines.get(
            &PipelineDesc::new("lines/extract_seeded.comp", &ROUND_BINDINGS, LINES_PUSH)
                .constants(&[kinds.max(1)]),
        )?;
        let LineState {
            buffer: out,
            seed: slot,
            ..
        } = line_state;
        let state = SeedState::ensure(ctx, slot, voxels)?;
        let mut push = LinesPush::new(
            dims,
            spacing,
            eye,
            params,
            SEED_STRIDE,
            out.capacity,
            state.capacity,
        );
        let header = bytemuck::cast_slice(&HEADER_INIT);
        frame.profiler.begin(cmd, "lines");
        // The previous frame's extraction wrote `out` and the frontiers; its rasteriser and
        // rounds read them, also as indirect arguments.
        memory_transition(ctx, cmd, Access::ComputeReadWrite, Access::TransferWrite);
        memory_transition(ctx, cmd, Access::IndirectRead, Access::TransferWrite);
        memory_transition(ctx, cmd, Access::ComputeReadWrite, Access::ComputeReadWrite);
        vellum_gpu::commands::fill_buffer(ctx, cmd, &state.visited, 0);
        update_buffer(ctx, cmd, &state.frontier[0], header);
        memory_transition(ctx, cmd, Access::TransferWrite, Access::ComputeReadWrite);
        values.transition(cmd, Access::ComputeSampled);
        let seed_binds = [
            Bind::Sampled(values, &self.nearest),
            Bind::StorageBuffer(&out.buffer),
            Bind::StorageBuffer(&state.frontier[0]),
            Bind::StorageBuffer(&state.visited),
        ];
        if previous {
            // The previous segments' header is their indirect dispatch (64 a workgroup).
            memory_transition(ctx, cmd, Access::ComputeReadWrite, Access::IndirectRead);
            seed.dispatch_indirect(cmd, &seed_binds, &push, &out.buffer, 0)?;
        }
        let grid: u64 = dims
            .iter()
            .map(|&d| (d.saturating_sub(2) as u64) / SEED_STRIDE as u64 + 1)
            .product();
        push.seed_mode = 1;
        seed.dispatch(
            cmd,
            &seed_binds,
            &push,
            [grid.div_ceil(64).clamp(1, LINES_MAX_GROUPS) as u32, 1, 1],
        )?;
        // The seeds are read; the buffer starts over for this frame's segments.
        memory_transition(ctx, cmd, Access::ComputeReadWrite, Access::TransferWrite);
        update_buffer(ctx, cmd, &out.buffer, header);
        memory_transition(ctx, cmd, Access::TransferWrite, Access::ComputeReadWrite);
        push.stride = 1;
        push.seed_mode = 0;
        for r in 0..SEED_ROUNDS as usize {
            let (now, next) = (&state.frontier[r % 2], &state.frontier[1 - r % 2]);
            // The round before last read `next` (as its frontier and indirect arguments).
            memory_transition(ctx, cmd, Access::ComputeReadWrite, Access::TransferWrite);
            memory_transition(ctx, cmd, Access::IndirectRead, Access::TransferWrite);
            update_buffer(ctx, cmd, next, header);
            memory_transition(ctx, cmd, Access::TransferWrite, Access::ComputeReadWrite);
            memory_transition(ctx, cmd, Access::ComputeReadWrite, Access::IndirectRead);
            round.dispatch_indirect(
                cmd,
                &[
                    Bind::Sampled(values, &self.nearest),
                    Bind::StorageBuffer(&out.buffer),
                    Bind::StorageBuffer(now),
                    Bind::StorageBuffer(next),
                    Bind::StorageBuffer(&state.visited),
                ],
                &push,
                now,
                0,
            )?;
        }
        frame.profiler.end(cmd);
        Ok(())
    }

    /// Uploads `v`, extracts its lines (`params.iso` in data units) and reads them back. The
    /// pipelines are taken from `pipelines` (built there on first use).
    pub fn extract(
        &mut self,
        pipelines: &mut PipelineCache,
        v: &Volume,
        eye: Eye,
        params: &LineParams,
        capacity: u32,
    ) -> Result<LineSet> {
        self.extract_with(pipelines, v, eye, params, capacity, HessianSource::OnTheFly)
    }

    /// Uploads `v` once and extracts one frame per entry of `frames` (`iso` in data units, the
    /// same smoothing in all) into one line state, one submission each, reading each back: a
    /// seeded frame seeds from the frame before it, as in a window.
    pub fn extract_frames(
        &mut self,
        pipelines: &mut PipelineCache,
        v: &Volume,
        frames: &[(Eye, LineParams)],
        capacity: u32,
    ) -> Result<Vec<LineSet>> {
        let ctx = &self.ctx.clone();
        let Some((_, first)) = frames.first() else {
            return Ok(Vec::new());
        };
        if frames.iter().any(|(_, p)| p.smooth != first.smooth) {
            return Err(Error::Invalid(
                "the frames of one extraction share one smoothing radius".into(),
            ));
        }
        let input = OcclusionInput::upload(ctx, v)?;
        let mut state = LineState::new(ctx, capacity)?;
        let spacing = v.spacing.map(|s| s as f32);
        let smoothed = match first.smooth {
            0 => None,
            r => Some(submit_once(ctx, "line smoothing", |f| {
                self.record_smoothing(f, &input.intensity, v.dims, r)
            })?),
        };
        let values = smoothed.as_ref().unwrap_or(&input.intensity);
        let mut sets = Vec::with_capacity(frames.len());
        for (eye, params) in frames {
            let request = LineRequest {
                values,
                dims: v.dims,
                spacing,
                eye: *eye,
                params: LineParams {
                    iso: normalised_iso(input.range, params.iso),
                    ..*params
                },
                hessian: None,
            };
            let ((), times) = submit_timed(ctx, "lines", |f| {
                self.record(f, pipelines, &mut state, &request)
            })?;
            let (segments, found) = state.buffer.read()?;
            sets.push(LineSet {
                segments,
                found,
                ms: times.iter().map(|t| t.ms).sum(),
                hessian_ms: 0.0,
            });
        }
        Ok(sets)
    }

    /// [`LineExtractor::extract`] with the Hessian from `source`. [`LineSet::ms`] times the
    /// smoothing and the extraction; [`LineSet::hessian_ms`] the precomputation, apart, since
    /// it is made once per volume.
    pub fn extract_with(
        &mut self,
        pipelines: &mut PipelineCache,
        v: &Volume,
        eye: Eye,
        params: &LineParams,
        capacity: u32,
        source: HessianSource,
    ) -> Result<LineSet> {
        let ctx = &self.ctx.clone();
        let input = OcclusionInput::upload(ctx, v)?;
        let p = LineParams {
            iso: normalised_iso(input.range, params.iso),
            ..*params
        };
        let mut state = LineState::new(ctx, capacity)?;
        let spacing = v.spacing.map(|s| s as f32);
        let ((), timings) = submit_timed(ctx, "lines", |f| {
            let smoothed = match p.smooth {
                0 => None,
                r => Some(self.record_smoothing(f, &input.intensity, v.dims, r)?),
            };
            let values = smoothed.as_ref().unwrap_or(&input.intensity);
            let hessian = match source {
                HessianSource::OnTheFly => None,
                HessianSource::Precomputed => {
                    Some(self.record_hessian(f, pipelines, values, v.dims, spacing)?)
                }
            };
            let request = LineRequest {
                values,
                dims: v.dims,
                spacing,
                eye,
                params: p,
                hessian: hessian.as_ref(),
            };
            self.record(f, pipelines, &mut state, &request)?;
            // The images (and `smoothed`) are released once the submission completes.
            Ok(())
        })?;
        let hessian_ms = vellum_gpu::profiler::total_ms(&timings, "lines_hessian");
        let ms = timings
            .iter()
            .filter(|t| t.name != "lines_hessian")
            .map(|t| t.ms)
            .sum();
        let (segments, found) = state.buffer.read()?;
        Ok(LineSet {
            segments,
            found,
            ms,
            hessian_ms,
        })
    }
}

impl LineExtractor {
    /// The lines of each segment of `labels` whose index `indices` lists, as a frame of a style
    /// with lines over that label volume draws them ([`LineExtractor::record_segments`]), read
    /// back: the tools' path, one submission. `params.iso` and `seeded` are the segments'.
    pub fn extract_segments(
        &mut self,
        pipelines: &mut PipelineCache,
        labels: &vellum_volume::labels::Labels,
        (indices, spacing): (&[u16], [f32; 3]),
        eye: Eye,
        params: &LineParams,
        capacity: u32,
    ) -> Result<LineSet> {
        let ctx = &self.ctx.clone();
        let voxels = Buffer::storage_from_bytes(
            ctx,
            "label voxels",
            bytemuck::cast_slice(&labels.packed()),
        )?;
        let field = Image::new(
            ctx,
            "segment field",
            &ImageDesc::new_3d(Format::R32_SFLOAT, labels.dims.map(|d| d as u32)),
        )?;
        let boxes = labels.boxes();
        let mut state = LineState::new(ctx, capacity)?;
        let ((), timings) = submit_timed(ctx, "lines", |f| {
            let request = LineRequest {
                values: &field,
                dims: labels.dims,
                spacing,
                eye,
                params: *params,
                hessian: None,
            };
            let segments = SegmentLines {
                voxels: &voxels,
                indices,
                boxes: &boxes,
                field: &field,
            };
            self.record_segments(f, pipelines, &mut state, &request, &segments)
        })?;
        let (segments, found) = state.buffer.read()?;
        Ok(LineSet {
            segments,
            found,
            ms: timings.iter().map(|t| t.ms).sum(),
            hessian_ms: 0.0,
        })
    }
}

/// The kinds of lines `p` asks for, as the extraction's specialisation constant: bit 0
/// silhouettes, bit 1 suggestive contours.
fn kinds_of(p: &LineParams) -> u32 {
    (p.silhouettes as u32) | (p.suggestive as u32) << 1
}

/// `iso` in data units on the [0, 1] scale of a volume normalised from `[lo, hi]` (0.5 for a
/// constant volume).
fn normalised_iso([lo, hi]: [f64; 2], iso: f32) -> f32 {
    if hi > lo {
        ((iso as f64 - lo) / (hi - lo)) as f32
    } else {
        0.5
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vellum_gpu::interface::assert_glsl_layout;

    #[test]
    fn raster_push_constants_match_glsl() {
        assert_glsl_layout!(
            RasterPush,
            "lines.glsl",
            "RasterPush",
            [index_to_clip, depth, params, capacity_size]
        );
    }

    #[test]
    fn push_constants_match_glsl() {
        assert_glsl_layout!(
            LinesPush,
            "lines.glsl",
            "LinesPush",
            [
                dims,
                stride,
                spacing,
                iso,
                eye,
                kinds,
                cos_c,
                derivative_threshold,
                capacity,
                cell_capacity,
                seed_mode,
                pad1,
                pad2
            ]
        );
    }
}
