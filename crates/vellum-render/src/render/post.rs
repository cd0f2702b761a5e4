//! The image-space passes of the styles (two-level paper §3; SPEC TL4, TL6), recorded after the
//! renderer's passes over its persistent layers: edges on the luminance of `focus.diffuse`
//! (Sobel, DoG, Canny), abstraction of `context` (Kuwahara, saturation), and the style composite
//! (edges over `focus.phong`, the context over that) into `composite`. Each pass has a CPU twin in
//! `imaging/` that `tests/styles.rs` compares it with.
//!
//! ## Canny's hysteresis
//! Hysteresis is a flood fill; on the GPU it is a bounded series of [`HYSTERESIS_PASSES`] passes.
//! Each pass spreads "strong" to 8-connected "weak" pixels within its 16×16 tile until the tile
//! stops changing, so a pass carries a chain across at least one tile border. A pass runs only if
//! the one before it changed something; the counter after the last pass says whether the series
//! converged (`PostTargets::hysteresis_converged` reads it in tests). 16 passes follow a chain
//! through 16 tile borders, at least 256 pixels of edge, which covers every chain we have met in
//! renders up to 1024²; the tests assert convergence, so a longer chain fails loudly.

use crate::passes::lines::{LineExtractor, LineRequest, LineState, RasterView, SegmentLines};
use crate::render::style::{Abstraction, EdgeKind, Style, StyleParams};
use crate::render::targets::{PostTargets, TargetImages, TargetLayers};
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::commands::memory_transition;
use vellum_gpu::pipeline::group_count;
use vellum_gpu::CommandBuffer;
use vellum_gpu::{
    Access, Bind, BindingKind, ComputePipeline, Context, Frame, Image, PipelineCache, PipelineDesc,
};
use vellum_volume::lines::{Eye, LineParams};

/// Object-space lines of a frame (styles 4–12): what to extract, from which volume, and where
/// to draw it. The renderer fills it in; [`Post::record`] extracts and draws the lines into the
/// edge image before the style composite.
pub(crate) struct LinesDraw<'a> {
    /// The extraction and raster passes.
    pub(crate) extractor: &'a LineExtractor,
    /// Where the extraction's per-kind pipelines are built and kept.
    pub pipelines: &'a mut PipelineCache,
    /// The view's segment buffer and traversal state.
    pub state: &'a mut LineState,
    /// The normalised volume texture.
    pub volume: &'a Image,
    /// Voxels along x, y, z of `volume`.
    pub dims: [usize; 3],
    /// Physical size of a voxel along x, y, z.
    pub spacing: [f32; 3],
    /// Where the eye is, in the physical frame (index × spacing).
    pub eye: Eye,
    /// Which lines and how they are filtered; `iso` on the normalised scale of `volume`.
    pub params: LineParams,
    /// Where the lines are drawn; [`Post::record`] sets its `value` and `floor` for the edge image.
    pub view: RasterView,
    /// A label volume's segments, whose lines are drawn instead of `volume`'s.
    pub segments: Option<SegmentLines<'a>>,
}

/// What every step of one frame's style passes shares.
struct Step<'a> {
    cmd: CommandBuffer,
    groups: [u32; 3],
    /// The push constants with the image size set.
    base: PostPush,
    layers: &'a TargetLayers,
    post: &'a PostTargets,
}

/// Push constants of the post passes (GLSL twin: `PostPush` in post.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct PostPush {
    /// x, y: the image's width and height; z: the blur's axis (0 x, 1 y); w: Kuwahara's radius.
    pub(crate) size_mode: [i32; 4],
    /// Per pass: blur σ; Sobel threshold; DoG τ, ε, φ; Canny high and low; saturation factor.
    pub params: [f32; 4],
    /// Composite: the edge colour (rgb) and its opacity (a).
    pub edge: [f32; 4],
    /// Composite: x the dilation radius, y whether edges are present, z the edge image's offset
    /// (1 for Canny's classes); hysteresis: w the pass index.
    pub flags: [i32; 4],
}

/// Workgroup edge of the post passes (POST_LOCAL in post.glsl).
pub(crate) const LOCAL: u32 = 16;

