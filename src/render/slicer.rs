//! The 3D-texture slice renderer with two levels (SPEC TL2, TL3; two-level paper §3, §3.1).
//!
//! View-aligned proxy polygons are drawn back to front with premultiplied "over" blending. Each
//! fragment samples the normalised intensity, looks colour and opacity up in the 1D transfer
//! function (opacity corrected for the slice spacing), and shades with the Sobel gradient.
//!
//! Two levels: pass `focus` renders only the focus samples into three targets at once (Phong with
//! specular, diffuse only, linear depth) plus a D32 depth buffer holding the nearest focus sample.
//! Pass `context` renders every other sample, depth-tested against that buffer, so context hidden
//! behind the focus is dropped. Pass `composite` lays the context over the focus. With an opaque
//! focus this equals the classic single pass (`one_pass`), which is the paper's claim and a test.

use crate::error::{Error, Result};
use crate::gpu::graphics::{
    begin_rendering, end_rendering, Blend, DepthState, GraphicsDesc, GraphicsPipeline, Load,
};
use crate::gpu::profiler::PassTime;
use crate::gpu::transfer::{record_readback, record_upload, staging_buffer};
use crate::gpu::{
    submit_once, Access, Bind, BindingKind, Buffer, Context, Image, ImageDesc, Profiler, Sampler,
};
use crate::passes::normals::VolumeTextures;
use crate::render::camera::Camera;
use crate::render::proxy::view_aligned_slices_in;
use crate::render::transfer::TransferFunction;
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
}

/// What the first level renders.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum Focus {
    /// No focus: everything is context.
    None,
    /// Samples whose data value lies in [lo, hi] (data units), with the transfer function's opacity.
    Range { lo: f64, hi: f64 },
    /// Samples at or above the data value: an opaque isosurface.
    Iso(f64),
}

impl Focus {
    /// Parses `--focus LO:HI` or `--iso V` (data units).
    pub fn parse(range: Option<&str>, iso: Option<f64>) -> Result<Focus> {
        match (range, iso) {
            (Some(_), Some(_)) => Err(Error::Invalid(
                "give either --focus LO:HI or --iso V, not both".into(),
            )),
            (None, Some(v)) if v.is_finite() => Ok(Focus::Iso(v)),
            (None, Some(_)) => Err(Error::Invalid("--iso needs a finite value".into())),
            (Some(r), None) => {
                let parsed = r.split_once(':').and_then(|(a, b)| {
                    Some((a.trim().parse::<f64>().ok()?, b.trim().parse::<f64>().ok()?))
                });
                match parsed {
                    Some((lo, hi)) if lo <= hi && lo.is_finite() && hi.is_finite() => {
                        Ok(Focus::Range { lo, hi })
                    }
                    _ => Err(Error::Invalid(format!(
                        "--focus '{r}' is not an interval LO:HI of data values with LO <= HI"
                    ))),
                }
            }
            (None, None) => Ok(Focus::None),
        }
    }

    /// (lo, hi, mode) on the normalised range of `data_range`.
    fn normalised(&self, data_range: [f64; 2]) -> [f32; 3] {
        let n = |v: f64| {
            if data_range[1] > data_range[0] {
                ((v - data_range[0]) / (data_range[1] - data_range[0])) as f32
            } else {
                0.0
            }
        };
        match *self {
            Focus::None => [0.0, 0.0, 0.0],
            Focus::Range { lo, hi } => [n(lo), n(hi), 1.0],
            Focus::Iso(v) => [n(v), f32::INFINITY, 2.0],
        }
    }
}

/// Parameters of one frame.
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

/// A rendered frame.
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

const COLOR: vk::Format = vk::Format::R32G32B32A32_SFLOAT;
const LINEAR_DEPTH: vk::Format = vk::Format::R32_SFLOAT;
const DEPTH: vk::Format = vk::Format::D32_SFLOAT;

/// The pipelines of the slice renderer.
pub struct Renderer {
    ctx: Arc<Context>,
    one_pass: GraphicsPipeline,
    focus: GraphicsPipeline,
    context: GraphicsPipeline,
    composite: GraphicsPipeline,
    linear: Sampler,
    nearest: Sampler,
    /// 1×1 stand-ins bound when no occlusion transfer function is used.
    dummy_3d: Image,
    dummy_2d: Image,
}

