//! Frame assembly: what one frame of a volume becomes, from the [`View`] to the recorded passes.
//!
//! 1. `FrameSetup::new` decides everything the host decides, with no Vulkan: it validates the
//!    view against the volume and its classification, builds the [`WorldBox`] and the
//!    `FrameCamera` (once), culls the 16³ bricks per level, cuts the slicer's proxy planes to
//!    them, and fills the uniforms and the ray caster's tables. A unit test can look at all of it.
//! 2. [`Renderer::record`] stages those into the frame's ring, re-uploads changed classification
//!    tables, makes sure the persistent layers exist at this size, and hands the frame to one
//!    draw step: `Slicer::record_two_level`, `Slicer::record_one_pass` or
//!    `RayCaster::record`. All of them write the same named layers.
//! 3. With a style, the lines-draw step (`Renderer::record_style`) prepares the object-space
//!    lines the style asks for and `Post::record` runs the style passes over the layers.
//! 4. [`Recorded`] returns what a caller needs afterwards (the planes drawn, the lines' raster
//!    view); [`Renderer::render_frame`] is the one-shot form that also reads the layers back.

use crate::classify::labels::GpuLabels;
use crate::classify::modulation::Modulation;
use crate::classify::textures::GpuClassification;
use crate::classify::Focus;
use crate::passes::gpu_volume::VolumeRef;
use crate::passes::lines::{LineExtractor, RasterView, SegmentLines, DEFAULT_CAPACITY};
use crate::passes::normals::{Bricks, VolumeTextures};
use crate::passes::paging::{ENTRY_WORDS, HEADER, MODE_RESUME, MODE_WAIT};
use crate::render::post::{LinesDraw, Post};
use crate::render::proxy::{depth_span, view_aligned_slices_in, ProxySlices};
use crate::render::raycast::{
    opacity_bounds, walk_batch, RayCaster, RayPush, RayRequest, BRICK_FOCUS, BRICK_VISIBLE,
};
use crate::render::shading::SliceUniforms;
use crate::render::slicer::{SliceDraw, Slicer};
use crate::render::style::{LineKind, Style};
use crate::render::targets::{
    FrameImage, FrameTargets, Layers, PostTargets, TargetImages, TargetsReadback, ViewState,
};
use crate::render::view::{FrameCamera, RayOptions, View, WorldBox, MAX_SLICES};
use glam::Vec3;
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::{
    Access, Bind, BufferSlice, Context, Frames, FramesDesc, Image, ImageDesc, PipelineCache,
    Sampler,
};
use vellum_gpu::{BindingKind, PipelineDesc};
use vellum_gpu::{CommandBuffer, Format};
use vellum_volume::geometry::Geometry;

/// What [`FrameSetup`] needs of the volume and its classification: host data only.
pub(crate) struct SetupInput<'a> {
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// Physical size of a voxel along x, y, z.
    pub spacing: [f64; 3],
    /// Origin and directions of the volume, which place its box in the world.
    pub geometry: Geometry,
    /// Data values that map to normalised intensity 0 and 1.
    pub range: [f64; 2],
    /// Per-brick range of the normalised intensity, for culling bricks with nothing to draw.
    pub bricks: &'a Bricks,
    /// The 1D transfer function's table (256 RGBA entries).
    pub table: &'a [[f32; 4]],
    /// The focus, in data units.
    pub focus: Focus,
    /// Whether the segments of a label volume decide the level (`classify::labels`), in place
    /// of the focus.
    pub(crate) labels_focus: bool,
    /// Channels mixed in the ray: what makes a brick visible is then any channel's opacity.
    pub(crate) channels: Option<&'a crate::classify::channels::GpuChannels>,
    /// Importance modulation (SPEC IM3–IM5), written into the uniforms; when active, the volume
    /// must carry ΔD.
    pub modulation: &'a Modulation,
    /// Whether an occlusion transfer function classifies the volume, and whether the volume
    /// carries the occlusion volume it reads.
    pub(crate) uses_occlusion: bool,
    /// Whether the volume carries its occlusion volume.
    pub(crate) has_occlusion: bool,
    /// Whether the volume carries its importance map (ΔD), which modulation reads.
    pub has_importance: bool,
    /// The device's largest 2D image side.
    pub(crate) max_image_size: u32,
}

impl<'a> SetupInput<'a> {
    /// The host side of a volume and classification that are on the GPU.
    pub fn of(vol: VolumeRef<'a>, classify: &'a GpuClassification, max: u32) -> Self {
        SetupInput {
            dims: vol.dims(),
            spacing: vol.spacing(),
            geometry: vol.geometry(),
            range: vol.range(),
            bricks: vol.bricks(),
            table: classify.transfer_table(),
            focus: classify.focus,
            labels_focus: classify.labels.as_ref().is_some_and(|l| l.decide_focus),
            channels: classify.channels.as_ref(),
            modulation: &classify.modulation,
            uses_occlusion: classify.uses_occlusion(),
            has_occlusion: vol.occlusion().is_some(),
            has_importance: vol.importance().is_some(),
            max_image_size: max,
        }
    }
}

/// Everything the host decides for one frame, before anything is recorded.
#[derive(Clone, Debug)]
pub(crate) struct FrameSetup {
    /// Image width and height in pixels.
    pub size: [u32; 2],
    /// The volume's box in the world.
    pub world: WorldBox,
    /// The camera in the box frame, computed once.
    pub camera: FrameCamera,
    /// The focus in normalised intensity: low, high, mode ([`Focus::normalised`]).
    pub focus: [f32; 3],
    /// The context's (or the one pass's) planes, cut to its bricks; for a ray-cast frame only
    /// their spacing and count, which the rays share.
    pub(crate) proxy: ProxySlices,
    /// The focus level's planes, cut to the bricks that may hold focus (slicing, two levels).
    pub(crate) focus_proxy: Option<ProxySlices>,
    /// Depth of the nearest and the farthest box corner along the view direction.
    pub(crate) depth_span: (f32, f32),
    /// The shaders' per-frame uniforms, staged into the frame's ring.
    pub(crate) uniforms: SliceUniforms,
    /// The ray caster's table for a ray-cast frame: the transfer function's opacity bounds, then
    /// the bricks' flags ([`BRICK_VISIBLE`], [`BRICK_FOCUS`]).
    pub(crate) ray_tables: Option<Vec<u32>>,
}

impl FrameSetup {
    /// The frame of the volume and classification `input` describes, seen by `view`; errors name
    /// the view's or the scene's keys (`size`, `one_pass`, `focus`, `slices`, ...).
    pub fn new(input: &SetupInput, view: &View) -> Result<Self> {
        validate(input, view)?;
        let world = WorldBox::new(input.dims, input.spacing, &input.geometry);
        let camera = FrameCamera::new(&world, view);
        let slices = plane_count(input.dims, view)?;
        let focus = input.focus.normalised(input.range);
        let visible: Vec<bool> = match input.channels {
            // Mixed channels: a brick is visible where any channel's function gives opacity.
            Some(c) => (0..input.bricks.range.len())
                .map(|b| {
                    c.skipping
                        .iter()
                        .any(|(t, ranges)| any_opacity(t, &ranges[b]))
                })
                .collect(),
            None => input
                .bricks
                .range
                .iter()
                .map(|r| input.uses_occlusion || any_opacity(input.table, r))
                .collect(),
        };
        let span = depth_span(world.half, camera.view_dir.normalize());
        let (proxy, focus_proxy) = match view.raycast {
            Some(_) => (
                ProxySlices {
                    spacing: (span.1 - span.0) / slices as f32,
                    slices,
                    ..ProxySlices::default()
                },
                None,
            ),
            None => proxies(
                input,
                view,
                &world,
                camera.view_dir,
                slices,
                &visible,
                focus,
            ),
        };
        let mut uniforms = shading_uniforms(input, view, &world, &camera, &proxy, focus);
        uniforms.set_modulation(input.modulation, input.dims);
        let ray_tables = view
            .raycast
            .map(|_| ray_tables(input.table, input.bricks, &visible, focus));
        Ok(FrameSetup {
            size: view.size,
            world,
            camera,
            focus,
            proxy,
            focus_proxy,
            depth_span: span,
            uniforms,
            ray_tables,
        })
    }