pub(crate) use crate::render::targets::HYSTERESIS_PASSES;

/// The post pipelines.
pub(crate) struct Post {
    ctx: Arc<Context>,
    luminance: Arc<ComputePipeline>,
    blur: Arc<ComputePipeline>,
    gradient: Arc<ComputePipeline>,
    sobel: Arc<ComputePipeline>,
    dog: Arc<ComputePipeline>,
    canny: Arc<ComputePipeline>,
    hysteresis: Arc<ComputePipeline>,
    kuwahara: Arc<ComputePipeline>,
    saturation: Arc<ComputePipeline>,
    composite: Arc<ComputePipeline>,
}

impl Post {
    /// Takes the pipelines from `pipelines`, building those it does not hold.
    pub fn new(pipelines: &mut PipelineCache) -> Result<Self> {
        use BindingKind::*;
        let push = std::mem::size_of::<PostPush>() as u32;
        let ctx = pipelines.context().clone();
        let mut p =
            |shader: &str, b: &[BindingKind]| pipelines.get(&PipelineDesc::new(shader, b, push));
        let two = [StorageImage, StorageImage];
        Ok(Post {
            ctx,
            luminance: p("post/luminance.comp", &two)?,
            blur: p("post/blur.comp", &two)?,
            gradient: p("post/gradient.comp", &two)?,
            sobel: p("post/sobel_edges.comp", &two)?,
            dog: p("post/dog.comp", &[StorageImage, StorageImage, StorageImage])?,
            canny: p("post/canny_nms.comp", &two)?,
            hysteresis: p("post/hysteresis.comp", &[StorageImage, StorageBuffer])?,
            kuwahara: p("post/kuwahara.comp", &two)?,
            saturation: p("post/saturation.comp", &two)?,
            composite: p(
                "post/composite.comp",
                &[StorageImage, StorageImage, StorageImage, StorageImage],
            )?,
        })
    }

    /// Records the style's passes over `layers` (a two-level frame's targets) into `frame`,
    /// ending with the styled image in `layers.composite`: edges, lines, abstraction, composite.
    pub fn record(
        &self,
        frame: &mut Frame,
        style: &Style,
        layers: &TargetImages,
        post: &PostTargets,
        lines: Option<LinesDraw>,
    ) -> Result<()> {
        if style.def.edges.is_none() && style.def.abstraction.is_none() && lines.is_none() {
            // Style 15: the plain two-level composite is already in place.
            return Ok(());
        }
        let l = layers
            .layers
            .as_ref()
            .ok_or_else(|| Error::Invalid("styles are recorded on two-level frames".into()))?;
        let size = layers.size;
        let s = Step {
            cmd: frame.cmd,
            groups: group_count([size[0], size[1], 1], [LOCAL, LOCAL, 1]),
            base: PostPush {
                size_mode: [size[0] as i32, size[1] as i32, 0, 0],
                ..Default::default()
            },
            layers: l,
            post,
        };
        let edge_offset = match style.def.edges {
            Some(kind) => self.record_edges(&s, frame, kind, &style.params)?,
            None => 0,
        };
        let has_lines = lines.is_some();
        if let Some(d) = lines {
            self.record_lines(&s, frame, d, style.def.edges.is_none(), edge_offset)?;
        }
        let context = match style.def.abstraction {
            None => &l.context,
            Some(a) => self.record_abstraction(&s, frame, a, &style.params)?,
        };
        let with_edges = style.def.edges.is_some() || has_lines;
        frame.profiler.pass(s.cmd, "style_composite", |_| {
            self.record_composite(
                &s,
                style,
                context,
                &layers.composite,
                with_edges,
                edge_offset,
            )
        })
    }

    /// One dispatch of `pipeline` from `inputs` (read) to `output` (written).
    fn run(
        &self,
        s: &Step,
        pipeline: &ComputePipeline,
        inputs: &[&Image],
        output: &Image,
        push: PostPush,
    ) -> Result<()> {
        for i in inputs {
            i.transition(s.cmd, Access::ComputeRead);
        }
        output.discard();
        output.transition(s.cmd, Access::ComputeWrite);
        let mut binds: Vec<Bind> = inputs.iter().map(|i| Bind::StorageImage(i)).collect();
        binds.push(Bind::StorageImage(output));
        pipeline.dispatch(s.cmd, &binds, &push, s.groups)
    }

