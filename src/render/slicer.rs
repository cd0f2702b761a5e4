//! The 3D-texture slice renderer with two levels (SPEC TL2, TL3; two-level paper §3, §3.1).
//!
//! View-aligned proxy polygons are drawn back to front with premultiplied "over" blending. Each
//! fragment samples the normalised intensity, classifies it (`glsl/common/classify.glsl`: the 1D
//! transfer function or the occlusion one, opacity corrected for the slice spacing) and shades it
//! with the Sobel gradient (`glsl/common/shading.glsl`).
//!
//! Two levels: pass `focus` renders only the focus samples into three targets at once (Phong with
//! specular, diffuse only, linear depth) plus a D32 depth buffer holding the nearest focus sample.
//! Pass `context` renders every other sample, depth-tested against that buffer, so context hidden
//! behind the focus is dropped. Pass `composite` lays the context over the focus. With an opaque
//! focus this equals the classic single pass (`one_pass`), which is the paper's claim and a test.
//!
//! ## Frames
//! [`Renderer::record`] records one frame into a caller's [`gpu::Frame`]: the per-frame uniforms
//! and proxy vertices go into the frame's staging ring, the classification textures are
//! re-uploaded only if they changed, and the layers land in persistent [`FrameTargets`]. Nothing
//! is allocated in steady state. [`Renderer::render`] is the one-shot form for tools and tests: one
//! frame plus a readback.

use crate::classify::modulation::Modulation;
use crate::classify::textures::GpuClassification;
use crate::classify::transfer::TransferFunction;
pub use crate::classify::Focus;
use crate::error::{Error, Result};
use crate::gpu::graphics::{
    begin_rendering, end_rendering, Blend, DepthState, GraphicsDesc, GraphicsPipeline, Load,
};
use crate::gpu::profiler::PassTime;
use crate::gpu::{
    self, Access, Bind, BindingKind, BufferSlice, Context, Frames, FramesDesc, Image, ImageDesc,
    Sampler,
};
use crate::passes::normals::{Bricks, VolumeTextures};
use crate::render::camera::Camera;
use crate::render::post::Post;
use crate::render::proxy::{depth_span, view_aligned_slices_in, ProxySlices};
use crate::render::raycast::{RayOptions, RayPush, BRICK_FOCUS, BRICK_VISIBLE};
use crate::render::style::Style;
use crate::render::targets::{FrameTargets, TargetsReadback, COLOR, DEPTH, LINEAR_DEPTH};
use ash::vk;
use glam::Vec3;
use std::sync::Arc;

/// Uniforms of the slice shaders (GLSL twin: `SliceUniforms` in render.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct SliceUniforms {
    pub view_proj: [[f32; 4]; 4],
    pub half_extent: [f32; 4],
    pub eye: [f32; 4],
    pub view_dir: [f32; 4],
    pub light: [f32; 4],
    pub material: [f32; 4],
    pub focus: [f32; 4],
    /// x colour mode (0 off, 1 raw, 2 abs), y opacity on, z stipple on, w levels (1 focus,
    /// 2 context, 3 both; 0 when nothing is modulated).
    pub mod_flags: [i32; 4],
    /// x γ, y base colour (0 ambient, 1 Phong).
    pub mod_color: [f32; 4],
    /// t_l, t_h, k_l, k_h (eq. 5).
    pub mod_opacity: [f32; 4],
    /// x t, y f (eq. 6).
    pub mod_stipple: [f32; 4],
    /// x stipple seed.
    pub mod_seed: [u32; 4],
    pub stipple_white: [f32; 4],
    pub stipple_black: [f32; 4],
    /// Volume size in voxels (xyz), for the stipple grid.
    pub volume_dims: [f32; 4],
}

impl SliceUniforms {
    /// Writes the modulation fields (all off when `m` is inactive).
    fn set_modulation(&mut self, m: &Modulation, dims: [usize; 3]) {
        use crate::classify::modulation::{ApplyTo, ColorMode, ModulateLighting};
        let levels = match m.apply_to {
            ApplyTo::Focus => 1,
            ApplyTo::Context => 2,
            ApplyTo::Both => 3,
        };
        self.mod_flags = [
            match m.color.map(|c| c.mode) {
                None => 0,
                Some(ColorMode::Raw) => 1,
                Some(ColorMode::Abs) => 2,
            },
            m.opacity.is_some() as i32,
            m.stipple.is_some() as i32,
            if m.is_active() { levels } else { 0 },
        ];
        self.mod_color = [
            m.color.map_or(0.0, |c| c.gamma),
            (m.lighting == ModulateLighting::Phong) as i32 as f32,
            0.0,
            0.0,
        ];
        if let Some(o) = &m.opacity {
            self.mod_opacity = [o.t_low, o.t_high, o.k_low, o.k_high];
        }
        if let Some(st) = &m.stipple {
            self.mod_stipple = [st.t, st.f, 0.0, 0.0];
            self.mod_seed = [st.seed, 0, 0, 0];
            self.stipple_white = [st.white[0], st.white[1], st.white[2], 1.0];
            self.stipple_black = [st.black[0], st.black[1], st.black[2], 1.0];
        }
        self.volume_dims = [dims[0] as f32, dims[1] as f32, dims[2] as f32, 0.0];
    }
}