const SLICE_BINDINGS: [BindingKind; 6] = [
    BindingKind::UniformBuffer,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
    BindingKind::SampledImage,
];

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
        let dummy_2d = Image::new(ctx, "dummy occlusion tf", &ImageDesc::new_2d(COLOR, [1, 1]))?;
        crate::gpu::transfer::upload(ctx, &dummy_3d, &[0u8; 4], Access::FragmentSampled)?;
        crate::gpu::transfer::upload(ctx, &dummy_2d, &[0u8; 16], Access::FragmentSampled)?;
        Ok(Renderer {
            ctx: ctx.clone(),
            one_pass,
            focus,
            context,
            composite,
            linear: Sampler::new(ctx, true)?,
            nearest: Sampler::new(ctx, false)?,
            dummy_3d,
            dummy_2d,
        })
    }

    /// Renders one frame of `vol`. With `readback`, the composite (and the layers of a two-level
    /// frame) come back to the host.
    pub fn render(
        &self,
        vol: &VolumeTextures,
        params: &RenderParams,
        readback: bool,
    ) -> Result<Frame> {
        let ctx = &self.ctx;
        let [w, h] = params.size;
        let max2d = ctx.info.max_image_dimension_2d;
        if w == 0 || h == 0 || w > max2d || h > max2d {
            return Err(Error::Invalid(format!(
                "image size {w}x{h} is invalid; expected 1..={max2d} pixels per side"
            )));
        }
        // The box in world units: physical size scaled so that its longest edge is 1.
        let physical: [f64; 3] = std::array::from_fn(|a| vol.dims[a] as f64 * vol.spacing[a]);
        let longest = physical.iter().copied().fold(0.0, f64::max);
        let half = Vec3::from_array(physical.map(|p| (0.5 * p / longest) as f32));
        let radius = half.length();
        let voxel = vol.spacing.iter().copied().fold(f64::INFINITY, f64::min) / longest;
        let n_slices = params
            .slices
            .unwrap_or_else(|| 2 * *vol.dims.iter().max().unwrap_or(&1) as u32)
            .max(1);
        if n_slices > 16384 {
            return Err(Error::Invalid(format!(
                "{n_slices} slices are too many; expected at most 16384"
            )));
        }
        let cam = &params.camera;
        let view_dir = cam.view_dir(radius);
        // Every pass draws the same planes, cut only by the bricks that can contribute to it, so
        // each fragment it draws is one the whole-box geometry would draw and skipped fragments
        // would all have been discarded. One pass and context: bricks whose intensities meet a
        // non-zero opacity (all bricks with an occlusion TF); the context also drops bricks that
        // are focus throughout. Focus: bricks that can hold focus samples.
        let table: Vec<[f32; 4]> = params.transfer.table(256);
        let focus_n = params.focus.normalised(vol.range);
        let visible: Vec<bool> = vol
            .bricks
            .range
            .iter()
            .map(|r| params.occlusion_tf.is_some() || any_opacity(&table, r))
            .collect();
        let boxes = |keep: &dyn Fn(usize) -> bool| brick_boxes(vol, half, keep);
        let proxy = if params.one_pass {
            view_aligned_slices_in(half, view_dir, n_slices, &boxes(&|b| visible[b]))
        } else {
            view_aligned_slices_in(
                half,
                view_dir,
                n_slices,
                &boxes(&|b| visible[b] && !all_focus(&vol.bricks.range[b], focus_n)),
            )
        };
        let focus_proxy = (!params.one_pass).then(|| {
            view_aligned_slices_in(
                half,
                view_dir,
                n_slices,
                &boxes(&|b| may_focus(&vol.bricks.range[b], focus_n)),
            )
        });
        let eye = cam.eye(radius);
        let light = -view_dir; // a headlight
        let uniforms = SliceUniforms {
            view_proj: cam
                .view_proj(w as f32 / h as f32, radius)
                .to_cols_array_2d(),
            half_extent: [half.x, half.y, half.z, 0.0],
            eye: [eye.x, eye.y, eye.z, 0.0],
            view_dir: [
                view_dir.x,
                view_dir.y,
                view_dir.z,
                if cam.ortho { 1.0 } else { 0.0 },
            ],
            light: [light.x, light.y, light.z, 24.0],
            material: [0.25, 0.75, 0.35, (proxy.spacing as f64 / voxel) as f32],
            focus: {
                let f = params.focus.normalised(vol.range);
                [
                    f[0],
                    f[1],
                    f[2],
                    if params.occlusion_tf.is_some() {
                        1.0
                    } else {
                        0.0
                    },
                ]
            },
        };
        // The occlusion transfer function: a 256×256 table and the occlusion volume to index it.
        let otf = match (&params.occlusion_tf, &vol.occlusion) {
            (None, _) => None,
            (Some(_), None) => {
                return Err(Error::Invalid("an occlusion transfer function needs an occlusion volume attached to the volume textures".into()))
            }
            (Some(table), Some(occlusion)) => {
                if table.len() != 256 * 256 {
                    return Err(Error::Invalid("an occlusion transfer-function table needs 256×256 entries".into()));
                }
                let image = Image::new(ctx, "occlusion transfer function", &ImageDesc::new_2d(COLOR, [256, 256]))?;
                crate::gpu::transfer::upload(ctx, &image, bytemuck::cast_slice(table), Access::FragmentSampled)?;
                Some((image, occlusion))
            }
        };

        let ubo = Buffer::from_bytes(
            ctx,
            "slice uniforms",
            vk::BufferUsageFlags::UNIFORM_BUFFER,
            bytemuck::bytes_of(&uniforms),
        )?;
        let vertices = Buffer::from_bytes(
            ctx,
            "proxy slices",
            vk::BufferUsageFlags::VERTEX_BUFFER,
            bytemuck::cast_slice(&proxy.vertices),
        )?;
        let focus_vertices = match &focus_proxy {
            Some(fp) => Some((
                Buffer::from_bytes(
                    ctx,
                    "focus proxy slices",
                    vk::BufferUsageFlags::VERTEX_BUFFER,
                    bytemuck::cast_slice(&fp.vertices),
                )?,
                fp.vertices.len() as u32,
            )),
            None => None,
        };
        let tf = Image::new(
            ctx,
            "transfer function",
            &ImageDesc::new_2d(COLOR, [256, 1]),
        )?;
        let mut tf_staging = staging_buffer(ctx, "transfer function staging", table.len() * 16)?;
        tf_staging.write(bytemuck::cast_slice(&table))?;

        let target = |name: &str, format| {
            let usage = if format == DEPTH {
                vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT
            } else {
                vk::ImageUsageFlags::COLOR_ATTACHMENT
                    | vk::ImageUsageFlags::SAMPLED
                    | vk::ImageUsageFlags::TRANSFER_SRC
            };
            Image::new(ctx, name, &ImageDesc::new_2d(format, [w, h]).usage(usage))
        };
        let composite = target("composite", COLOR)?;
        let two_level = !params.one_pass;
        let layers = if two_level {
            Some([
                target("focus phong", COLOR)?,
                target("focus diffuse", COLOR)?,
                target("focus linear depth", LINEAR_DEPTH)?,
                target("context", COLOR)?,
            ])
        } else {
            None
        };
        let depth = if two_level {
            Some(target("focus depth", DEPTH)?)
        } else {
            None
        };
        let readbacks: Vec<(&Image, Buffer)> = if readback {
            let mut images = vec![&composite];
            if let Some(l) = &layers {
                images.extend(l.iter());
            }
            images
                .into_iter()
                .map(|i| {
                    Ok((
                        i,
                        staging_buffer(ctx, &format!("{} readback", i.name), i.byte_size())?,
                    ))
                })
                .collect::<Result<_>>()?
        } else {
            Vec::new()
        };

        let vertex_count = proxy.vertices.len() as u32;
        let mut profiler = Profiler::new(ctx, 6)?;
        submit_once(ctx, "render frame", |cmd| {
            profiler.reset(cmd);
            record_upload(ctx, cmd, &tf_staging, &tf, Access::FragmentSampled);
            vol.intensity.transition(cmd, Access::FragmentSampled);
            vol.gradient.transition(cmd, Access::FragmentSampled);
            let binds = [
                Bind::Uniform(&ubo),
                Bind::Sampled(&vol.intensity, &self.linear),
                Bind::Sampled(&vol.gradient, &self.linear),
                Bind::Sampled(&tf, &self.linear),
                Bind::Sampled(otf.as_ref().map_or(&self.dummy_3d, |o| o.1), &self.linear),
                Bind::Sampled(otf.as_ref().map_or(&self.dummy_2d, |o| &o.0), &self.linear),
            ];
            let draw_with =
                |pipeline: &GraphicsPipeline, buffer: &Buffer, count: u32| -> Result<()> {
                    pipeline.bind(cmd, &binds, &(), [w, h])?;
                    if count > 0 {
                        unsafe {
                            ctx.device
                                .cmd_bind_vertex_buffers(cmd, 0, &[buffer.raw], &[0]);
                            ctx.device.cmd_draw(cmd, count, 1, 0, 0);
                        }
                    }
                    Ok(())
                };
            let draw = |pipeline: &GraphicsPipeline| draw_with(pipeline, &vertices, vertex_count);
            let clear = Load::Clear([0.0; 4]);
            match (&layers, &depth) {
                (Some([phong, diffuse, lin_depth, context]), Some(depth)) => {
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
                    let (fv, fcount) = focus_vertices
                        .as_ref()
                        .map_or((&vertices, 0), |(b, n)| (b, *n));
                    draw_with(&self.focus, fv, fcount)?;
                    end_rendering(ctx, cmd);
                    profiler.end(cmd);
                    profiler.begin(cmd, "context");
                    begin_rendering(ctx, cmd, &[(context, clear)], Some((depth, Load::Keep)));
                    draw(&self.context)?;
                    end_rendering(ctx, cmd);
                    profiler.end(cmd);
                    profiler.begin(cmd, "composite");
                    phong.transition(cmd, Access::FragmentSampled);
                    context.transition(cmd, Access::FragmentSampled);
                    begin_rendering(ctx, cmd, &[(&composite, clear)], None);
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
                    begin_rendering(ctx, cmd, &[(&composite, clear)], None);
                    draw(&self.one_pass)?;
                    end_rendering(ctx, cmd);
                    profiler.end(cmd);
                }
            }
            if !readbacks.is_empty() {
                profiler.pass(cmd, "readback", |cmd| {
                    for (image, buffer) in &readbacks {
                        record_readback(ctx, cmd, image, buffer);
                    }
                });
            }
            Ok(())
        })?;
        let passes = profiler.results()?;
        let rgba = |b: &Buffer| -> Result<Vec<[f32; 4]>> {
            let bytes = b
                .mapped()
                .ok_or_else(|| Error::Invalid("readback buffer is not host-visible".into()))?;
            Ok(bytemuck::pod_collect_to_vec(bytes))
        };
        let (composite_px, layers_px) = if readback {
            let composite_px = rgba(&readbacks[0].1)?;
            let layers_px = if two_level {
                let depth_bytes = readbacks[3]
                    .1
                    .mapped()
                    .ok_or_else(|| Error::Invalid("readback buffer is not host-visible".into()))?;
                Some(Layers {
                    focus_phong: rgba(&readbacks[1].1)?,
                    focus_diffuse: rgba(&readbacks[2].1)?,
                    focus_depth: bytemuck::pod_collect_to_vec(depth_bytes),
                    context: rgba(&readbacks[4].1)?,
                })
            } else {
                None
            };
            (composite_px, layers_px)
        } else {
            (Vec::new(), None)
        };
        Ok(Frame {
            size: [w, h],
            composite: composite_px,
            layers: layers_px,
            passes,
            slices: proxy.slices,
        })
    }
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
    vol: &VolumeTextures,
    half: Vec3,
    keep: &dyn Fn(usize) -> bool,
) -> Vec<(Vec3, Vec3)> {
    let n = vol.bricks.range.len();
    let kept: Vec<usize> = (0..n).filter(|&b| keep(b)).collect();
    if kept.len() as f64 > BRICK_FRACTION * n as f64 {
        return vec![(-half, half)];
    }
    let world = |v: usize, a: usize| (v as f32 / vol.dims[a] as f32) * 2.0 * half[a] - half[a];
    kept.into_iter()
        .map(|b| {
            let (l, h) = vol.bricks.voxel_bounds(b, vol.dims);
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
                focus
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

    #[test]
    fn focus_parsing() {
        assert_eq!(
            Focus::parse(Some("10:20"), None).unwrap(),
            Focus::Range { lo: 10.0, hi: 20.0 }
        );
        assert_eq!(Focus::parse(None, Some(3.0)).unwrap(), Focus::Iso(3.0));
        assert!(Focus::parse(Some("20:10"), None).is_err());
        assert!(Focus::parse(Some("x"), None).is_err());
        assert!(Focus::parse(Some("1:2"), Some(1.0)).is_err());
    }
}
