//! The compute-shader ray caster (SPEC §6), beside the slicer: `glsl/render/raycast.comp`.
//!
//! It shares everything but the sampling loop with the slicer (`crate::render::slicer`): the
//! uniforms, the classification and shading code (`shade.glsl` with `RAYCAST` defined), the brick
//! ranges and the named layers, so styles, importance modulation, occlusion transfer functions and
//! feature maps work on it unchanged.
//!
//! ## Sampling
//! A ray samples where the slicer's view-aligned planes cross it: steps of `spacing` in depth
//! along the view direction (so `spacing / cos θ` along an off-axis ray), with the slicer's
//! opacity correction. At the same number of planes the two renderers therefore sample the same
//! points, which is what makes their images comparable pixel for pixel; the ray caster composites
//! front to back in registers, the slicer back to front in a float target.
//!
//! With `sampling: world-steps`, samples are instead one spacing apart along each ray from the box
//! entry, which is what the opacity correction assumes on every ray; images then differ from the
//! slicer's off the image centre (a test bounds by how much).
//!
//! ## Speed-ups that keep the image
//! - Empty-space skipping: bricks (16³ voxels with a one-voxel apron) that hold nothing visible
//!   under the current transfer function and focus are stepped over to the first plane behind
//!   them. Samples are never moved, so the image is the same as without skipping.
//! - Early ray termination once the accumulated opacity reaches `ert` (default 0.99): what is
//!   left behind can change a pixel by at most `1 − ert` of its value.
//!
//! ## Isosurfaces
//! With `refine_iso` and an isosurface focus, the first focus sample is moved onto the surface:
//! regula falsi between it and the previous plane's sample (which is below the isovalue). The
//! depth layer then holds the surface's depth to a small fraction of a voxel, and shading is taken
//! on the surface.
//!
//! ## Jitter
//! An optional per-pixel offset of the planes, in (−½, ½) of a spacing from a seeded hash, turns
//! the wood-grain rings that regular slicing leaves on opaque surfaces into fine noise. Off by
//! default, so that images match the slicer.

use crate::render::shading::{SliceUniforms, SHADE_BINDINGS};
use crate::render::targets::TargetLayers;
pub use crate::render::view::{RayOptions, Sampling};
use std::sync::Arc;
use vellum_error::Result;
use vellum_gpu::{
    Access, Bind, BindingKind, BufferSlice, ComputePipeline, Image, PipelineCache, PipelineDesc,
};

/// Push constants of `raycast.comp`.
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct RayPush {
    /// Clip space to the box frame.
    pub(crate) inv_view_proj: [[f32; 4]; 4],
    /// Depth of the farthest plane's reference along the view direction, spacing, planes, ert.
    pub(crate) planes: [f32; 4],
    /// Brick counts along x, y, z, and the brick size in voxels.
    pub bricks: [i32; 4],
    /// Two levels (or, with mixed channels, the focus channel's component), skip empty bricks,
    /// jitter seed (0 off), bit 0 refine isosurface hits | bit 1 equal world steps. The modes
    /// (two levels, world steps) are selected by the pipeline's [`Variant`]; the shader reads
    /// only y, z and bit 0 of w, each behind its variant bit, and x behind the channels'.
    pub flags: [i32; 4],
}

/// Brick flag: may hold visible context (or one-pass) samples.
pub(crate) const BRICK_VISIBLE: u32 = 1;
/// Brick flag: may hold focus samples.
pub(crate) const BRICK_FOCUS: u32 = 2;

/// Bindings: the slicer's eight (`shade.glsl`), then the five layers as storage images, the
/// brick flags, the brick cache's page table, feedback and ray states (`passes::paging`), a
/// label volume's voxels and table (`classify::labels`), mixed channels' texture, transfer
/// functions and opacity bounds (`classify::channels`), the channels' sums and the tiles'
/// liveness of a bricked frame that waits, and the page table's header as uniforms.
pub(crate) const RAY_BINDINGS: [BindingKind; 26] = {
    let slicer = SHADE_BINDINGS;
    let mut all = [BindingKind::StorageBuffer; 26];
    let mut i = 0;
    while i < slicer.len() {
        all[i] = slicer[i];
        i += 1;
    }
    while i < 13 {
        all[i] = BindingKind::StorageImage;
        i += 1;
    }
    all[19] = BindingKind::SampledImage;
    all[20] = BindingKind::SampledImage;
    all[22] = BindingKind::SampledImage;
    all[25] = BindingKind::UniformBuffer;
    all
};

