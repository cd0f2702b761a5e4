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
//! The planes, uniforms and brick culling come from `render::frame`'s `FrameSetup`; this module
//! only draws them ([`Slicer::record_two_level`], [`Slicer::record_one_pass`]).

use crate::render::shading::SHADE_BINDINGS;
use crate::render::targets::{TargetLayers, COLOR, DEPTH, LINEAR_DEPTH};
use std::sync::Arc;
use vellum_error::Result;
use vellum_gpu::graphics::{
    begin_rendering, end_rendering, Blend, DepthState, DepthTest, GraphicsDesc, GraphicsPipeline,
    Load,
};
use vellum_gpu::{Access, Bind, BindingKind, BufferSlice, Context, Image, Sampler};
use vellum_gpu::{CommandBuffer, Format};

/// What the slicer draws in one frame: the shared shading bindings, and the proxy planes staged
/// in the frame's ring (the focus level's apart, for two levels).
pub(crate) struct SliceDraw<'a> {
    /// The eight bindings of `shade.glsl` (`render::shading::SHADE_BINDINGS`).
    pub(crate) shading: &'a [Bind<'a>; 8],
    /// Width and height of the targets in pixels.
    pub size: [u32; 2],
    /// The context's (or the one pass's) vertices and their count.
    pub(crate) vertices: (BufferSlice, u32),
    /// The focus level's vertices and their count.
    pub(crate) focus_vertices: Option<(BufferSlice, u32)>,
}

/// The slicer's pipelines.
pub(crate) struct Slicer {
    ctx: Arc<Context>,
    one_pass: GraphicsPipeline,
    focus: GraphicsPipeline,
    context: GraphicsPipeline,
    composite: GraphicsPipeline,
    nearest: Sampler,
}

impl Slicer {
    /// Builds the four pipelines.
    pub fn new(ctx: &Arc<Context>) -> Result<Self> {
        let slice =
            |name, fragment, colors: &[Format], blend: &[Blend], depth, constants: &[u32]| {
                GraphicsPipeline::new(
                    ctx,
                    &GraphicsDesc {
                        name,
                        vertex_shader: "render/slice.vert",
                        fragment_shader: fragment,
                        bindings: &SHADE_BINDINGS,
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
                compare: DepthTest::LessOrEqual,
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
                compare: DepthTest::Less,
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
        Ok(Slicer {
            ctx: ctx.clone(),
            one_pass,
            focus,
            context,
            composite,
            nearest: Sampler::new(ctx, false)?,
        })
    }

    /// Draws `vertices` with `pipeline` and the shading bindings (binding the pipeline even when
    /// there is nothing to draw, so the attachments are cleared).
    fn draw(
        &self,
        cmd: CommandBuffer,
        pipeline: &GraphicsPipeline,
        d: &SliceDraw,
        (buffer, count): (BufferSlice, u32),
    ) -> Result<()> {
        pipeline.bind(cmd, d.shading, &(), d.size)?;
        if count > 0 {
            vellum_gpu::commands::draw(&self.ctx, cmd, Some(&buffer), count);
        }
        Ok(())
    }

    /// Passes `focus` (MRT: Phong, diffuse, linear depth, and D32 depth), `context` (depth-tested
    /// against the focus) and `composite` (context over focus) into `layers` and `composite`.
    pub(crate) fn record_two_level(
        &self,
        frame: &mut vellum_gpu::Frame,
        d: &SliceDraw,
        layers: &TargetLayers,
        composite: &Image,
    ) -> Result<()> {
        let (ctx, cmd) = (&self.ctx, frame.cmd);
        let profiler = &mut *frame.profiler;
        let clear = Load::Clear([0.0; 4]);
        let (phong, context) = (&layers.focus_phong, &layers.context);
        profiler.begin(cmd, "focus");
        begin_rendering(
            ctx,
            cmd,
            &[
                (phong, clear),
                (&layers.focus_diffuse, clear),
                (&layers.focus_depth, Load::Clear([f32::INFINITY; 4])),
            ],
            Some((&layers.depth, Load::Clear([1.0; 4]))),
        );
        let focus_vertices = d.focus_vertices.unwrap_or((d.vertices.0, 0));
        self.draw(cmd, &self.focus, d, focus_vertices)?;
        end_rendering(ctx, cmd);
        profiler.end(cmd);
        profiler.begin(cmd, "context");
        begin_rendering(
            ctx,
            cmd,
            &[(context, clear)],
            Some((&layers.depth, Load::Keep)),
        );
        self.draw(cmd, &self.context, d, d.vertices)?;
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
            d.size,
        )?;
        vellum_gpu::commands::draw(ctx, cmd, None, 3);
        end_rendering(ctx, cmd);
        profiler.end(cmd);
        Ok(())
    }

    /// Pass `one_pass`: every sample, classified and shaded, into `composite`.
    pub(crate) fn record_one_pass(
        &self,
        frame: &mut vellum_gpu::Frame,
        d: &SliceDraw,
        composite: &Image,
    ) -> Result<()> {
        let cmd = frame.cmd;
        frame.profiler.begin(cmd, "one_pass");
        begin_rendering(&self.ctx, cmd, &[(composite, Load::Clear([0.0; 4]))], None);
        self.draw(cmd, &self.one_pass, d, d.vertices)?;
        end_rendering(&self.ctx, cmd);
        frame.profiler.end(cmd);
        Ok(())
    }
}