    /// The ray caster's push constants for `options` on a volume of `bricks`.
    pub(crate) fn ray_push(
        &self,
        options: &RayOptions,
        bricks: [usize; 3],
        two_level: bool,
    ) -> RayPush {
        let c = bricks.map(|n| n as i32);
        RayPush {
            inv_view_proj: self.camera.view_proj.inverse().to_cols_array_2d(),
            planes: [
                self.depth_span.1,
                self.proxy.spacing,
                self.proxy.slices as f32,
                options.ert,
            ],
            bricks: [c[0], c[1], c[2], crate::passes::normals::BRICK as i32],
            flags: [
                two_level as i32,
                options.skip_empty as i32,
                options.jitter.map_or(0, |j| j.max(1) as i32),
                options.refine_iso as i32
                    | ((options.sampling == crate::render::view::Sampling::WorldSteps) as i32) << 1,
            ],
        }
    }
}

/// Checks the view against the volume and classification before anything is computed.
fn validate(input: &SetupInput, view: &View) -> Result<()> {
    let [w, h] = view.size;
    let max = input.max_image_size;
    if w == 0 || h == 0 || w > max || h > max {
        return Err(Error::Invalid(format!(
            "image `size` {w}x{h} is invalid; expected 1..={max} pixels per side"
        )));
    }
    if input.uses_occlusion && !input.has_occlusion {
        return Err(Error::Invalid("an occlusion transfer function needs an occlusion volume attached to the volume textures".into()));
    }
    view.lighting.validate()?;
    if let Some(style) = &view.style {
        if view.one_pass {
            return Err(Error::Invalid(format!(
                "style {} ({}) works on the two levels; drop `one_pass`",
                style.def.number, style.def.name
            )));
        }
        if style.def.needs_focus() && input.focus == Focus::None && !input.labels_focus {
            return Err(Error::Invalid(format!(
                "style {} ({}) works on the focus layer; give a focus with `iso`, `focus` or `focus_labels`",
                style.def.number, style.def.name
            )));
        }
    }
    input.modulation.validate()?;
    if input.modulation.is_active() && !input.has_importance {
        return Err(Error::Invalid(
            "importance modulation needs the importance map attached to the volume textures".into(),
        ));
    }
    if let Some(r) = &view.raycast {
        r.validate()?;
    }
    Ok(())
}

/// The number of planes: the view's, or two per voxel along the longest axis.
fn plane_count(dims: [usize; 3], view: &View) -> Result<u32> {
    let n = view
        .slices
        .unwrap_or_else(|| 2 * *dims.iter().max().unwrap_or(&1) as u32)
        .max(1);
    if n > MAX_SLICES {
        return Err(Error::Invalid(format!(
            "{n} `slices` are too many; expected at most {MAX_SLICES}"
        )));
    }
    Ok(n)
}

/// The slicer's planes per level. Every level draws the same planes, cut only by the bricks that
/// can contribute to it, so each fragment it draws is one the whole-box planes would draw and the
/// skipped ones would all have been discarded. One pass and context: bricks whose intensities
/// meet a non-zero opacity (all bricks with an occlusion TF); the context also drops bricks that
/// are focus throughout. Focus: bricks that can hold focus samples.
fn proxies(
    input: &SetupInput,
    view: &View,
    world: &WorldBox,
    view_dir: Vec3,
    slices: u32,
    visible: &[bool],
    focus: [f32; 3],
) -> (ProxySlices, Option<ProxySlices>) {
    let (bricks, dims, half) = (input.bricks, input.dims, world.half);
    let planes = |keep: &dyn Fn(usize) -> bool| {
        view_aligned_slices_in(
            half,
            view_dir,
            slices,
            &brick_boxes(bricks, dims, half, keep),
        )
    };
    let context = || match view.one_pass {
        true => planes(&|b| visible[b]),
        false => planes(&|b| visible[b] && !all_focus(&bricks.range[b], focus)),
    };
    let focus_level = || (!view.one_pass).then(|| planes(&|b| may_focus(&bricks.range[b], focus)));
    rayon::join(context, focus_level)
}

/// The shaders' uniforms: camera, box, headlight, material, plane spacing in voxels, focus.
fn shading_uniforms(
    input: &SetupInput,
    view: &View,
    world: &WorldBox,
    camera: &FrameCamera,
    proxy: &ProxySlices,
    focus: [f32; 3],
) -> SliceUniforms {
    let (half, eye, view_dir) = (world.half, camera.eye, camera.view_dir);
    let region = view.raycast.and_then(|r| r.region);
    let light = -view_dir; // a headlight
    let l = &view.lighting;
    SliceUniforms {
        view_proj: camera.view_proj.to_cols_array_2d(),
        half_extent: [half.x, half.y, half.z, world.longest as f32],
        eye: [eye.x, eye.y, eye.z, 0.0],
        view_dir: [
            view_dir.x,
            view_dir.y,
            view_dir.z,
            if camera.camera.ortho { 1.0 } else { 0.0 },
        ],
        light: [light.x, light.y, light.z, l.shininess],
        material: [
            l.ambient,
            l.diffuse,
            l.specular,
            (proxy.spacing as f64 / world.voxel) as f32,
        ],
        focus: [
            focus[0],
            focus[1],
            focus[2],
            if input.uses_occlusion { 1.0 } else { 0.0 },
        ],
        region_lo: region.map_or([0.0; 4], |r| [r[0][0], r[0][1], r[0][2], 0.0]),
        region_hi: region.map_or([0.0; 4], |r| [r[1][0], r[1][1], r[1][2], 1.0]),
        ..bytemuck::Zeroable::zeroed()
    }
}

/// The ray caster's tables: opacity bounds per TF texel pair, then per-brick flags for
/// empty-space skipping (`raycast.comp`, `RayTables`).
fn ray_tables(table: &[[f32; 4]], bricks: &Bricks, visible: &[bool], focus: [f32; 3]) -> Vec<u32> {
    let flags = bricks.range.iter().zip(visible).map(|(r, &v)| {
        let v = if v { BRICK_VISIBLE } else { 0 };
        v | if may_focus(r, focus) { BRICK_FOCUS } else { 0 }
    });
    opacity_bounds(table)
        .into_iter()
        .map(f32::to_bits)
        .chain(flags)
        .collect()
}

/// Brick range in normalised units with one u16 step of margin for rounding between the CPU
/// ranges and the GPU's filtering.
fn widened(r: &[u16; 2]) -> (f32, f32) {
    ((r[0] as f32 - 1.0) / 65535.0, (r[1] as f32 + 1.0) / 65535.0)
}

/// Whether some sample of a brick with range `r` can be in `focus` (normalised lo, hi, mode).
fn may_focus(r: &[u16; 2], focus: [f32; 3]) -> bool {
    let (mn, mx) = widened(r);
    match focus[2] as i32 {
        1 => mx >= focus[0] && mn <= focus[1],
        2 => mx >= focus[0],
        _ => false,
    }
}

/// Whether every sample of a brick with range `r` is in `focus`.
fn all_focus(r: &[u16; 2], focus: [f32; 3]) -> bool {
    let (mn, mx) = widened(r);
    match focus[2] as i32 {
        1 => mn >= focus[0] && mx <= focus[1],
        2 => mn >= focus[0],
        _ => false,
    }
}

/// The first and last entries of an `n`-entry transfer-function table (knots at i / (n − 1))
/// that linear filtering blends for samples in the u16 range `r`. Filtering never leaves the range
/// of the texels it blends, and the ranges are of the very texels the GPU samples, so no margin is
/// needed: a brick of zeros touches knot 0 alone. (At n = 256, knot i is the u16 value 257 i.)
fn knots_touched(n: usize, r: [u16; 2]) -> (usize, usize) {
    let m = n.saturating_sub(1) as u64;
    let first = (r[0] as u64 * m / 65535) as usize;
    let last = ((r[1] as u64 * m).div_ceil(65535) as usize).min(n.saturating_sub(1));
    (first.min(last), last)
}

/// Whether the 1D transfer function gives any opacity to intensities in range `r`: the table
/// entries that linear filtering blends for samples in the range.
fn any_opacity(table: &[[f32; 4]], r: &[u16; 2]) -> bool {
    let (first, last) = knots_touched(table.len(), *r);
    table[first..=last].iter().any(|c| c[3] > 0.0)
}

/// Bricks kept above this fraction are drawn as the whole box instead: rasterising many small
/// polygons costs more on lavapipe than the skipped fragments save (measured on the engine, whose
/// haze keeps every brick: the single pass took 2.5× longer as bricks).
const BRICK_FRACTION: f64 = 0.5;