/// Phong lighting with a headlight (the light comes from the eye).
#[derive(Copy, Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Lighting {
    pub ambient: f32,
    pub diffuse: f32,
    pub specular: f32,
    /// Specular exponent.
    pub shininess: f32,
}

impl Default for Lighting {
    fn default() -> Self {
        Lighting {
            ambient: 0.25,
            diffuse: 0.75,
            specular: 0.35,
            shininess: 24.0,
        }
    }
}

impl Lighting {
    /// Checks that the coefficients are finite and not negative.
    pub fn validate(&self) -> Result<()> {
        let all = [self.ambient, self.diffuse, self.specular, self.shininess];
        if all.iter().all(|c| c.is_finite() && *c >= 0.0) {
            Ok(())
        } else {
            Err(Error::Invalid(format!(
                "lighting {self:?} is invalid; expected finite coefficients >= 0"
            )))
        }
    }
}

/// What a frame looks at and how: everything but the volume and its classification.
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    pub camera: Camera,
    pub size: [u32; 2],
    /// Number of slice planes; `None` picks about two per voxel along the longest axis.
    pub slices: Option<u32>,
    pub one_pass: bool,
    pub lighting: Lighting,
    /// A perceptual style (two-level frames only), recorded after the levels.
    pub style: Option<Style>,
    /// Frame the volume's projected bounding box (replacing the camera's distance).
    pub fit: bool,
    /// Ray cast instead of slicing (same planes, same layers; see `render::raycast`).
    pub raycast: Option<RayOptions>,
}

/// Margin left around a fitted volume, as a fraction of the image's half-size.
pub const FIT_MARGIN: f32 = 0.05;

/// Parameters of one frame for the one-shot [`Renderer::render`].
#[derive(Clone, Debug)]
pub struct RenderParams {
    pub camera: Camera,
    pub size: [u32; 2],
    /// Number of slice planes; `None` picks about two per voxel along the longest axis.
    pub slices: Option<u32>,
    pub focus: Focus,
    pub one_pass: bool,
    pub transfer: TransferFunction,
    /// An occlusion transfer function table (256×256, `table[o * 256 + s]`), which replaces
    /// `transfer`; the volume textures must then hold an occlusion volume.
    pub occlusion_tf: Option<Vec<[f32; 4]>>,
}

/// The layers of a two-level frame, premultiplied RGBA rows top to bottom.
#[derive(Clone, Debug)]
pub struct Layers {
    pub focus_phong: Vec<[f32; 4]>,
    pub focus_diffuse: Vec<[f32; 4]>,
    /// Distance along the view direction of the nearest focus sample; +inf where there is none.
    pub focus_depth: Vec<f32>,
    pub context: Vec<[f32; 4]>,
}

/// A rendered frame on the host.
#[derive(Clone, Debug)]
pub struct Frame {
    pub size: [u32; 2],
    /// Premultiplied RGBA over transparent black (empty when not read back).
    pub composite: Vec<[f32; 4]>,
    /// The two-level layers (two-level frames read back only).
    pub layers: Option<Layers>,
    /// GPU ms of `focus`, `context`, `composite` or `one_pass`, and `readback` when read back.
    pub passes: Vec<PassTime>,
    pub slices: u32,
}

/// What recording a frame decided.
#[derive(Copy, Clone, Debug)]
pub struct Recorded {
    pub slices: u32,
}

/// The pipelines of the slice renderer.
pub struct Renderer {
    ctx: Arc<Context>,
    one_pass: GraphicsPipeline,
    focus: GraphicsPipeline,
    context: GraphicsPipeline,
    composite: GraphicsPipeline,
    linear: Sampler,
    nearest: Sampler,
    /// 1×1 stand-in bound when no occlusion or importance volume is used.
    dummy_3d: Image,
    /// Stand-in for the max |ΔD| buffer.
    dummy_max: crate::gpu::Buffer,
    /// The style passes, built on the first styled frame.
    post: std::sync::OnceLock<Post>,
    /// The ray caster, built on the first ray-cast frame.
    raycaster: crate::render::raycast::RayPipelines,
    /// Object-space line extraction and its segment buffer, built on the first frame of a style
    /// with lines.
    lines: std::sync::OnceLock<(
        crate::passes::lines::LineExtractor,
        crate::passes::lines::LineBuffer,
    )>,
    /// The geometry the last styled frame drew its lines with (for vector output).
    last_lines: std::sync::Mutex<Option<crate::passes::lines::RasterView>>,
}