/// Workgroup size of `raycast.comp`.
pub(crate) const LOCAL: [u32; 3] = [8, 8, 1];

pub(crate) use crate::classify::transfer::opacity_bounds;

/// The bits of `raycast.comp`'s specialisation constant `VARIANT` (`shade.glsl`).
///
/// A CPU rasteriser such as lavapipe runs both sides of every branch its SIMD lanes could diverge
/// on, and does not skip a block whose condition is a uniform that happens to be false: a frame
/// without occlusion TFs still paid for their two texture fetches at every sample. So the ray
/// caster is compiled per set-up, with what a frame does not use left out. Modes (two levels,
/// world steps) select code; the other bits enable code that still tests its uniform, so setting
/// one is never wrong, only slower.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub(crate) struct Variant(pub u32);

impl Variant {
    /// Mode: two levels, writing the focus and context layers (else the one-pass composite).
    pub(crate) const TWO_LEVEL: u32 = 1;
    /// Steps over bricks that hold nothing visible (`RayOptions::skip_empty`).
    pub(crate) const SKIP_EMPTY: u32 = 2;
    /// Jitters the planes per pixel (`RayOptions::jitter`).
    pub(crate) const JITTER: u32 = 4;
    /// Refines the first isosurface hit by regula falsi (`RayOptions::refine_iso`; two levels).
    pub(crate) const REFINE_ISO: u32 = 8;
    /// Mode: equal steps along each ray ([`Sampling::WorldSteps`]) instead of the slicer's planes.
    pub(crate) const WORLD_STEPS: u32 = 16;
    /// Classifies through the occlusion transfer function when the `focus` uniform's w says so.
    pub(crate) const OTF: u32 = 32;
    /// Modulates opacity by importance (eq. 5) where the `mod_flags` uniform enables it.
    pub(crate) const MOD_OPACITY: u32 = 64;
    /// Modulates the shaded colour by importance: stippling (eq. 6) or colour (eq. 3, 4).
    pub(crate) const MOD_SHADE: u32 = 128;
    /// Samples through the brick cache's page table (skipping the bricks its words say are empty,
    /// at the level each sample reads, instead of the in-core table's).
    pub(crate) const BRICKED: u32 = 256;
    /// With BRICKED: each ray reuses its last brick's place in the pool (`Paged::reuse`).
    pub(crate) const BRICK_REUSE: u32 = 512;
    /// With BRICKED: each ray keeps the stretch of its path over which its last lookup holds
    /// (its brick, and its level by distance) and places the samples there by one multiply-add
    /// (`Paged::span`).
    pub(crate) const BRICK_SPAN: u32 = 1024;
    /// Reads each sample's segment from a label volume: its colour, whether it is drawn, and
    /// (with focus ids) its level.
    pub(crate) const LABELS: u32 = 2048;
    /// Mixes channels by `over` at each sample (`classify::channels`).
    pub(crate) const MIX_OVER: u32 = 4096;
    /// Mixes channels by `add` at each sample.
    pub(crate) const MIX_ADD: u32 = 8192;
    /// Projects each channel to its maximum along the ray (one level).
    pub(crate) const MIX_MAX: u32 = 16384;
    /// In core, the walk to a ray's next contributing sample fetches four samples at once
    /// ([`walk_batch`]).
    pub(crate) const WALK_BATCH: u32 = 32768;
    /// With a mix: the channels mixed, less one, in bits 16-18 (`shade.glsl`'s `CHANNEL_COUNT`).
    pub(crate) const CHANNELS_SHIFT: u32 = 16;
    /// A label volume hides a segment: samples that blend its voxels add nothing.
    pub(crate) const LABELS_SCREEN: u32 = 1 << 19;
    /// With BRICKED, by the level-of-detail rule: samples that want a level coarser than the
    /// planes' step over planes (`Paged::lod_steps`; a frame at `--lod finest` never does, and
    /// the test per sample cost it 5-8 % on lavapipe).
    pub(crate) const LOD_STEPS: u32 = 1 << 20;
    /// With LOD_STEPS, in a frame drawn around missing bricks: a sample that a coarser level
    /// stands in for is that level's voxel long (`Paged::widen`).
    pub(crate) const WIDEN: u32 = 1 << 21;
    /// With BRICKED and skipping: a ray passes the bricks and sub-blocks known to hold nothing it
    /// needs in front of it in a loop that only looks them up, before its walk (`Paged::trim`).
    pub(crate) const TRIM: u32 = 1 << 22;
    /// No gradient texture (in core where the gradients do not fit, and every bricked frame):
    /// each shaded sample's Sobel gradient is made from 26 fetches of the intensity
    /// (`shade.glsl`'s `sobel_at`).
    pub(crate) const GRADIENT_AT_SAMPLE: u32 = 1 << 23;