    /// Pass `blur`: the separable Gaussian of `sigma` from `src` into `dst`.
    fn blur(
        &self,
        s: &Step,
        frame: &mut Frame,
        src: &Image,
        dst: &Image,
        sigma: f32,
    ) -> Result<()> {
        frame.profiler.pass(s.cmd, "blur", |_| -> Result<()> {
            let mut push = s.base;
            push.params[0] = sigma;
            self.run(s, &self.blur, &[src], &s.post.tmp, push)?;
            push.size_mode[2] = 1;
            self.run(s, &self.blur, &[&s.post.tmp], dst, push)
        })
    }

    /// The edge passes on the luminance of `focus.diffuse` into `post.edges`. Returns the edge
    /// image's offset: 1 for Canny, whose image holds classes (2 edge, 1 weak), else 0.
    fn record_edges(
        &self,
        s: &Step,
        frame: &mut Frame,
        kind: EdgeKind,
        p: &StyleParams,
    ) -> Result<i32> {
        let (cmd, post, base) = (s.cmd, s.post, s.base);
        frame.profiler.pass(cmd, "luminance", |_| {
            self.run(
                s,
                &self.luminance,
                &[&s.layers.focus_diffuse],
                &post.luminance,
                base,
            )
        })?;
        match kind {
            EdgeKind::Sobel => frame.profiler.pass(cmd, "sobel", |_| -> Result<()> {
                self.run(s, &self.gradient, &[&post.luminance], &post.gradient, base)?;
                let mut push = base;
                push.params[0] = p.sobel_threshold;
                self.run(s, &self.sobel, &[&post.gradient], &post.edges, push)
            })?,
            EdgeKind::Dog => {
                self.blur(s, frame, &post.luminance, &post.blur_a, p.dog_sigma)?;
                self.blur(
                    s,
                    frame,
                    &post.luminance,
                    &post.blur_b,
                    p.dog_k * p.dog_sigma,
                )?;
                frame.profiler.pass(cmd, "dog", |_| {
                    let mut push = base;
                    push.params = [p.dog_tau, p.dog_threshold, p.dog_phi, 0.0];
                    self.run(
                        s,
                        &self.dog,
                        &[&post.blur_a, &post.blur_b],
                        &post.edges,
                        push,
                    )
                })?;
            }
            EdgeKind::Canny => {
                self.blur(s, frame, &post.luminance, &post.blur_a, p.canny_sigma)?;
                frame.profiler.pass(cmd, "canny", |_| -> Result<()> {
                    self.run(s, &self.gradient, &[&post.blur_a], &post.gradient, base)?;
                    let mut push = base;
                    push.params = [p.canny_high, p.canny_high * p.canny_low_ratio, 0.0, 0.0];
                    self.run(s, &self.canny, &[&post.gradient], &post.edges, push)
                })?;
                frame.profiler.pass(cmd, "hysteresis", |_| {
                    self.record_hysteresis(cmd, post, base)
                })?;
                return Ok(1);
            }
        }
        Ok(0)
    }

    /// Extracts the object-space lines and draws them into `post.edges` (cleared first when
    /// the style has no image-space edges), depth-tested against `focus.depth`.
    fn record_lines(
        &self,
        s: &Step,
        frame: &mut Frame,
        d: LinesDraw,
        alone: bool,
        edge_offset: i32,
    ) -> Result<()> {
        let (cmd, post) = (s.cmd, s.post);
        if alone {
            // Lines alone: start from an empty edge image.
            vellum_gpu::commands::clear_image(&self.ctx, cmd, &post.edges);
        }
        let request = LineRequest {
            values: d.volume,
            dims: d.dims,
            spacing: d.spacing,
            eye: d.eye,
            params: d.params,
            hessian: None,
        };
        match &d.segments {
            Some(segments) => {
                d.extractor
                    .record_segments(frame, d.pipelines, d.state, &request, segments)?
            }
            None => d.extractor.record(frame, d.pipelines, d.state, &request)?,
        }
        let view = RasterView {
            // Canny's edge image holds classes: 2 is an edge, 1 a candidate the composite
            // draws as none; a line pixel of coverage c is 1 + c there.
            value: 1.0 + edge_offset as f32,
            floor: edge_offset as f32,
            ..d.view
        };
        d.extractor.record_raster(
            frame,
            &d.state.buffer,
            &view,
            &s.layers.focus_depth,
            &post.edges,
        )
    }