/// Uniforms; intensity, gradient, TF, occlusion, OTF, ΔD; max |ΔD| (`shade.glsl`, which the ray
/// caster shares).
pub const SLICE_BINDINGS: [BindingKind; 8] = [
    BindingKind::UniformBuffer,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
    BindingKind::StorageBuffer,
];

/// Most slice planes a frame may draw.
pub const MAX_SLICES: u32 = 16384;

impl Renderer {
    /// Builds the four pipelines.
    pub fn new(ctx: &Arc<Context>) -> Result<Self> {
        let slice =
            |name, fragment, colors: &[vk::Format], blend: &[Blend], depth, constants: &[u32]| {
                GraphicsPipeline::new(
                    ctx,
                    &GraphicsDesc {
                        name,
                        vertex_shader: "render/slice.vert",
                        fragment_shader: fragment,
                        bindings: &SLICE_BINDINGS,
                        push_constant_bytes: 0,
                        vertex_stride: 12,
                        color_formats: colors,
                        blend,
                        depth,
                        fragment_constants: constants,
                    },
                )
            };
        let over = Blend::PremultipliedOver;
        let one_pass = slice(
            "one_pass",
            "render/slice.frag",
            &[COLOR],
            &[over],
            None,
            &[0],
        )?;
        let focus = slice(
            "focus",
            "render/slice_focus.frag",
            &[COLOR, COLOR, LINEAR_DEPTH],
            &[over, over, Blend::Replace],
            Some(DepthState {
                format: DEPTH,
                compare: vk::CompareOp::LESS_OR_EQUAL,
                write: true,
            }),
            &[],
        )?;
        let context = slice(
            "context",
            "render/slice.frag",
            &[COLOR],
            &[over],
            Some(DepthState {
                format: DEPTH,
                compare: vk::CompareOp::LESS,
                write: false,
            }),
            &[1],
        )?;
        let composite = GraphicsPipeline::new(
            ctx,
            &GraphicsDesc {
                name: "composite",
                vertex_shader: "render/fullscreen.vert",
                fragment_shader: "render/composite.frag",
                bindings: &[BindingKind::SampledImage, BindingKind::SampledImage],
                push_constant_bytes: 0,
                vertex_stride: 0,
                color_formats: &[COLOR],
                blend: &[Blend::Replace],
                depth: None,
                fragment_constants: &[],
            },
        )?;
        let dummy_3d = Image::new(
            ctx,
            "dummy occlusion",
            &ImageDesc::new_3d(vk::Format::R32_SFLOAT, [1, 1, 1]),
        )?;
        crate::gpu::transfer::upload(ctx, &dummy_3d, &[0u8; 4], Access::FragmentSampled)?;
        Ok(Renderer {
            ctx: ctx.clone(),
            one_pass,
            focus,
            context,
            composite,
            linear: Sampler::new(ctx, true)?,
            nearest: Sampler::new(ctx, false)?,
            dummy_3d,
            dummy_max: crate::gpu::Buffer::from_bytes(
                ctx,
                "dummy importance max",
                vk::BufferUsageFlags::STORAGE_BUFFER,
                &[0u8; 4],
            )?,
            post: std::sync::OnceLock::new(),
            raycaster: Default::default(),
            lines: std::sync::OnceLock::new(),
            last_lines: std::sync::Mutex::new(None),
        })
    }