/// World boxes of the bricks for which `keep` holds, or the whole volume box when more than
/// [`BRICK_FRACTION`] of them do. Faces come from integer voxel coordinates through one formula, so
/// neighbouring boxes share their corners exactly (no T-junctions: bricks are never merged).
fn brick_boxes(
    bricks: &Bricks,
    dims: [usize; 3],
    half: Vec3,
    keep: &dyn Fn(usize) -> bool,
) -> Vec<(Vec3, Vec3)> {
    let n = bricks.range.len();
    let kept: Vec<usize> = (0..n).filter(|&b| keep(b)).collect();
    if kept.len() as f64 > BRICK_FRACTION * n as f64 {
        return vec![(-half, half)];
    }
    let world = |v: usize, a: usize| (v as f32 / dims[a] as f32) * 2.0 * half[a] - half[a];
    kept.into_iter()
        .map(|b| {
            let (l, h) = bricks.voxel_bounds(b, dims);
            (
                Vec3::new(world(l[0], 0), world(l[1], 1), world(l[2], 2)),
                Vec3::new(world(h[0], 0), world(h[1], 1), world(h[2], 2)),
            )
        })
        .collect()
}

/// What recording a frame decided, for the caller to use once the frame has completed.
#[derive(Copy, Clone, Debug)]
pub struct Recorded {
    /// Planes drawn (or sampled by the rays).
    pub slices: u32,
    /// The geometry the frame's object-space lines were drawn with, when its style has lines:
    /// with the segments in the targets' `ViewState`, what vector output needs.
    pub lines: Option<RasterView>,
}

impl Recorded {
    /// The frame image of this frame, with what came back from it.
    pub fn image(
        self,
        size: [u32; 2],
        (composite, layers): (Vec<[f32; 4]>, Option<crate::render::targets::Layers>),
        passes: Vec<vellum_gpu::PassTime>,
        segments: Option<(Vec<vellum_volume::lines::Segment>, u64)>,
    ) -> FrameImage {
        FrameImage {
            size,
            composite,
            layers,
            passes,
            slices: self.slices,
            lines: self.lines,
            segments,
        }
    }
}

/// The frame's staged data: uniforms, proxy vertices and the ray caster's table.
struct Staged {
    ubo: BufferSlice,
    vertices: (BufferSlice, u32),
    focus_vertices: Option<(BufferSlice, u32)>,
    ray_tables: Option<BufferSlice>,
}

impl Staged {
    /// Pushes the setup's data into the frame's staging ring (nothing is allocated).
    fn push(frame: &mut vellum_gpu::Frame, setup: &FrameSetup) -> Result<Self> {
        let staging = &mut *frame.staging;
        let ubo = staging.push_pod(&setup.uniforms)?;
        let mut vertices = |p: &ProxySlices| -> Result<(BufferSlice, u32)> {
            let slice = staging.push(bytemuck::cast_slice(&p.vertices), 16)?;
            Ok((slice, p.vertices.len() as u32))
        };
        let proxy = vertices(&setup.proxy)?;
        let focus_vertices = setup.focus_proxy.as_ref().map(&mut vertices).transpose()?;
        let ray_tables = match &setup.ray_tables {
            Some(t) => Some(staging.push(bytemuck::cast_slice(t), 256)?),
            None => None,
        };
        Ok(Staged {
            ubo,
            vertices: proxy,
            focus_vertices,
            ray_tables,
        })
    }
}

/// The renderer: the slicer, the ray caster and the style passes, with the samplers and stand-in
/// images their shared bindings need, and the one pipeline cache they build their lazily made
/// pipelines in. What a view keeps between frames is in its [`FrameTargets`], not here.
pub struct Renderer {
    ctx: Arc<Context>,
    slicer: Slicer,
    linear: Sampler,
    stand_ins: StandIns,
    /// The ray caster's variants, line extraction's per-kind pipelines and the style passes'.
    pipelines: PipelineCache,
    /// The style passes, built on the first styled frame.
    post: Option<Post>,
    /// Object-space line extraction, built on the first frame of a style with lines.
    lines: Option<LineExtractor>,
}

/// 1×1 stand-ins bound when a frame uses no occlusion or importance volume, or no brick cache.
struct StandIns {
    /// For the occlusion volume and ΔD.
    volume: Image,
    /// For the max |ΔD| buffer.
    max: vellum_gpu::Buffer,
    /// For the brick cache's feedback and ray states.
    paging: vellum_gpu::Buffer,
}

impl StandIns {
    fn new(ctx: &Arc<Context>) -> Result<Self> {
        // R32F: the format of the occlusion volume and ΔD it stands in for; one voxel of 0.
        let volume = Image::new(
            ctx,
            "dummy occlusion",
            &ImageDesc::new_3d(Format::R32_SFLOAT, [1, 1, 1]),
        )?;
        vellum_gpu::transfer::upload(ctx, &volume, &[0u8; 4], Access::FragmentSampled)?;
        let max = vellum_gpu::Buffer::storage_from_bytes(ctx, "dummy importance max", &[0u8; 4])?;
        let paging = vellum_gpu::Buffer::new(
            ctx,
            "dummy paging",
            &vellum_gpu::BufferDesc::storage(crate::passes::paging::RAY_STATE_BYTES),
        )?;
        Ok(StandIns {
            volume,
            max,
            paging,
        })
    }

    /// The occlusion volume, ΔD and max |ΔD| the shaders bind (or 1×1 stand-ins when the frame
    /// uses none), moved with the volume's textures to `sampled`.
    fn shading_inputs<'a>(
        &'a self,
        ctx: &Context,
        cmd: CommandBuffer,
        vol: VolumeRef<'a>,
        classify: &GpuClassification,
        sampled: Access,
    ) -> (&'a Image, &'a Image, &'a vellum_gpu::Buffer) {
        let occlusion = match (classify.uses_occlusion(), vol.occlusion()) {
            (true, Some(o)) => o,
            _ => &self.volume,
        };
        vol.intensity().transition(cmd, sampled);
        if let Some(g) = vol.gradient() {
            g.transition(cmd, sampled);
        }
        if let Some((lo, hi)) = vol.channel_pools() {
            lo.transition(cmd, sampled);
            if let Some(hi) = hi {
                hi.transition(cmd, sampled);
            }
        }
        occlusion.transition(cmd, sampled);
        let importance = vol.importance().filter(|_| classify.modulation.is_active());
        let Some(i) = importance else {
            return (occlusion, &self.volume, &self.max);
        };
        i.delta_d.transition(cmd, sampled);
        // The reduction's atomics must be visible to the shaders' reads.
        let read = match sampled {
            Access::ComputeSampled => Access::ComputeRead,
            _ => Access::FragmentStorageRead,
        };
        vellum_gpu::commands::memory_transition(ctx, cmd, Access::ComputeReadWrite, read);
        (occlusion, &i.delta_d, &i.max_abs)
    }
}

/// Parameters of one frame for the one-shot [`Renderer::render`].
#[derive(Clone, Debug)]
pub struct RenderParams {
    /// The camera around the volume's box.
    pub camera: crate::render::camera::Camera,
    /// Image width and height in pixels.
    pub size: [u32; 2],
    /// Number of slice planes; `None` picks about two per voxel along the longest axis.
    pub slices: Option<u32>,
    /// The focus, in data units.
    pub focus: Focus,
    /// Draw one level, all context, instead of the two levels.
    pub one_pass: bool,
    /// The 1D transfer function.
    pub transfer: crate::classify::transfer::TransferFunction,
    /// An occlusion transfer function table (256×256, `table[o * 256 + s]`), which replaces
    /// `transfer`; the volume textures must then hold an occlusion volume.
    pub occlusion_tf: Option<Vec<[f32; 4]>>,
}

impl Renderer {
    /// Builds the slicer's pipelines; the ray caster's and the styles' are built on first use.
    pub fn new(ctx: &Arc<Context>) -> Result<Self> {
        Ok(Renderer {
            ctx: ctx.clone(),
            slicer: Slicer::new(ctx)?,
            linear: Sampler::new(ctx, true)?,
            stand_ins: StandIns::new(ctx)?,
            pipelines: PipelineCache::new(ctx),
            post: None,
            lines: None,
        })
    }