    /// The variant for a frame with these options, level mode and uniforms, of a bricked volume
    /// or one in core.
    pub fn of(
        options: &RayOptions,
        two_level: bool,
        uniforms: &SliceUniforms,
        bricked: bool,
    ) -> Self {
        let bits = [
            (two_level, Self::TWO_LEVEL),
            (options.skip_empty, Self::SKIP_EMPTY),
            (bricked, Self::BRICKED),
            (options.jitter.is_some(), Self::JITTER),
            (options.refine_iso && two_level, Self::REFINE_ISO),
            (options.sampling == Sampling::WorldSteps, Self::WORLD_STEPS),
            (uniforms.focus[3] > 0.5, Self::OTF),
            (uniforms.mod_flags[1] != 0, Self::MOD_OPACITY),
            (uniforms.mod_flags[3] != 0, Self::MOD_SHADE),
        ];
        Variant(bits.iter().filter(|(on, _)| *on).map(|(_, b)| b).sum())
    }
}

/// Whether rays in core walk to their next contributing sample four samples at a time on a
/// device `info` describes (the `WALK_BATCH` variant; the shader's `walk_batch`). On a GPU a lone
/// ray is a chain of dependent fetches, and a small frame lasts as long as its longest ray's
/// chain (issue 43); four fetches in flight together shorten it. On by default on a GPU; off on a
/// CPU rasteriser, whose lanes pay for every fetch, the batch's speculative ones too.
/// `VELLUM_WALK_BATCH=0|1` overrides, for measuring. The image is the same either way.
pub(crate) fn walk_batch(info: &vellum_gpu::DeviceInfo) -> bool {
    info.on_gpu_unless("VELLUM_WALK_BATCH")
}