    /// The context the pipelines were built on.
    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }

    /// Records one frame of `vol`, classified by `classify` (transfer functions, focus,
    /// modulation), as seen by `view`, into `frame`; the layers land in `targets` (resized if
    /// needed). Passes: `focus`, `context`, `composite`, or `one_pass`.
    pub fn record(
        &self,
        frame: &mut gpu::Frame,
        vol: &VolumeTextures,
        classify: &mut GpuClassification,
        view: &View,
        targets: &mut FrameTargets,
    ) -> Result<Recorded> {
        let focus = classify.focus;
        let ctx = &self.ctx;
        let [w, h] = view.size;
        let max2d = ctx.info.max_image_dimension_2d;
        if w == 0 || h == 0 || w > max2d || h > max2d {
            return Err(Error::Invalid(format!(
                "image size {w}x{h} is invalid; expected 1..={max2d} pixels per side"
            )));
        }
        let uses_occlusion = classify.uses_occlusion();
        let occlusion = match (uses_occlusion, &vol.occlusion) {
            (false, _) => &self.dummy_3d,
            (true, Some(o)) => o,
            (true, None) => {
                return Err(Error::Invalid("an occlusion transfer function needs an occlusion volume attached to the volume textures".into()))
            }
        };
        view.lighting.validate()?;
        if let Some(style) = &view.style {
            if view.one_pass {
                return Err(Error::Invalid(format!(
                    "style {} ({}) works on the two levels; drop --one-pass",
                    style.def.number, style.def.name
                )));
            }
            if style.def.needs_focus() && focus == Focus::None {
                return Err(Error::Invalid(format!(
                    "style {} ({}) works on the focus layer; give a focus with --iso V or --focus LO:HI",
                    style.def.number, style.def.name
                )));
            }
            if style.def.lines.is_some() && self.lines.get().is_none() {
                let extractor = crate::passes::lines::LineExtractor::new(ctx)?;
                let buffer = crate::passes::lines::LineBuffer::new(
                    ctx,
                    crate::passes::lines::DEFAULT_CAPACITY,
                )?;
                let _ = self.lines.set((extractor, buffer));
            }
            if self.post.get().is_none() {
                let _ = self.post.set(Post::new(ctx)?);
            }
        }
        let modulation = classify.modulation.clone();
        modulation.validate()?;
        let importance = match (modulation.is_active(), &vol.importance) {
            (false, _) => None,
            (true, Some(i)) => Some(i),
            (true, None) => return Err(Error::Invalid(
                "importance modulation needs the importance map attached to the volume textures"
                    .into(),
            )),
        };
        // The box in world units: physical size scaled so that its longest edge is 1.
        let physical: [f64; 3] = std::array::from_fn(|a| vol.dims[a] as f64 * vol.spacing[a]);
        let longest = physical.iter().copied().fold(0.0, f64::max);
        let half = Vec3::from_array(physical.map(|p| (0.5 * p / longest) as f32));
        let radius = half.length();
        let voxel = vol.spacing.iter().copied().fold(f64::INFINITY, f64::min) / longest;
        let n_slices = view
            .slices
            .unwrap_or_else(|| 2 * *vol.dims.iter().max().unwrap_or(&1) as u32)
            .max(1);
        if n_slices > MAX_SLICES {
            return Err(Error::Invalid(format!(
                "{n_slices} slices are too many; expected at most {MAX_SLICES}"
            )));
        }
        // The camera lives in world space: LPS for a volume whose orientation is known, where the
        // box is turned by its direction matrix R about its centre; else the box's own axes. So
        // the box-frame quantities are R^T applied to the world ones, and box → clip is VP · R.
        let rot = match vol.geometry.is_oriented() {
            true => {
                glam::Mat3::from_cols_array_2d(&vol.geometry.direction.map(|r| r.map(|v| v as f32)))
                    .transpose()
            }
            false => glam::Mat3::IDENTITY,
        };
        let aspect = w as f32 / h as f32;
        let cam = &frame_camera(vol, view);
        let view_dir = rot.transpose() * cam.view_dir(radius);
        // Every pass draws the same planes, cut only by the bricks that can contribute to it, so
        // each fragment it draws is one the whole-box geometry would draw and skipped fragments
        // would all have been discarded. One pass and context: bricks whose intensities meet a
        // non-zero opacity (all bricks with an occlusion TF); the context also drops bricks that
        // are focus throughout. Focus: bricks that can hold focus samples.
        let table = classify.transfer_table();
        let focus_n = focus.normalised(vol.range);
        let visible: Vec<bool> = vol
            .bricks
            .range
            .iter()
            .map(|r| uses_occlusion || any_opacity(table, r))
            .collect();
        let (bricks, dims) = (&vol.bricks, vol.dims);
        let boxes = |keep: &dyn Fn(usize) -> bool| brick_boxes(bricks, dims, half, keep);
        let context_proxy = || {
            if view.one_pass {
                view_aligned_slices_in(half, view_dir, n_slices, &boxes(&|b| visible[b]))
            } else {
                view_aligned_slices_in(
                    half,
                    view_dir,
                    n_slices,
                    &boxes(&|b| visible[b] && !all_focus(&bricks.range[b], focus_n)),
                )
            }
        };
        let focus_proxy = || {
            (!view.one_pass).then(|| {
                view_aligned_slices_in(
                    half,
                    view_dir,
                    n_slices,
                    &boxes(&|b| may_focus(&bricks.range[b], focus_n)),
                )
            })
        };
        let raycast = view.raycast;
        if let Some(r) = &raycast {
            r.validate()?;
        }
        let (near, far) = depth_span(half, view_dir.normalize());
        let (proxy, focus_proxy) = match raycast {
            Some(_) => (
                ProxySlices {
                    spacing: (far - near) / n_slices as f32,
                    slices: n_slices,
                    ..ProxySlices::default()
                },
                None,
            ),
            None => rayon::join(context_proxy, focus_proxy),
        };
        let eye = rot.transpose() * cam.eye(radius);
        let light = -view_dir; // a headlight
        let l = &view.lighting;
        let mut uniforms = SliceUniforms {
            view_proj: (cam.view_proj(aspect, radius) * glam::Mat4::from_mat3(rot))
                .to_cols_array_2d(),
            half_extent: [half.x, half.y, half.z, 0.0],
            eye: [eye.x, eye.y, eye.z, 0.0],
            view_dir: [
                view_dir.x,
                view_dir.y,
                view_dir.z,
                if cam.ortho { 1.0 } else { 0.0 },
            ],
            light: [light.x, light.y, light.z, l.shininess],
            material: [
                l.ambient,
                l.diffuse,
                l.specular,
                (proxy.spacing as f64 / voxel) as f32,
            ],
            focus: [
                focus_n[0],
                focus_n[1],
                focus_n[2],
                if uses_occlusion { 1.0 } else { 0.0 },
            ],
            ..bytemuck::Zeroable::zeroed()
        };
        uniforms.set_modulation(&modulation, vol.dims);
        let ubo = frame.staging.push_pod(&uniforms)?;
        let vertices = frame
            .staging
            .push(bytemuck::cast_slice(&proxy.vertices), 16)?;
        let vertex_count = proxy.vertices.len() as u32;
        let focus_vertices = match &focus_proxy {
            Some(fp) => Some((
                frame.staging.push(bytemuck::cast_slice(&fp.vertices), 16)?,
                fp.vertices.len() as u32,
            )),
            None => None,
        };
        // The ray caster's tables: opacity bounds per TF texel pair, then per-brick flags for
        // empty-space skipping (`raycast.comp`, `RayTables`).
        let brick_flags = match raycast {
            Some(_) => {
                let flags: Vec<u32> = crate::render::raycast::opacity_bounds(table)
                    .into_iter()
                    .map(f32::to_bits)
                    .chain((0..bricks.range.len()).map(|b| {
                        let v = if visible[b] { BRICK_VISIBLE } else { 0 };
                        let f = if may_focus(&bricks.range[b], focus_n) {
                            BRICK_FOCUS
                        } else {
                            0
                        };
                        v | f
                    }))
                    .collect();
                Some(frame.staging.push(bytemuck::cast_slice(&flags), 256)?)
            }
            None => None,
        };
        let sampled = match raycast {
            Some(_) => Access::ComputeSampled,
            None => Access::FragmentSampled,
        };
        classify.record(frame, sampled)?;
        let t = targets.ensure([w, h], !view.one_pass, view.style.is_some())?;
        let cmd = frame.cmd;
        let profiler = &mut *frame.profiler;
        vol.intensity.transition(cmd, sampled);
        vol.gradient.transition(cmd, sampled);
        occlusion.transition(cmd, sampled);
        let (delta_d, delta_max) = match importance {
            Some(i) => (&i.delta_d, &i.max_abs),
            None => (&self.dummy_3d, &self.dummy_max),
        };
        if let Some(i) = importance {
            i.delta_d.transition(cmd, sampled);
            // The reduction's atomics must be visible to the shaders' reads.
            let read = match raycast {
                Some(_) => Access::ComputeRead,
                None => Access::FragmentStorageRead,
            };
            crate::gpu::commands::memory_transition(ctx, cmd, Access::ComputeReadWrite, read);
        }
        let binds = [
            Bind::UniformSlice(ubo),
            Bind::Sampled(&vol.intensity, &self.linear),
            Bind::Sampled(&vol.gradient, &self.linear),
            Bind::Sampled(classify.transfer_image(), &self.linear),
            Bind::Sampled(occlusion, &self.linear),
            Bind::Sampled(classify.occlusion_image(), &self.linear),
            Bind::Sampled(delta_d, &self.linear),
            Bind::StorageBuffer(delta_max),
        ];
        let draw_with =
            |pipeline: &GraphicsPipeline, buffer: BufferSlice, count: u32| -> Result<()> {
                pipeline.bind(cmd, &binds, &(), [w, h])?;
                if count > 0 {
                    unsafe {
                        ctx.device
                            .cmd_bind_vertex_buffers(cmd, 0, &[buffer.raw], &[buffer.offset]);
                        ctx.device.cmd_draw(cmd, count, 1, 0, 0);
                    }
                }
                Ok(())
            };
        let clear = Load::Clear([0.0; 4]);
        let composite = &t.composite;
        match (raycast, &t.layers, view.one_pass) {
            (Some(r), layers, one_pass) => {
                let layers = layers.as_ref().filter(|_| !one_pass);
                let out = |pick: fn(&crate::render::targets::TargetLayers) -> &Image| {
                    layers.map_or(composite, pick)
                };
                let images = [
                    out(|l| &l.focus_phong),
                    out(|l| &l.focus_diffuse),
                    out(|l| &l.focus_depth),
                    out(|l| &l.context),
                    composite,
                ];
                for image in images {
                    image.transition(cmd, Access::ComputeWrite);
                }
                let mut ray_binds: Vec<Bind> = binds.into_iter().collect();
                ray_binds.extend(images.map(Bind::StorageImage));
                ray_binds.push(Bind::StorageSlice(brick_flags.expect("pushed above")));
                let inv = (cam.view_proj(aspect, radius) * glam::Mat4::from_mat3(rot)).inverse();
                let c = bricks.counts.map(|n| n as i32);
                let push = RayPush {
                    inv_view_proj: inv.to_cols_array_2d(),
                    planes: [far, proxy.spacing, n_slices as f32, r.ert],
                    bricks: [c[0], c[1], c[2], crate::passes::normals::BRICK as i32],
                    flags: [
                        (!one_pass) as i32,
                        r.skip_empty as i32,
                        r.jitter.map_or(0, |j| j.max(1) as i32),
                        r.refine_iso as i32
                            | ((r.sampling == crate::render::raycast::Sampling::WorldSteps) as i32)
                                << 1,
                    ],
                };
                let variant = crate::render::raycast::Variant::of(&r, !one_pass, &uniforms);
                let pipeline = self.raycaster.get(ctx, variant)?;
                let groups =
                    crate::gpu::pipeline::group_count([w, h, 1], crate::render::raycast::LOCAL);
                profiler.begin(cmd, "raycast");
                pipeline.dispatch(cmd, &ray_binds, &push, groups)?;
                profiler.end(cmd);
            }
            (None, Some(layers), false) => {
                let (phong, diffuse, lin_depth, context, depth) = (
                    &layers.focus_phong,
                    &layers.focus_diffuse,
                    &layers.focus_depth,
                    &layers.context,
                    &layers.depth,
                );
                profiler.begin(cmd, "focus");
                begin_rendering(
                    ctx,
                    cmd,
                    &[
                        (phong, clear),
                        (diffuse, clear),
                        (lin_depth, Load::Clear([f32::INFINITY; 4])),
                    ],
                    Some((depth, Load::Clear([1.0; 4]))),
                );
                let (fv, fcount) = focus_vertices.unwrap_or((vertices, 0));
                draw_with(&self.focus, fv, fcount)?;
                end_rendering(ctx, cmd);
                profiler.end(cmd);
                profiler.begin(cmd, "context");
                begin_rendering(ctx, cmd, &[(context, clear)], Some((depth, Load::Keep)));
                draw_with(&self.context, vertices, vertex_count)?;
                end_rendering(ctx, cmd);
                profiler.end(cmd);
                profiler.begin(cmd, "composite");
                phong.transition(cmd, Access::FragmentSampled);
                context.transition(cmd, Access::FragmentSampled);
                begin_rendering(ctx, cmd, &[(composite, clear)], None);
                self.composite.bind(
                    cmd,
                    &[
                        Bind::Sampled(phong, &self.nearest),
                        Bind::Sampled(context, &self.nearest),
                    ],
                    &(),
                    [w, h],
                )?;
                unsafe { ctx.device.cmd_draw(cmd, 3, 1, 0, 0) };
                end_rendering(ctx, cmd);
                profiler.end(cmd);
            }
            _ => {
                profiler.begin(cmd, "one_pass");
                begin_rendering(ctx, cmd, &[(composite, clear)], None);
                draw_with(&self.one_pass, vertices, vertex_count)?;
                end_rendering(ctx, cmd);
                profiler.end(cmd);
            }
        }
        if let (Some(style), Some(post), false) = (&view.style, &t.post, view.one_pass) {
            let pipelines = self.post.get().expect("built above");
            // Lines of a smoothed volume: made once per volume and radius, kept with the volume
            // (the slot stays locked while this frame records its lines).
            let mut slot = vol.smoothed.lock().unwrap_or_else(|p| p.into_inner());
            let radius = style.params.line_smooth;
            if let (Some(_), Some((extractor, _)), true) =
                (style.def.lines, self.lines.get(), radius > 0)
            {
                if slot.as_ref().is_none_or(|(kept, _)| *kept != radius) {
                    let image = extractor.record_smoothing(
                        cmd,
                        profiler,
                        &vol.intensity,
                        vol.dims,
                        radius,
                    )?;
                    *slot = Some((radius, image));
                }
            }
            let smoothed = slot
                .as_ref()
                .filter(|(kept, _)| radius > 0 && *kept == radius)
                .map(|(_, image)| image);
            let lines = match (style.def.lines, self.lines.get()) {
                (Some(kind), Some((extractor, buffer))) => {
                    let p = &style.params;
                    let spacing = vol.spacing.map(|s| s as f32);
                    let longest = longest as f32;
                    let scale = spacing.map(|s| s / longest);
                    let offset: [f32; 3] = std::array::from_fn(|a| {
                        (0.5 - 0.5 * vol.dims[a] as f32) * spacing[a] / longest
                    });
                    // The eye in the extraction's frame (index × spacing): box · longest plus the
                    // box centre's position there.
                    let eye_line = if cam.ortho {
                        crate::volume::lines::Eye::Direction((-view_dir).to_array())
                    } else {
                        crate::volume::lines::Eye::Point(std::array::from_fn(|a| {
                            eye[a] * longest + (0.5 * vol.dims[a] as f32 - 0.5) * spacing[a]
                        }))
                    };
                    let min_spacing = spacing.iter().copied().fold(f32::INFINITY, f32::min);
                    let raster = crate::passes::lines::RasterView {
                        view_proj: uniforms.view_proj,
                        index_scale: scale,
                        index_offset: offset,
                        eye: eye.to_array(),
                        view_dir: view_dir.to_array(),
                        bias: p.line_depth_bias * min_spacing / longest,
                        value: 1.0,
                        floor: 0.0,
                    };
                    if let Ok(mut last) = self.last_lines.lock() {
                        *last = Some(raster);
                    }
                    Some(crate::render::post::LinesDraw {
                        extractor,
                        buffer,
                        volume: smoothed.unwrap_or(&vol.intensity),
                        dims: vol.dims,
                        spacing,
                        eye: eye_line,
                        params: crate::volume::lines::LineParams {
                            // The focus surface: the isovalue, or a range's lower bound.
                            iso: focus_n[0],
                            silhouettes: p.line_both
                                || kind == crate::render::style::LineKind::Silhouettes,
                            suggestive: p.line_both
                                || kind == crate::render::style::LineKind::SuggestiveContours,
                            min_angle_deg: p.line_angle,
                            derivative_threshold: p.line_derivative_threshold,
                            stride: p.line_stride,
                            smooth: p.line_smooth,
                            seeded: p.line_seeded,
                        },
                        view: raster,
                    })
                }
                _ => None,
            };
            pipelines.record(cmd, profiler, style, t, post, lines)?;
        }
        Ok(Recorded {
            slices: proxy.slices,
        })
    }

    /// The object-space lines of the last styled frame (read after it completes), if a style with
    /// lines has been recorded.
    pub fn line_buffer(&self) -> Option<&crate::passes::lines::LineBuffer> {
        self.lines.get().map(|(_, b)| b)
    }

    /// The geometry the last styled frame drew its lines with.
    pub fn last_lines_view(&self) -> Option<crate::passes::lines::RasterView> {
        self.last_lines.lock().ok().and_then(|l| *l)
    }

    /// Renders one frame in one submission (the tools' path): the persistent-state types, used
    /// once. With `readback`, the composite (and the layers of a two-level frame) come back to
    /// the host.
    pub fn render(
        &self,
        vol: &VolumeTextures,
        params: &RenderParams,
        readback: bool,
    ) -> Result<Frame> {
        let mut classify = GpuClassification::new(&self.ctx, &params.transfer, params.focus)?;
        classify.set_occlusion_table(params.occlusion_tf.clone())?;
        let view = View {
            camera: params.camera,
            size: params.size,
            slices: params.slices,
            one_pass: params.one_pass,
            lighting: Lighting::default(),
            style: None,
            fit: false,
            raycast: None,
        };
        self.render_frame(vol, &mut classify, &view, readback)
    }

    /// [`Renderer::render`] for a volume and classification that are already on the GPU.
    pub fn render_frame(
        &self,
        vol: &VolumeTextures,
        classify: &mut GpuClassification,
        view: &View,
        readback: bool,
    ) -> Result<Frame> {
        let ctx = &self.ctx;
        let mut targets = FrameTargets::new(ctx);
        let mut frames = Frames::new(ctx, &FramesDesc::one_shot("render frame", 32))?;
        let mut host = None;
        let (recorded, _) = frames.frame(|f| {
            let r = self.record(f, vol, classify, view, &mut targets)?;
            if readback {
                let rb = TargetsReadback::new(ctx, &targets)?;
                f.profiler
                    .pass(f.cmd, "readback", |cmd| rb.record(cmd, &targets));
                host = Some(rb);
            }
            Ok(r)
        })?;
        let passes = frames.finish()?;
        let (composite, layers) = match &host {
            Some(rb) => rb.read()?,
            None => (Vec::new(), None),
        };
        Ok(Frame {
            size: view.size,
            composite,
            layers,
            passes,
            slices: recorded.slices,
        })
    }
}