    /// The context the pipelines were built on.
    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }

    /// Records one frame of `vol`, classified by `classify` (transfer functions, focus,
    /// modulation), as seen by `view`, into `frame`; the layers land in `targets` (resized if
    /// needed). Passes: `focus`, `context`, `composite`; or `one_pass`; or `raycast`; then the
    /// style's.
    pub fn record<'v>(
        &mut self,
        frame: &mut vellum_gpu::Frame,
        vol: impl Into<VolumeRef<'v>>,
        classify: &mut GpuClassification,
        view: &View,
        targets: &mut FrameTargets,
    ) -> Result<Recorded> {
        let vol = vol.into();
        let max = self.ctx.info.max_image_dimension_2d;
        check_paged(vol, view)?;
        check_labels(classify, view)?;
        let paged_view = paged_planes(vol, view);
        let view = paged_view.as_ref().unwrap_or(view);
        let setup = FrameSetup::new(&SetupInput::of(vol, classify, max), view)?;
        self.build_style_passes(view)?;
        let staged = Staged::push(frame, &setup)?;
        let sampled = match view.raycast {
            Some(_) => Access::ComputeSampled,
            None => Access::FragmentSampled,
        };
        classify.record(frame, sampled)?;
        let (t, state) = targets.ensure(view.size, !view.one_pass, view.style.is_some())?;
        let (occlusion, delta_d, delta_max) = self
            .stand_ins
            .shading_inputs(&self.ctx, frame.cmd, vol, classify, sampled);
        let binds = [
            Bind::UniformSlice(staged.ubo),
            Bind::Sampled(vol.intensity(), &self.linear),
            // (Gradients made at each sample: the intensity stands in, never read.)
            Bind::Sampled(vol.gradient().unwrap_or(vol.intensity()), &self.linear),
            Bind::Sampled(classify.transfer_image(), &self.linear),
            Bind::Sampled(occlusion, &self.linear),
            Bind::Sampled(classify.occlusion_image(), &self.linear),
            Bind::Sampled(delta_d, &self.linear),
            Bind::StorageBuffer(delta_max),
        ];
        let draw = SliceDraw {
            shading: &binds,
            size: view.size,
            vertices: staged.vertices,
            focus_vertices: staged.focus_vertices,
        };
        match (view.raycast, &t.layers, view.one_pass, staged.ray_tables) {
            (Some(mut options), layers, one_pass, Some(tables)) => {
                let two_level = !one_pass;
                // The bricks' flags know the focus interval, not the segments: where segments
                // decide the level, any visible brick may hold focus, and none is skipped.
                if classify.labels.as_ref().is_some_and(|l| l.decide_focus) {
                    options.skip_empty = false;
                }
                match &classify.channels {
                    Some(c) => {
                        c.image.transition(frame.cmd, Access::ComputeSampled);
                        c.tfs.transition(frame.cmd, Access::ComputeSampled);
                        if let Some(hi) = &c.image_hi {
                            hi.transition(frame.cmd, Access::ComputeSampled);
                        }
                    }
                    None => self
                        .stand_ins
                        .volume
                        .transition(frame.cmd, Access::ComputeSampled),
                }
                let rays = RayFrame {
                    setup: &setup,
                    options,
                    binds: &binds,
                    layers: layers.as_ref().filter(|_| two_level),
                    composite: &t.composite,
                    tables,
                    stand_in: &self.stand_ins.paging,
                    labels: classify.labels.as_ref(),
                    channels: classify
                        .channels
                        .as_ref()
                        .ok_or([&self.stand_ins.volume, classify.transfer_image()]),
                    sampler: &self.linear,
                    flags: BrickFlags::new(
                        classify.transfer_table(),
                        setup.focus,
                        classify.uses_occlusion(),
                    )
                    .with_channels(classify.channels.as_ref()),
                };
                record_rays(&self.ctx, &mut self.pipelines, frame, vol, &rays, state)?;
            }
            (None, Some(layers), false, _) => {
                self.slicer
                    .record_two_level(frame, &draw, layers, &t.composite)?
            }
            _ => self.slicer.record_one_pass(frame, &draw, &t.composite)?,
        }
        let lines = match view.one_pass {
            false => {
                let labels = classify.labels.as_ref();
                self.record_view_style(frame, vol, (&setup, view, labels), (t, state))?
            }
            true => None,
        };
        Ok(Recorded {
            slices: setup.proxy.slices,
            lines,
        })
    }

    /// The style of `view`, if any, over the layers of `t`.
    fn record_view_style(
        &mut self,
        frame: &mut vellum_gpu::Frame,
        vol: VolumeRef,
        (setup, view, labels): (&FrameSetup, &View, Option<&GpuLabels>),
        (t, state): (&TargetImages, &mut ViewState),
    ) -> Result<Option<RasterView>> {
        match (&view.style, &t.post) {
            (Some(style), Some(post)) => {
                let style_frame = StyleFrame {
                    setup,
                    style,
                    images: t,
                    post,
                    labels,
                };
                self.record_style(frame, vol, &style_frame, state)
            }
            _ => Ok(None),
        }
    }

    /// Records only `view`'s style over the layers in `targets`, which a frame of the same view
    /// (another style, or none) left there ([`Renderer::render_styles`]).
    fn record_restyle(
        &mut self,
        frame: &mut vellum_gpu::Frame,
        vol: VolumeRef,
        classify: &mut GpuClassification,
        view: &View,
        targets: &mut FrameTargets,
    ) -> Result<Recorded> {
        let max = self.ctx.info.max_image_dimension_2d;
        let setup = FrameSetup::new(&SetupInput::of(vol, classify, max), view)?;
        self.build_style_passes(view)?;
        let (t, state) = targets.ensure(view.size, true, true)?;
        let labels = classify.labels.as_ref();
        let lines = self.record_view_style(frame, vol, (&setup, view, labels), (t, state))?;
        Ok(Recorded {
            slices: setup.proxy.slices,
            lines,
        })
    }

    /// Builds the style passes, and the line extractor for a style with lines, on the first
    /// frame that needs them.
    fn build_style_passes(&mut self, view: &View) -> Result<()> {
        let Some(style) = &view.style else {
            return Ok(());
        };
        if style.def.lines.is_some() && self.lines.is_none() {
            self.lines = Some(LineExtractor::new(&self.ctx)?);
        }
        if self.post.is_none() {
            self.post = Some(Post::new(&mut self.pipelines)?);
        }
        Ok(())
    }

    /// The lines-draw step and the style passes: extracts the object-space lines the style asks
    /// for (from the volume, or from its smoothed copy, made once per volume and radius and kept
    /// in the view's `state`) and records [`Post::record`]. Returns the lines' raster view.
    fn record_style(
        &mut self,
        frame: &mut vellum_gpu::Frame,
        vol: VolumeRef,
        f: &StyleFrame,
        state: &mut ViewState,
    ) -> Result<Option<RasterView>> {
        let passes = self
            .post
            .as_ref()
            .ok_or_else(|| Error::Invalid("the style passes were not built".into()))?;
        // Lines are drawn from a volume in core only (`check_paged` refuses them otherwise).
        let Some(vol) = vol.in_core().filter(|_| f.style.def.lines.is_some()) else {
            passes.record(frame, f.style, f.images, f.post, None)?;
            return Ok(None);
        };
        let radius = f.style.params.line_smooth.radius(vol.auto_line_smooth);
        if let (Some(_), Some(extractor)) = (f.style.def.lines, self.lines.as_mut()) {
            if radius > 0 && !state.has_smoothed(vol.id, radius) {
                let image = extractor.record_smoothing(frame, &vol.intensity, vol.dims, radius)?;
                state.keep_smoothed(vol.id, radius, image);
            }
        }
        let draw = match (f.style.def.lines, &self.lines) {
            (Some(kind), Some(extractor)) => {
                let g = line_geometry(vol, f, kind);
                let (line_state, volume, segments) = match f
                    .labels
                    .and_then(|l| Some((l, l.voxels.as_ref()?)))
                {
                    Some((labels, voxels)) => {
                        let (line_state, field) =
                            state.lines_and_segment_field(&self.ctx, DEFAULT_CAPACITY, vol.dims)?;
                        let segments = SegmentLines {
                            voxels,
                            indices: &labels.drawn,
                            boxes: &labels.boxes,
                            field,
                        };
                        (line_state, &vol.intensity, Some(segments))
                    }
                    None => {
                        let (line_state, smoothed) = state.lines_and_smoothed(
                            &self.ctx,
                            DEFAULT_CAPACITY,
                            (vol.id, radius),
                        )?;
                        (line_state, smoothed.unwrap_or(&vol.intensity), None)
                    }
                };
                Some(LinesDraw {
                    extractor,
                    pipelines: &mut self.pipelines,
                    state: line_state,
                    volume,
                    dims: vol.dims,
                    spacing: g.spacing,
                    eye: g.eye,
                    params: g.params,
                    view: g.view,
                    segments,
                })
            }
            _ => None,
        };
        let raster = draw.as_ref().map(|d| d.view);
        passes.record(frame, f.style, f.images, f.post, draw)?;
        Ok(raster)
    }

    /// Renders one frame in one submission (the tools' path): the persistent-state types, used
    /// once. With `readback`, the composite (and the layers of a two-level frame) come back to
    /// the host.
    pub fn render<'v>(
        &mut self,
        vol: impl Into<VolumeRef<'v>>,
        params: &RenderParams,
        readback: bool,
    ) -> Result<FrameImage> {
        let mut classify = GpuClassification::new(&self.ctx, &params.transfer, params.focus)?;
        classify.set_occlusion_table(params.occlusion_tf.clone())?;
        let view = View {
            camera: params.camera,
            size: params.size,
            slices: params.slices,
            one_pass: params.one_pass,
            lighting: Default::default(),
            style: None,
            fit: false,
            raycast: None,
        };
        self.render_frame(vol, &mut classify, &view, readback)
    }

    /// [`Renderer::render`] for a volume and classification that are already on the GPU. A
    /// frame read back brings its object-space lines' segments too.
    pub fn render_frame<'v>(
        &mut self,
        vol: impl Into<VolumeRef<'v>>,
        classify: &mut GpuClassification,
        view: &View,
        readback: bool,
    ) -> Result<FrameImage> {
        let mut targets = FrameTargets::new(&self.ctx);
        self.frame_in(
            vol.into(),
            classify,
            (view, &mut targets),
            (readback, false),
        )
    }

    /// Each of `styles` over one two-level frame of `view` (whose own style is ignored), read
    /// back: the levels are drawn once, and every style's passes then run over the same layers
    /// (they read the layers and write the composite). A style that records nothing (15, none)
    /// shows the levels' own composite, so it is drawn whole. The first frame's passes include
    /// the levels'; the others' only the style's.
    pub fn render_styles<'v>(
        &mut self,
        vol: impl Into<VolumeRef<'v>>,
        classify: &mut GpuClassification,
        view: &View,
        styles: &[Style],
    ) -> Result<Vec<FrameImage>> {
        let vol = vol.into();
        let mut targets = FrameTargets::new(&self.ctx);
        let mut out = Vec::with_capacity(styles.len());
        for (i, style) in styles.iter().enumerate() {
            let v = View {
                style: Some(*style),
                ..view.clone()
            };
            let d = style.def;
            let plain = d.edges.is_none() && d.abstraction.is_none() && d.lines.is_none();
            let restyle = i > 0 && !plain && !view.one_pass;
            out.push(self.frame_in(vol, classify, (&v, &mut targets), (true, restyle))?);
        }
        Ok(out)
    }

    /// One frame of `view` into `targets`: whole, or (`restyle`) only its style's passes over
    /// the layers a frame of the same view left there; read back when `readback`.
    fn frame_in(
        &mut self,
        vol: VolumeRef,
        classify: &mut GpuClassification,
        (view, targets): (&View, &mut FrameTargets),
        (readback, restyle): (bool, bool),
    ) -> Result<FrameImage> {
        let ctx = &self.ctx.clone();
        let mut frames = Frames::new(ctx, &FramesDesc::one_shot("render frame", 32))?;
        let mut host = None;
        let (recorded, _) = frames.frame(|f| {
            let r = match restyle {
                true => self.record_restyle(f, vol, classify, view, targets)?,
                false => self.record(f, vol, classify, view, targets)?,
            };
            if readback {
                let rb = TargetsReadback::new(ctx, targets)?;
                rb.record(f, targets);
                host = Some(rb);
            }
            Ok(r)
        })?;
        let passes = frames.finish()?;
        let (composite, layers) = match &host {
            Some(rb) => rb.read()?,
            None => (Vec::new(), None),
        };
        let segments = match (&targets.state().lines, readback && recorded.lines.is_some()) {
            (Some(lines), true) => Some(lines.buffer.read()?),
            _ => None,
        };
        Ok(recorded.image(view.size, (composite, layers), passes, segments))
    }
}