    /// Pass `kuwahara` or `saturation` on `context` into `post.context`, which it returns.
    fn record_abstraction<'a>(
        &self,
        s: &Step<'a>,
        frame: &mut Frame,
        a: Abstraction,
        p: &StyleParams,
    ) -> Result<&'a Image> {
        let (name, pipeline, mut push) = match a {
            Abstraction::Kuwahara => ("kuwahara", &self.kuwahara, s.base),
            Abstraction::Saturation => ("saturation", &self.saturation, s.base),
        };
        push.size_mode[3] = p.kuwahara_radius as i32;
        push.params[0] = p.saturation;
        frame.profiler.pass(s.cmd, name, |_| {
            self.run(s, pipeline, &[&s.layers.context], &s.post.context, push)
        })?;
        Ok(&s.post.context)
    }

    /// The style composite: edges over `focus.phong`, `context` over that, into `composite`.
    fn record_composite(
        &self,
        s: &Step,
        style: &Style,
        context: &Image,
        composite: &Image,
        with_edges: bool,
        edge_offset: i32,
    ) -> Result<()> {
        let p = &style.params;
        let push = PostPush {
            edge: [
                p.edge_color[0],
                p.edge_color[1],
                p.edge_color[2],
                p.edge_opacity,
            ],
            flags: [
                (p.edge_width.max(1) as i32 - 1) / 2,
                with_edges as i32,
                edge_offset,
                0,
            ],
            ..s.base
        };
        if !with_edges {
            // The binding still needs an image: a defined one.
            s.post.edges.transition(s.cmd, Access::ComputeRead);
        }
        self.run(
            s,
            &self.composite,
            &[&s.layers.focus_phong, context, &s.post.edges],
            composite,
            push,
        )
    }

    /// The hysteresis series on `post.edges`, in place.
    fn record_hysteresis(
        &self,
        cmd: CommandBuffer,
        post: &PostTargets,
        base: PostPush,
    ) -> Result<()> {
        let ctx = &self.ctx;
        let groups = group_count([post.size[0], post.size[1], 1], [LOCAL, LOCAL, 1]);
        vellum_gpu::commands::fill_buffer(ctx, cmd, &post.changed, 0);
        memory_transition(ctx, cmd, Access::TransferWrite, Access::TransferWrite);
        vellum_gpu::commands::update_buffer(ctx, cmd, &post.changed, &1u32.to_ne_bytes());
        memory_transition(ctx, cmd, Access::TransferWrite, Access::ComputeReadWrite);
        for i in 0..HYSTERESIS_PASSES {
            post.edges.transition(cmd, Access::ComputeReadWrite);
            if i > 0 {
                memory_transition(ctx, cmd, Access::ComputeReadWrite, Access::ComputeReadWrite);
            }
            let mut push = base;
            push.flags[3] = i as i32;
            self.hysteresis.dispatch(
                cmd,
                &[
                    Bind::StorageImage(&post.edges),
                    Bind::StorageBuffer(&post.changed),
                ],
                &push,
                groups,
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vellum_gpu::interface::assert_glsl_layout;

    #[test]
    fn push_constants_match_glsl() {
        assert_glsl_layout!(
            PostPush,
            "post.glsl",
            "PostPush",
            [size_mode, params, edge, flags]
        );
        let src = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../glsl/common/post.glsl"
        ))
        .unwrap();
        assert!(src.contains(&format!("#define POST_LOCAL {LOCAL}")));
    }
}