/// The volume's box in world units (physical size scaled so that its longest edge is 1): its half
/// extents and the rotation from the box's axes to world space (LPS for an oriented volume).
fn world_box(vol: &VolumeTextures) -> (Vec3, glam::Mat3) {
    let physical: [f64; 3] = std::array::from_fn(|a| vol.dims[a] as f64 * vol.spacing[a]);
    let longest = physical.iter().copied().fold(0.0, f64::max);
    let half = Vec3::from_array(physical.map(|p| (0.5 * p / longest) as f32));
    let rot = match vol.geometry.is_oriented() {
        true => {
            glam::Mat3::from_cols_array_2d(&vol.geometry.direction.map(|r| r.map(|v| v as f32)))
                .transpose()
        }
        false => glam::Mat3::IDENTITY,
    };
    (half, rot)
}

/// The camera a frame of `vol` seen by `view` uses: `view.camera`, with its distance fitted to the
/// volume's projected bounding box when `view.fit` (the viewer turns a fitted distance into an
/// explicit one before zooming).
pub fn frame_camera(vol: &VolumeTextures, view: &View) -> Camera {
    let mut cam = view.camera;
    if view.fit {
        let (half, rot) = world_box(vol);
        let corners: Vec<Vec3> = (0..8)
            .map(|i| {
                let sign = |k: u32| if (i >> k) & 1 == 1 { 1.0 } else { -1.0 };
                rot * Vec3::new(sign(0) * half.x, sign(1) * half.y, sign(2) * half.z)
            })
            .collect();
        let aspect = view.size[0].max(1) as f32 / view.size[1].max(1) as f32;
        cam.distance = cam.fit_distance(&corners, half.length(), aspect, FIT_MARGIN);
    }
    cam
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

/// Whether the 1D transfer function gives any opacity to intensities in range `r`: the table
/// entries that linear filtering blends for samples in the range.
fn any_opacity(table: &[[f32; 4]], r: &[u16; 2]) -> bool {
    let (mn, mx) = widened(r);
    let n = table.len() as f32;
    let first = ((mn * n - 0.5).floor().max(0.0)) as usize;
    let last = ((mx * n + 0.5).ceil() as usize).min(table.len() - 1);
    table[first.min(last)..=last].iter().any(|c| c[3] > 0.0)
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

impl Frame {
    /// Writes the frame's layers as named float channels to one OpenEXR file: focus.phong,
    /// focus.diffuse (RGBA), focus.depth (Z) and context for two-level frames, and composite.
    pub fn write_exr(&self, path: &std::path::Path) -> Result<()> {
        use crate::output::{write_exr_layers, ExrChannels, ExrLayer};
        let mut layers = Vec::new();
        if let Some(l) = &self.layers {
            layers.push(ExrLayer {
                name: "focus.phong",
                channels: ExrChannels::Rgba(&l.focus_phong),
            });
            layers.push(ExrLayer {
                name: "focus.diffuse",
                channels: ExrChannels::Rgba(&l.focus_diffuse),
            });
            layers.push(ExrLayer {
                name: "focus.depth",
                channels: ExrChannels::Depth(&l.focus_depth),
            });
            layers.push(ExrLayer {
                name: "context",
                channels: ExrChannels::Rgba(&l.context),
            });
        }
        layers.push(ExrLayer {
            name: "composite",
            channels: ExrChannels::Rgba(&self.composite),
        });
        write_exr_layers(path, self.size[0], self.size[1], &layers)
    }
}

/// Premultiplied RGBA over an opaque `background`, as 8-bit RGB for PNG.
pub fn to_rgb8(pixels: &[[f32; 4]], background: [f32; 3]) -> Vec<u8> {
    pixels
        .iter()
        .flat_map(|p| {
            let a = p[3].clamp(0.0, 1.0);
            [0, 1, 2]
                .map(|c| ((p[c] + (1.0 - a) * background[c]).clamp(0.0, 1.0) * 255.0).round() as u8)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::interface::assert_glsl_layout;

    #[test]
    fn uniforms_match_glsl() {
        assert_glsl_layout!(
            SliceUniforms,
            "render.glsl",
            "SliceUniforms",
            [
                view_proj,
                half_extent,
                eye,
                view_dir,
                light,
                material,
                focus,
                mod_flags,
                mod_color,
                mod_opacity,
                mod_stipple,
                mod_seed,
                stipple_white,
                stipple_black,
                volume_dims
            ]
        );
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
    }
}