impl Renderer {
    /// Styles a two-level frame whose layers were made elsewhere (composited from the ranks of a
    /// job by `render::sortlast`): uploads `layers` and `composite` into targets of `size`,
    /// records `style`'s passes over them and reads the frame back. A style with object-space
    /// lines is refused: they are drawn from the volume, which no one rank holds.
    pub fn style_layers(
        &mut self,
        (layers, composite): (&Layers, &[[f32; 4]]),
        size: [u32; 2],
        style: &Style,
    ) -> Result<FrameImage> {
        if style.def.lines.is_some() {
            return Err(Error::Invalid(format!(
                "style {} draws object-space lines, which need the whole volume on one rank; choose an image-space style",
                style.def.name
            )));
        }
        if self.post.is_none() {
            self.post = Some(Post::new(&mut self.pipelines)?);
        }
        let ctx = &self.ctx.clone();
        let mut targets = FrameTargets::new(ctx);
        targets.ensure(size, true, true)?;
        let t = targets
            .images()
            .ok_or_else(|| Error::Invalid("no targets".into()))?;
        let (l, post) = match (&t.layers, &t.post, &self.post) {
            (Some(l), Some(p), Some(post)) => ((l, p), post),
            _ => return Err(Error::Invalid("the styled targets were not made".into())),
        };
        let uploads: [(&Image, &[u8]); 5] = [
            (&l.0.focus_phong, bytemuck::cast_slice(&layers.focus_phong)),
            (
                &l.0.focus_diffuse,
                bytemuck::cast_slice(&layers.focus_diffuse),
            ),
            (&l.0.focus_depth, bytemuck::cast_slice(&layers.focus_depth)),
            (&l.0.context, bytemuck::cast_slice(&layers.context)),
            (&t.composite, bytemuck::cast_slice(composite)),
        ];
        let mut desc = FramesDesc::one_shot("styled layers", 32);
        desc.staging_bytes = uploads.iter().map(|(_, b)| b.len() as u64 + 256).sum();
        let mut frames = Frames::new(ctx, &desc)?;
        let rb = TargetsReadback::new(ctx, &targets)?;
        frames.frame(|f| {
            for (image, bytes) in uploads {
                let src = f.staging.push(bytes, 16)?;
                vellum_gpu::transfer::record_upload_from(
                    ctx,
                    f.cmd,
                    src,
                    image,
                    Access::ComputeRead,
                );
            }
            post.record(f, style, t, l.1, None)?;
            rb.record(f, &targets);
            Ok(())
        })?;
        let passes = frames.finish()?;
        let recorded = Recorded {
            slices: 0,
            lines: None,
        };
        Ok(recorded.image(size, rb.read()?, passes, None))
    }
}

/// A bricked frame's list of tiles for `ray_wake` and how many tiles the frame has.
type ListedTiles<'a> = Option<(&'a vellum_gpu::Buffer, u64)>;