/// What the ray caster draws in one frame.
pub(crate) struct RayRequest<'a> {
    /// The eight bindings of `shade.glsl` (`render::shading::SHADE_BINDINGS`).
    pub(crate) shading: &'a [Bind<'a>; 8],
    /// The frame's uniforms, from which the pipeline variant is chosen.
    pub(crate) uniforms: &'a SliceUniforms,
    /// The ray caster's options for this frame.
    pub options: RayOptions,
    /// The two-level layers; `None` draws one pass into `composite`.
    pub layers: Option<&'a TargetLayers>,
    /// The composite: the one-pass frame, or a two-level frame's context over its focus.
    pub composite: &'a Image,
    /// The opacity bounds and brick flags staged for this frame (`RayTables`).
    pub tables: BufferSlice,
    /// The page table, feedback, ray states, the channels' sums, the tiles' liveness and the page
    /// table's header as uniforms of a bricked volume (stand-ins in core, and for the sums
    /// without `add` or `max` mixing).
    pub paging: [Bind<'a>; 6],
    /// A resumed pass that waits: the tiles `ray_wake` listed, whose first words are the
    /// dispatch (one workgroup per listed tile).
    pub listed: Option<&'a vellum_gpu::Buffer>,
    /// Whether the volume is drawn through the brick cache (the `BRICKED` variant).
    pub bricked: bool,
    /// A label volume's voxels and table (stand-ins without one), and whether there is one
    /// (the `LABELS` variant).
    pub(crate) labels: ([Bind<'a>; 2], bool, bool),
    /// Mixed channels' texture, transfer functions, opacity bounds and texture of channels 4–7
    /// (stand-ins without), and their mix and count.
    pub(crate) channels: (
        [Bind<'a>; 4],
        Option<(crate::classify::channels::Mix, usize)>,
    ),
    /// With `bricked`: rays reuse their last brick's lookup (`Paged::reuse`).
    pub(crate) brick_reuse: bool,
    /// With `bricked`: rays keep the stretch over which their last lookup holds (`Paged::span`).
    pub(crate) brick_span: bool,
    /// With `bricked`: its samples may step over planes (`Paged::lod_steps`, not at finest).
    pub(crate) lod_steps: bool,
    /// With `lod_steps`: the frame is drawn around missing bricks (`Paged::widens`).
    pub(crate) widen: bool,
    /// With `bricked` and skipping: rays pass the empty bricks in front of them before their walk
    /// (`Paged::trim`).
    pub(crate) trim: bool,
    /// Rays in core walk four samples at a time to their next contributing one ([`walk_batch`]).
    pub(crate) walk_batch: bool,
    /// No gradient texture: each shaded sample's gradient is made from the intensity (in core,
    /// `GradientSource::AtSample`; bricked, always), the `GRADIENT_AT_SAMPLE` variant.
    pub(crate) gradient_at_sample: bool,
    /// The push constants of `raycast.comp`.
    pub push: RayPush,
    /// The image size in pixels, width and height: one invocation per pixel.
    pub size: [u32; 2],
}

/// The ray caster. Its pipelines, one per variant, live in the caller's [`PipelineCache`]: built
/// when a frame first needs one and kept. At most 1,024 exist; a session uses a handful.
#[derive(Copy, Clone, Debug, Default)]
pub(crate) struct RayCaster;

impl RayCaster {
    /// The pipeline of `variant`, built on first use.
    pub(crate) fn pipeline(
        pipelines: &mut PipelineCache,
        variant: Variant,
    ) -> Result<Arc<ComputePipeline>> {
        pipelines.get(
            &PipelineDesc::new(
                "render/raycast.comp",
                &RAY_BINDINGS,
                std::mem::size_of::<RayPush>() as u32,
            )
            .constants(&[variant.0]),
        )
    }

    /// Pass `raycast`: one dispatch writing every layer (or the one-pass composite) as storage
    /// images.
    pub fn record(
        &self,
        frame: &mut vellum_gpu::Frame,
        pipelines: &mut PipelineCache,
        r: &RayRequest,
    ) -> Result<()> {
        let cmd = frame.cmd;
        let out = |pick: fn(&TargetLayers) -> &Image| r.layers.map_or(r.composite, pick);
        let images = [
            out(|l| &l.focus_phong),
            out(|l| &l.focus_diffuse),
            out(|l| &l.focus_depth),
            out(|l| &l.context),
            r.composite,
        ];
        for image in images {
            image.transition(cmd, Access::ComputeWrite);
        }
        // On the stack: a steady frame allocates nothing here.
        let s = r.shading;
        let [i0, i1, i2, i3, i4] = images.map(Bind::StorageImage);
        let [p0, p1, p2, p3, p4, p5] = r.paging;
        let [l0, l1] = r.labels.0;
        let [c0, c1, c2, c3] = r.channels.0;
        let binds: [Bind; 26] = [
            s[0],
            s[1],
            s[2],
            s[3],
            s[4],
            s[5],
            s[6],
            s[7],
            i0,
            i1,
            i2,
            i3,
            i4,
            Bind::StorageSlice(r.tables),
            p0,
            p1,
            p2,
            l0,
            l1,
            c0,
            c1,
            c2,
            c3,
            p3,
            p4,
            p5,
        ];
        let mut variant = Variant::of(&r.options, r.layers.is_some(), r.uniforms, r.bricked);
        if r.bricked && r.brick_reuse {
            variant.0 |= Variant::BRICK_REUSE;
        }
        if r.bricked && r.brick_span {
            variant.0 |= Variant::BRICK_SPAN;
        }
        if r.bricked && r.lod_steps {
            variant.0 |= Variant::LOD_STEPS;
            if r.widen {
                variant.0 |= Variant::WIDEN;
            }
        }
        if r.bricked && r.trim && r.options.skip_empty {
            variant.0 |= Variant::TRIM;
        }
        if r.labels.1 {
            variant.0 |= Variant::LABELS;
        }
        if r.labels.2 {
            variant.0 |= Variant::LABELS_SCREEN;
        }
        if r.walk_batch {
            variant.0 |= Variant::WALK_BATCH;
        }
        if r.gradient_at_sample {
            variant.0 |= Variant::GRADIENT_AT_SAMPLE;
        }
        if let Some((mix, count)) = r.channels.1 {
            variant.0 |= match mix {
                crate::classify::channels::Mix::Over => Variant::MIX_OVER,
                crate::classify::channels::Mix::Add => Variant::MIX_ADD,
                crate::classify::channels::Mix::Max => Variant::MIX_MAX,
            };
            variant.0 |= (count.clamp(1, 8) as u32 - 1) << Variant::CHANNELS_SHIFT;
        }
        let pipeline = Self::pipeline(pipelines, variant)?;
        let groups = vellum_gpu::pipeline::group_count([r.size[0], r.size[1], 1], LOCAL);
        frame.profiler.begin(cmd, "raycast");
        match r.listed {
            Some(list) => pipeline.dispatch_indirect(cmd, &binds, &r.push, list, 0)?,
            None => pipeline.dispatch(cmd, &binds, &r.push, groups)?,
        }
        frame.profiler.end(cmd);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn push_constants_fit_the_guaranteed_minimum() {
        assert!(std::mem::size_of::<RayPush>() <= 128);
    }

    #[test]
    fn opacity_bounds_cover_linear_filtering() {
        // A ramp from texel 100 to 110 and one spike at 200.
        let table: Vec<[f32; 4]> = (0..256)
            .map(|i| {
                let a = match i {
                    100..=110 => (i - 99) as f32 / 11.0,
                    111..=199 => 1.0,
                    200 => 0.5,
                    _ => 0.0,
                };
                [1.0, 1.0, 1.0, a]
            })
            .collect();
        let b = opacity_bounds(&table);
        // Every value filtering can return between texel centres i and i + 1 is at most b[i].
        for i in 0..256usize {
            for k in 0..=8 {
                let w = k as f32 / 8.0;
                let j = (i + 1).min(255);
                let filtered = table[i][3] * (1.0 - w) + table[j][3] * w;
                assert!(filtered <= b[i], "texel {i}, weight {w}");
            }
        }
        assert_eq!(b[98], 0.0);
        assert_eq!(b[99], table[100][3]);
        assert_eq!(b[199], 1.0);
        assert_eq!(b[201], 0.0);
        assert_eq!(b[255], 0.0);
    }

    #[test]
    fn variants_follow_the_frame() {
        let mut u: SliceUniforms = bytemuck::Zeroable::zeroed();
        let o = RayOptions::default();
        assert_eq!(Variant::of(&o, false, &u, false).0, Variant::SKIP_EMPTY);
        // Bricked frames skip through the page table's flags.
        assert_eq!(
            Variant::of(&o, false, &u, true).0,
            Variant::BRICKED | Variant::SKIP_EMPTY
        );
        u.focus[3] = 1.0;
        u.mod_flags = [1, 1, 0, 3];
        let o = RayOptions {
            jitter: Some(3),
            refine_iso: true,
            sampling: Sampling::WorldSteps,
            skip_empty: false,
            ..Default::default()
        };
        assert_eq!(
            Variant::of(&o, true, &u, false).0,
            0xff & !Variant::SKIP_EMPTY
        );
        // Refinement only exists in two levels.
        assert_eq!(Variant::of(&o, false, &u, false).0 & Variant::REFINE_ISO, 0);
    }
}