/// The page table (staged here, its feedback cleared), feedback, ray states, channel sums,
/// tiles' list and the page table's header as uniforms of a bricked frame, and that list with
/// how many tiles the frame has; in core, the frame's tables and stand-ins.
fn paging_binds<'a>(
    ctx: &Arc<Context>,
    frame: &mut vellum_gpu::Frame,
    vol: VolumeRef<'a>,
    r: &RayFrame<'a>,
    state: &'a mut ViewState,
) -> Result<([Bind<'a>; 6], ListedTiles<'a>)> {
    let Some(p) = vol.paged() else {
        let binds = [
            Bind::StorageSlice(r.tables),
            Bind::StorageBuffer(r.stand_in),
            Bind::StorageBuffer(r.stand_in),
            Bind::StorageBuffer(r.stand_in),
            Bind::StorageBuffer(r.stand_in),
            Bind::UniformSlice(frame.staging.push_pod(&[0u32; HEADER])?),
        ];
        return Ok((binds, None));
    };
    // The entries, with the flags of the bricks whose range is known, written into the frame's
    // ring in place; the header as uniforms.
    let setup = r.setup;
    let planes = planes_level(p, &setup.camera, &setup.world, setup.size, vol.dims());
    let header = p.header(lod_line(setup, vol.dims()), planes);
    let entries = p.cache.page_table.len();
    let kept = state.page_words();
    let table = frame
        .staging
        .push_with(4 * ENTRY_WORDS * entries, 16, |dst| {
            p.page_words(
                bytemuck::cast_slice_mut(dst),
                &|range, channels| r.flags.of(range, channels),
                (vol.id(), r.flags.key()),
                kept,
            );
        })?;
    // The header as uniforms: the ray caster reads the levels' words at its lookups, and a CPU
    // device loads a storage buffer lane by lane, a loop at each load, but gathers uniforms (a
    // complete bricked frame 5 % faster on lavapipe).
    let head = frame.staging.push_pod(&header)?;
    p.record_clear_feedback(ctx, frame);
    // `add` and `max` keep each channel's sum while a ray waits for a brick.
    let project = r
        .channels
        .is_ok_and(|c| c.mix != crate::classify::channels::Mix::Over);
    let tile = [
        crate::render::raycast::LOCAL[0],
        crate::render::raycast::LOCAL[1],
    ];
    let b = state.ray_states(ctx, (r.setup.size, tile), project)?;
    let (tiles, count) = b.tiles;
    let binds = [
        Bind::StorageSlice(table),
        Bind::StorageBuffer(&p.feedback),
        Bind::StorageBuffer(b.rays),
        Bind::StorageBuffer(b.sums.unwrap_or(r.stand_in)),
        Bind::StorageBuffer(tiles),
        Bind::UniformSlice(head),
    ];
    Ok((binds, Some((tiles, count))))
}

/// Pass `ray_wake` before a resumed pass that waits: lists the tiles (`tiles` of them, of an
/// image of `size`) with a ray that a brick let go on in `list`, whose first words the ray
/// caster's indirect dispatch then reads; `paging` gives the page table, feedback and ray states.
fn record_wake(
    ctx: &Context,
    pipelines: &mut PipelineCache,
    frame: &mut vellum_gpu::Frame,
    paging: &[Bind; 6],
    (list, size, tiles): (&vellum_gpu::Buffer, [u32; 2], u64),
) -> Result<()> {
    use vellum_gpu::commands::{fill_buffer_range, memory_transition, update_buffer};
    let [tx, ty] = [0, 1].map(|a| size[a].div_ceil(crate::render::raycast::LOCAL[a]));
    // The dispatch (the tiles along x, no row yet, 1) and no tile counted; then none listed.
    memory_transition(ctx, frame.cmd, Access::IndirectRead, Access::TransferWrite);
    update_buffer(
        ctx,
        frame.cmd,
        list,
        bytemuck::cast_slice(&[tx, 0, 1, 0u32]),
    );
    fill_buffer_range(ctx, frame.cmd, list, (16, 4 * tiles), 0);
    memory_transition(
        ctx,
        frame.cmd,
        Access::TransferWrite,
        Access::ComputeReadWrite,
    );
    let wake = pipelines.get(&PipelineDesc::new(
        "render/ray_wake.comp",
        &[BindingKind::StorageBuffer; 4],
        16,
    ))?;
    let push: [u32; 4] = [size[0], size[1], tx, tiles as u32];
    frame.profiler.begin(frame.cmd, "ray_wake");
    let binds = [paging[0], paging[1], paging[2], Bind::StorageBuffer(list)];
    wake.dispatch(frame.cmd, &binds, &push, [tx, ty, 1])?;
    frame.profiler.end(frame.cmd);
    // The ray caster writes the feedback too, and reads the list and its dispatch.
    memory_transition(
        ctx,
        frame.cmd,
        Access::ComputeReadWrite,
        Access::ComputeReadWrite,
    );
    memory_transition(
        ctx,
        frame.cmd,
        Access::ComputeReadWrite,
        Access::IndirectRead,
    );
    Ok(())
}

/// The ray-casting step: of a volume in core, or through the brick cache's page table (staged
/// here), with its feedback cleared before and made visible to the host after.
fn record_rays(
    ctx: &Arc<Context>,
    pipelines: &mut PipelineCache,
    frame: &mut vellum_gpu::Frame,
    vol: VolumeRef,
    r: &RayFrame,
    state: &mut ViewState,
) -> Result<()> {
    let two_level = r.layers.is_some();
    let size = r.setup.size;
    let (paging, tiles) = paging_binds(ctx, frame, vol, r, state)?;
    // The ray states (and the stand-ins) are written by every frame's dispatch.
    vellum_gpu::commands::memory_transition(
        ctx,
        frame.cmd,
        Access::ComputeReadWrite,
        Access::ComputeReadWrite,
    );
    let waits = MODE_WAIT | MODE_RESUME;
    let listed = match (vol.paged(), tiles) {
        (Some(p), Some((list, count))) if p.mode & waits == waits => {
            record_wake(ctx, pipelines, frame, &paging, (list, size, count))?;
            Some(list)
        }
        _ => None,
    };
    RayCaster.record(
        frame,
        pipelines,
        &RayRequest {
            shading: r.binds,
            uniforms: &r.setup.uniforms,
            options: r.options,
            layers: r.layers,
            composite: r.composite,
            tables: r.tables,
            paging,
            listed,
            bricked: vol.paged().is_some(),
            labels: match r.labels {
                Some(l) => {
                    // Through the brick cache, its slots' indices; in core, the volume's.
                    let voxels = match vol.paged() {
                        Some(_) => vol.label_pool(),
                        None => l.voxels.as_ref(),
                    };
                    let voxels = voxels.ok_or_else(|| {
                        Error::Invalid(
                            "the brick cache was opened without the label volume; expected `labels` when the input is opened".into(),
                        )
                    })?;
                    (
                        [Bind::StorageBuffer(voxels), Bind::StorageBuffer(&l.table)],
                        true,
                        l.screens,
                    )
                }
                None => ([Bind::StorageBuffer(r.stand_in); 2], false, false),
            },
            channels: match r.channels {
                Ok(c) => {
                    // Through the brick cache, the channels' pools; in core, their textures.
                    let (lo, hi) = vol
                        .channel_pools()
                        .unwrap_or((&c.image, c.image_hi.as_ref()));
                    (
                        [
                            Bind::Sampled(lo, r.sampler),
                            Bind::Sampled(&c.tfs, r.sampler),
                            Bind::StorageBuffer(&c.bounds),
                            // Four or fewer channels: never read.
                            Bind::Sampled(hi.unwrap_or(lo), r.sampler),
                        ],
                        Some((c.mix, c.count)),
                    )
                }
                Err([volume, table]) => (
                    [
                        Bind::Sampled(volume, r.sampler),
                        Bind::Sampled(table, r.sampler),
                        Bind::StorageBuffer(r.stand_in),
                        Bind::Sampled(volume, r.sampler),
                    ],
                    None,
                ),
            },
            brick_reuse: vol.paged().is_some_and(|p| p.reuse),
            brick_span: vol.paged().is_some_and(|p| p.span),
            lod_steps: vol.paged().is_some_and(|p| p.lod_steps && !p.finest),
            widen: vol.paged().is_some_and(|p| p.widens()),
            trim: vol.paged().is_some_and(|p| p.trim),
            walk_batch: r
                .options
                .walk_batch
                .unwrap_or_else(|| walk_batch(&ctx.info)),
            gradient_at_sample: vol.gradient().is_none(),
            push: {
                let mut push = r.setup.ray_push(&r.options, vol.bricks().counts, two_level);
                // Mixed channels: the focus channel's component, where a sample's intensity is
                // read (the shader reads x only then).
                if let Ok(c) = r.channels {
                    push.flags[0] = c.focus as i32;
                }
                push
            },
            size,
        },
    )?;
    if vol.paged().is_some() {
        vellum_gpu::commands::memory_transition(
            ctx,
            frame.cmd,
            Access::ComputeReadWrite,
            Access::HostRead,
        );
    }
    Ok(())
}

/// What the ray-casting step of one frame works on.
struct RayFrame<'a> {
    setup: &'a FrameSetup,
    options: RayOptions,
    binds: &'a [Bind<'a>; 8],
    layers: Option<&'a crate::render::targets::TargetLayers>,
    composite: &'a Image,
    tables: BufferSlice,
    /// Bound for the brick cache's buffers in core, and for the label buffers without labels.
    stand_in: &'a vellum_gpu::Buffer,
    /// A label volume beside the input.
    labels: Option<&'a crate::classify::labels::GpuLabels>,
    /// Channels mixed in the ray, or the stand-ins (a 3D and a 2D image) bound without.
    channels: Result<&'a crate::classify::channels::GpuChannels, [&'a Image; 2]>,
    /// The sampler of the channels.
    sampler: &'a Sampler,
    /// What a brick of a known range may hold under this frame's classification (the page
    /// table's flags of a volume in the brick cache).
    flags: BrickFlags,
}

/// What a brick of a given range may hold under a classification: [`BRICK_VISIBLE`] when the
/// transfer function gives some of its samples opacity (always under an occlusion transfer
/// function), [`BRICK_FOCUS`] when some of them may be in focus. The in-core table's tests
/// (`any_opacity`, `may_focus`) in constant time, for the page table's entries of every frame.
struct BrickFlags {
    /// Per TF entry i, the entries before it that have opacity.
    opaque_before: Vec<u32>,
    focus: [f32; 3],
    uses_occlusion: bool,
    /// With mixed channels, each channel's `opaque_before`: a brick is visible where one of
    /// them gives its channel's range opacity.
    channels: Option<Vec<Vec<u32>>>,
}

/// Per entry i of `table`, the entries before it that have opacity (and the total last).
fn opaque_before(table: &[[f32; 4]]) -> Vec<u32> {
    let mut out = Vec::with_capacity(table.len() + 1);
    let mut n = 0;
    out.push(0);
    for c in table {
        n += (c[3] > 0.0) as u32;
        out.push(n);
    }
    out
}

/// Whether a table of `opaque_before` gives some value of the range `r` opacity.
fn opaque_in(opaque_before: &[u32], r: [u16; 2]) -> bool {
    let (first, last) = knots_touched(opaque_before.len() - 1, r);
    opaque_before[last + 1] > opaque_before[first]
}

impl BrickFlags {
    /// What the flags depend on, hashed: a page table whose words were made under the same key
    /// keeps them.
    fn key(&self) -> u64 {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        self.opaque_before.hash(&mut h);
        self.focus.map(f32::to_bits).hash(&mut h);
        self.uses_occlusion.hash(&mut h);
        self.channels.hash(&mut h);
        h.finish()
    }

    fn new(table: &[[f32; 4]], focus: [f32; 3], uses_occlusion: bool) -> Self {
        BrickFlags {
            opaque_before: opaque_before(table),
            focus,
            uses_occlusion,
            channels: None,
        }
    }

    /// These flags where `channels` are mixed: visibility from their functions.
    fn with_channels(mut self, channels: Option<&crate::classify::channels::GpuChannels>) -> Self {
        self.channels =
            channels.map(|c| c.skipping.iter().map(|(t, _)| opaque_before(t)).collect());
        self
    }

    /// The flags of a brick of range `r` whose mixed channels' ranges are `channels` (one per
    /// channel once read; a brick whose channels are not known is visible).
    fn of(&self, r: [u16; 2], channels: &[[u16; 2]]) -> u32 {
        let visible = match &self.channels {
            Some(c) if c.len() == channels.len() => c
                .iter()
                .zip(channels)
                .any(|(o, &cr)| cr == vellum_volume::bricks::UNKNOWN_RANGE || opaque_in(o, cr)),
            Some(_) => true,
            None => self.uses_occlusion || opaque_in(&self.opaque_before, r),
        };
        (if visible { BRICK_VISIBLE } else { 0 })
            | (if may_focus(&r, self.focus) {
                BRICK_FOCUS
            } else {
                0
            })
    }
}

/// A volume in the brick cache is drawn by the ray caster, without object-space lines (their
/// extraction reads the whole volume); say so in one sentence.
fn check_paged(vol: VolumeRef, view: &View) -> Result<()> {
    let Some(p) = vol.paged() else {
        if vol.gradient().is_none() && view.raycast.is_none() {
            return Err(Error::Invalid(
                "the volume's gradients do not fit the GPU budget, so only the ray caster draws it (making them at each sample); use `renderer: raycast`".into(),
            ));
        }
        return Ok(());
    };
    let budget = p.pool_bytes as f64 / (1 << 20) as f64;
    if view.raycast.is_none() {
        return Err(Error::Invalid(format!(
            "the volume is larger than the GPU budget ({budget:.0} MiB of bricks), so only the ray caster draws it; use `renderer: raycast`"
        )));
    }
    if let Some(style) = view.style.as_ref().filter(|s| s.def.lines.is_some()) {
        return Err(Error::Invalid(format!(
            "style {} ({}) draws object-space lines, which need the whole volume on the GPU; it is larger than the GPU budget ({budget:.0} MiB of bricks)",
            style.def.number, style.def.name
        )));
    }
    Ok(())
}

/// Segments from a label volume and mixed channels are drawn by the ray caster (in core or
/// through the brick cache).
fn check_labels(classify: &GpuClassification, view: &View) -> Result<()> {
    if classify.channels.is_some() && view.raycast.is_none() {
        return Err(Error::Invalid(
            "channels are mixed by the ray caster; use `renderer: raycast`".into(),
        ));
    }
    if classify.labels.is_none() {
        return Ok(());
    }
    if view.raycast.is_none() {
        return Err(Error::Invalid(
            "segments from a label volume are drawn by the ray caster; use `renderer: raycast`"
                .into(),
        ));
    }
    Ok(())
}

/// The level-of-detail line of a bricked frame: a sample at distance d from the eye covers
/// a·d + b level-0 voxels (its pixel's footprint there over the longest level-0 voxel edge).
fn lod_line(setup: &FrameSetup, dims: [usize; 3]) -> (f32, f32) {
    lod_of(&setup.camera, &setup.world, setup.size, dims)
}

fn lod_of(camera: &FrameCamera, world: &WorldBox, size: [u32; 2], dims: [usize; 3]) -> (f32, f32) {
    let cam = &camera.camera;
    let half = world.half;
    let voxel = (0..3)
        .map(|a| 2.0 * half[a] / dims[a] as f32)
        .fold(0.0f32, f32::max);
    let tan = (cam.fov_y_deg.to_radians() * 0.5).tan();
    let pixels = size[1].max(1) as f32;
    match cam.ortho {
        true => (
            0.0,
            2.0 * world.radius() * cam.distance * tan / pixels / voxel,
        ),
        false => (2.0 * tan / pixels / voxel, 0.0),
    }
}

/// A bricked frame that chooses levels by projected voxel size samples no finer than the finest
/// level it reads (see [`voxel_planes`]): two planes per voxel of that level instead of level
/// 0's, unless the view sets its planes. The first frames of a store, with its coarsest level
/// only, are quick, and the planes follow the bricks in. `None`: the view as it is.
fn paged_planes(vol: VolumeRef, view: &View) -> Option<View> {
    vol.paged().filter(|p| !p.finest)?;
    if view.slices.is_some() || view.raycast.is_none() {
        return None;
    }
    Some(View {
        slices: Some(2 * voxel_planes(vol, view)),
        ..view.clone()
    })
}

/// One plane per voxel along the longest axis of the finest level a frame of `vol` seen by
/// `view` reads: level 0 in core or through a cache that reads it only; else [`planes_level`].
/// A frame while the user drags takes this many planes, half the refined frame's, as VTK's
/// mapper widens its sample distance while the user interacts.
pub fn voxel_planes(vol: VolumeRef, view: &View) -> u32 {
    let longest = |dims: [usize; 3]| dims.into_iter().max().unwrap_or(1).max(1) as u32;
    let Some(p) = vol.paged().filter(|p| !p.finest) else {
        return longest(vol.dims());
    };
    let world = WorldBox::new(vol.dims(), vol.spacing(), &vol.geometry());
    let camera = FrameCamera::new(&world, view);
    let level = planes_level(p, &camera, &world, view.size, vol.dims());
    longest(p.levels.levels()[level].dims)
}

/// The finest level a bricked frame reads, for which its planes are chosen: the level the sample
/// at the box's point nearest the eye wants, and for a frame that neither waits for its bricks
/// nor resumes rays (the viewer's), no finer than what is resident. Samples that want a coarser
/// level step over planes (`Paged::lod_steps`).
fn planes_level(
    p: &crate::passes::paging::Paged,
    camera: &FrameCamera,
    world: &WorldBox,
    size: [u32; 2],
    dims: [usize; 3],
) -> usize {
    let levels = p.levels.levels();
    if p.finest {
        return 0;
    }
    let (a, b) = lod_of(camera, world, size, dims);
    let nearest = (camera.eye - camera.eye.clamp(-world.half, world.half)).length();
    let cover = (a * nearest + b).max(1.0);
    let level = (cover.log2().floor() as usize).min(levels.len() - 1);
    // Waiting or resumed rays keep the planes their passes began with.
    let waits = crate::passes::paging::MODE_WAIT | crate::passes::paging::MODE_RESUME;
    if p.mode & waits != 0 {
        return level;
    }
    level.max(
        p.cache
            .finest_resident(&p.levels)
            .unwrap_or(levels.len() - 1),
    )
}

/// What the style passes of one frame work on: the frame's setup, the style, the layers and the
/// style passes' images.
struct StyleFrame<'a> {
    setup: &'a FrameSetup,
    style: &'a Style,
    images: &'a TargetImages,
    post: &'a PostTargets,
    /// A label volume beside the volume: its segments' lines are drawn instead of the volume's.
    labels: Option<&'a GpuLabels>,
}

/// The geometry of one frame's object-space lines: the extraction's frame and parameters, and
/// the raster view that draws them into the edge layer.
struct LineGeometry {
    spacing: [f32; 3],
    eye: vellum_volume::lines::Eye,
    params: vellum_volume::lines::LineParams,
    view: RasterView,
}

/// The lines of the frame's style (of `kind`): what to extract and how to draw it.
fn line_geometry(vol: &VolumeTextures, f: &StyleFrame, kind: LineKind) -> LineGeometry {
    use vellum_volume::lines::{Eye, LineParams};
    let (setup, p) = (f.setup, &f.style.params);
    let (eye, view_dir) = (setup.camera.eye, setup.camera.view_dir);
    let spacing = vol.spacing.map(|s| s as f32);
    let longest = setup.world.longest as f32;
    let scale = spacing.map(|s| s / longest);
    let offset: [f32; 3] =
        std::array::from_fn(|a| (0.5 - 0.5 * vol.dims[a] as f32) * spacing[a] / longest);
    // The eye in the extraction's frame (index × spacing): box · longest plus the box centre's
    // position there.
    let eye_line = match setup.camera.camera.ortho {
        true => Eye::Direction((-view_dir).to_array()),
        false => Eye::Point(std::array::from_fn(|a| {
            eye[a] * longest + (0.5 * vol.dims[a] as f32 - 0.5) * spacing[a]
        })),
    };
    let min_spacing = spacing.iter().copied().fold(f32::INFINITY, f32::min);
    LineGeometry {
        spacing,
        eye: eye_line,
        params: LineParams {
            // The focus surface: the isovalue, or a range's lower bound.
            iso: setup.focus[0],
            silhouettes: p.line_both || kind == LineKind::Silhouettes,
            suggestive: p.line_both || kind == LineKind::SuggestiveContours,
            min_angle_deg: p.line_angle,
            derivative_threshold: p.line_derivative_threshold,
            stride: p.line_stride,
            smooth: p.line_smooth.radius(vol.auto_line_smooth),
            seeded: p.line_seeded,
        },
        view: RasterView {
            view_proj: setup.uniforms.view_proj,
            index_scale: scale,
            index_offset: offset,
            eye: eye.to_array(),
            view_dir: view_dir.to_array(),
            bias: p.line_depth_bias * min_spacing / longest,
            value: 1.0,
            floor: 0.0,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classify::transfer::TransferFunction;
    use crate::render::camera::Camera;
    use crate::render::view::Lighting;

    /// The host side of Shepp–Logan at 64³ under the grey ramp, with an isosurface focus.
    struct Host {
        bricks: Bricks,
        range: [f64; 2],
        table: Vec<[f32; 4]>,
        modulation: Modulation,
    }

    fn host() -> Host {
        let v = vellum_volume::phantom::shepp_logan(64);
        let (texels, range) = v.normalised_u16();
        Host {
            bricks: Bricks::new(&texels, v.dims),
            range,
            table: TransferFunction::preset("grey").unwrap().table(256),
            modulation: Modulation::default(),
        }
    }

    fn input(h: &Host) -> SetupInput<'_> {
        SetupInput {
            dims: [64; 3],
            spacing: [1.0; 3],
            geometry: Geometry::default(),
            range: h.range,
            bricks: &h.bricks,
            table: &h.table,
            focus: Focus::Iso(0.9),
            labels_focus: false,
            channels: None,
            modulation: &h.modulation,
            uses_occlusion: false,
            has_occlusion: false,
            has_importance: false,
            max_image_size: 4096,
        }
    }

    fn view() -> View {
        View {
            camera: Camera::default(),
            size: [64, 48],
            slices: None,
            one_pass: false,
            lighting: Lighting::default(),
            style: None,
            fit: true,
            raycast: None,
        }
    }

    #[test]
    fn a_two_level_frame_is_set_up_without_a_device() {
        let h = host();
        let s = FrameSetup::new(&input(&h), &view()).unwrap();
        assert_eq!(s.proxy.slices, 128, "two planes per voxel");
        let focus = s
            .focus_proxy
            .as_ref()
            .expect("two levels have a focus level");
        // The skull's bricks are a part of the volume, and the focus level is cut to them.
        let kept = h
            .bricks
            .range
            .iter()
            .filter(|r| may_focus(r, s.focus))
            .count();
        assert!(kept > 0 && kept < h.bricks.range.len(), "{kept} bricks");
        assert!(!focus.vertices.is_empty());
        assert!(s.ray_tables.is_none());
        assert_eq!(s.uniforms.focus[2], 2.0, "an isosurface focus");
        // The camera was fitted once and is what the uniforms carry.
        assert_eq!(s.uniforms.view_proj, s.camera.view_proj.to_cols_array_2d());
        assert_ne!(s.camera.camera.distance, Camera::default().distance);
    }

    #[test]
    fn a_ray_cast_frame_has_tables_and_no_planes() {
        let h = host();
        let v = View {
            raycast: Some(RayOptions::default()),
            ..view()
        };
        let s = FrameSetup::new(&input(&h), &v).unwrap();
        assert!(s.proxy.vertices.is_empty() && s.focus_proxy.is_none());
        let tables = s.ray_tables.as_ref().unwrap();
        assert_eq!(tables.len(), 256 + h.bricks.range.len());
        let focus_bricks = tables[256..]
            .iter()
            .filter(|f| *f & BRICK_FOCUS != 0)
            .count();
        assert!(focus_bricks > 0 && focus_bricks < h.bricks.range.len());
        let span = s.depth_span.1 - s.depth_span.0;
        assert!((s.proxy.spacing * s.proxy.slices as f32 - span).abs() < 1e-5);
        let push = s.ray_push(&RayOptions::default(), h.bricks.counts, true);
        assert_eq!(push.planes[0], s.depth_span.1);
        assert_eq!(push.bricks[..3], [4, 4, 4]);
    }

    #[test]
    fn errors_name_the_keys() {
        let h = host();
        let refused = |v: View, i: &SetupInput| FrameSetup::new(i, &v).unwrap_err().to_string();
        let styled = Style::new("canny", Default::default()).unwrap();
        let one_pass = View {
            style: Some(styled),
            one_pass: true,
            ..view()
        };
        assert!(refused(one_pass, &input(&h)).contains("drop `one_pass`"));
        let no_focus = SetupInput {
            focus: Focus::None,
            ..input(&h)
        };
        let styled_view = View {
            style: Some(styled),
            ..view()
        };
        assert!(refused(styled_view, &no_focus).contains("`iso`, `focus` or `focus_labels`"));
        let empty = View {
            size: [0, 10],
            ..view()
        };
        assert!(refused(empty, &input(&h)).contains("`size`"));
        let planes = View {
            slices: Some(MAX_SLICES + 1),
            ..view()
        };
        assert!(refused(planes, &input(&h)).contains("`slices`"));
        let otf = SetupInput {
            uses_occlusion: true,
            ..input(&h)
        };
        assert!(refused(view(), &otf).contains("occlusion volume"));
    }

    #[test]
    fn brick_classification() {
        let iso = [0.5, f32::INFINITY, 2.0];
        assert!(may_focus(&[0, 40000], iso) && !all_focus(&[0, 40000], iso));
        assert!(all_focus(&[40000, 60000], iso) && !may_focus(&[0, 30000], iso));
        let range = [0.2, 0.4, 1.0];
        assert!(may_focus(&[0, 20000], range) && !may_focus(&[30000, 65535], range));
        assert!(!may_focus(&[0, 65535], [0.0, 0.0, 0.0]));
        // Opacity only above 0.5 of the range: a brick of low intensities is empty.
        let table: Vec<[f32; 4]> = (0..256)
            .map(|i| [1.0, 1.0, 1.0, if i >= 128 { 1.0 } else { 0.0 }])
            .collect();
        assert!(!any_opacity(&table, &[0, 30000]));
        assert!(any_opacity(&table, &[0, 33000]));
        // A ramp from 0: a brick of zeros is empty, one reaching a step above is not.
        let ramp: Vec<[f32; 4]> = (0..256)
            .map(|i| [1.0, 1.0, 1.0, i as f32 / 255.0])
            .collect();
        assert!(!any_opacity(&ramp, &[0, 0]));
        assert!(any_opacity(&ramp, &[0, 1]));
        assert_eq!(knots_touched(256, [257, 514]), (1, 2));
        assert_eq!(knots_touched(256, [256, 515]), (0, 3));
        assert_eq!(knots_touched(256, [65535, 65535]), (255, 255));
        let before = opaque_before(&ramp);
        assert!(!opaque_in(&before, [0, 0]) && opaque_in(&before, [0, 1]));
    }
}
