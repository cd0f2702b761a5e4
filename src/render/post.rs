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

use crate::error::Result;
use crate::gpu::commands::memory_transition;
use crate::gpu::pipeline::group_count;
use crate::gpu::{
    Access, Bind, BindingKind, Buffer, BufferDesc, ComputePipeline, Context, Image, ImageDesc,
    Profiler,
};
use crate::passes::lines::{LineBuffer, LineExtractor, RasterView};
use crate::render::style::{Abstraction, EdgeKind, Style};
use crate::render::targets::TargetImages;
use crate::volume::lines::{Eye, LineParams};
use ash::vk;
use std::sync::Arc;

/// Object-space lines of a frame (styles 4–12): what to extract, from which volume, and where
/// to draw it. The renderer fills it in; [`Post::record`] extracts and draws the lines into the
/// edge image before the style composite.
pub struct LinesDraw<'a> {
    pub extractor: &'a LineExtractor,
    pub buffer: &'a LineBuffer,
    /// The normalised volume texture.
    pub volume: &'a Image,
    pub dims: [usize; 3],
    pub spacing: [f32; 3],
    pub eye: Eye,
    pub params: LineParams,
    pub view: RasterView,
}

/// Push constants of the post passes (GLSL twin: `PostPush` in post.glsl).
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct PostPush {
    pub size_mode: [i32; 4],
    pub params: [f32; 4],
    pub edge: [f32; 4],
    pub flags: [i32; 4],
}

/// Workgroup edge of the post passes (POST_LOCAL in post.glsl).
pub const LOCAL: u32 = 16;

/// Passes of Canny's hysteresis (see the module's doc).
pub const HYSTERESIS_PASSES: u32 = 16;

/// The images the post passes work in, for one size.
pub struct PostTargets {
    pub size: [u32; 2],
    /// Luminance of focus.diffuse.
    pub luminance: Image,
    /// Blur scratch and results.
    pub tmp: Image,
    pub blur_a: Image,
    pub blur_b: Image,
    /// Sobel gradient (gx, gy, normalised magnitude).
    pub gradient: Image,
    /// Edge strength in [0, 1], or Canny's classes (2 edge, 1 weak, 0 none).
    pub edges: Image,
    /// The abstracted context.
    pub context: Image,
    /// Hysteresis change counters, one per pass plus one.
    pub changed: Buffer,
}

impl PostTargets {
    /// Allocates the images for `size`.
    pub fn new(ctx: &Arc<Context>, size: [u32; 2]) -> Result<Self> {
        let desc = |format| {
            ImageDesc::new_2d(format, size).usage(
                vk::ImageUsageFlags::STORAGE
                    | vk::ImageUsageFlags::SAMPLED
                    | vk::ImageUsageFlags::TRANSFER_SRC
                    | vk::ImageUsageFlags::TRANSFER_DST,
            )
        };
        let image = |name: &str, format| Image::new(ctx, name, &desc(format));
        let r32 = vk::Format::R32_SFLOAT;
        let rgba = vk::Format::R32G32B32A32_SFLOAT;
        Ok(PostTargets {
            size,
            luminance: image("post.luminance", r32)?,
            tmp: image("post.tmp", r32)?,
            blur_a: image("post.blur_a", r32)?,
            blur_b: image("post.blur_b", r32)?,
            gradient: image("post.gradient", rgba)?,
            // Lines are drawn into the edges with atomic max on the R32_UINT view: coverage is a
            // non-negative float, whose bits order as unsigned integers do.
            edges: Image::new(ctx, "post.edges", &desc(r32).alias(vk::Format::R32_UINT))?,
            context: image("post.context", rgba)?,
            changed: Buffer::new(
                ctx,
                "post.changed",
                &BufferDesc::storage(4 * (HYSTERESIS_PASSES as u64 + 1)),
            )?,
        })
    }

    /// Whether the last recorded hysteresis converged: reads the last change counter back (tests
    /// and diagnostics; a frame never waits for it).
    pub fn hysteresis_converged(&self, ctx: &Arc<Context>) -> Result<bool> {
        let bytes = crate::gpu::transfer::readback_buffer(ctx, &self.changed)?;
        let counters: Vec<u32> = bytemuck::pod_collect_to_vec(&bytes);
        Ok(counters.last() == Some(&0))
    }
}

/// The post pipelines.
pub struct Post {
    ctx: Arc<Context>,
    luminance: ComputePipeline,
    blur: ComputePipeline,
    gradient: ComputePipeline,
    sobel: ComputePipeline,
    dog: ComputePipeline,
    canny: ComputePipeline,
    hysteresis: ComputePipeline,
    kuwahara: ComputePipeline,
    saturation: ComputePipeline,
    composite: ComputePipeline,
}

impl Post {
    /// Builds the pipelines.
    pub fn new(ctx: &Arc<Context>) -> Result<Self> {
        use BindingKind::*;
        let push = std::mem::size_of::<PostPush>() as u32;
        let p = |shader: &str, b: &[BindingKind]| ComputePipeline::new(ctx, shader, b, push);
        let two = [StorageImage, StorageImage];
        Ok(Post {
            ctx: ctx.clone(),
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

    /// Records the style's passes over `layers` (a two-level frame's targets) into `cmd`, ending
    /// with the styled image in `layers.composite`.
    pub fn record(
        &self,
        cmd: vk::CommandBuffer,
        profiler: &mut Profiler,
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
            .expect("styles are recorded on two-level frames");
        let size = layers.size;
        let groups = group_count([size[0], size[1], 1], [LOCAL, LOCAL, 1]);
        let base = PostPush {
            size_mode: [size[0] as i32, size[1] as i32, 0, 0],
            ..Default::default()
        };
        let p = &style.params;
        // One dispatch from `inputs` (read) to `output` (written).
        let run = |pipeline: &ComputePipeline,
                   inputs: &[&Image],
                   output: &Image,
                   push: PostPush|
         -> Result<()> {
            for i in inputs {
                i.transition(cmd, Access::ComputeRead);
            }
            output.discard();
            output.transition(cmd, Access::ComputeWrite);
            let mut binds: Vec<Bind> = inputs.iter().map(|i| Bind::StorageImage(i)).collect();
            binds.push(Bind::StorageImage(output));
            pipeline.dispatch(cmd, &binds, &push, groups)
        };
        let blur = |profiler: &mut Profiler, src: &Image, dst: &Image, sigma: f32| {
            profiler.pass(cmd, "blur", |_| -> Result<()> {
                let mut push = base;
                push.params[0] = sigma;
                run(&self.blur, &[src], &post.tmp, push)?;
                push.size_mode[2] = 1;
                run(&self.blur, &[&post.tmp], dst, push)
            })
        };
        let mut edge_offset = 0;
        if let Some(kind) = style.def.edges {
            profiler.pass(cmd, "luminance", |_| {
                run(&self.luminance, &[&l.focus_diffuse], &post.luminance, base)
            })?;
            match kind {
                EdgeKind::Sobel => profiler.pass(cmd, "sobel", |_| -> Result<()> {
                    run(&self.gradient, &[&post.luminance], &post.gradient, base)?;
                    let mut push = base;
                    push.params[0] = p.sobel_threshold;
                    run(&self.sobel, &[&post.gradient], &post.edges, push)
                })?,
                EdgeKind::Dog => {
                    blur(profiler, &post.luminance, &post.blur_a, p.dog_sigma)?;
                    blur(
                        profiler,
                        &post.luminance,
                        &post.blur_b,
                        p.dog_k * p.dog_sigma,
                    )?;
                    profiler.pass(cmd, "dog", |_| {
                        let mut push = base;
                        push.params = [p.dog_tau, p.dog_threshold, p.dog_phi, 0.0];
                        run(&self.dog, &[&post.blur_a, &post.blur_b], &post.edges, push)
                    })?;
                }
                EdgeKind::Canny => {
                    blur(profiler, &post.luminance, &post.blur_a, p.canny_sigma)?;
                    profiler.pass(cmd, "canny", |_| -> Result<()> {
                        run(&self.gradient, &[&post.blur_a], &post.gradient, base)?;
                        let mut push = base;
                        push.params = [p.canny_high, p.canny_high * p.canny_low_ratio, 0.0, 0.0];
                        run(&self.canny, &[&post.gradient], &post.edges, push)
                    })?;
                    profiler.pass(cmd, "hysteresis", |_| {
                        self.record_hysteresis(cmd, post, base)
                    })?;
                    edge_offset = 1;
                }
            }
        }
        let has_lines = lines.is_some();
        if let Some(d) = lines {
            if style.def.edges.is_none() {
                // Lines alone: start from an empty edge image.
                post.edges.discard();
                post.edges.transition(cmd, Access::TransferWrite);
                unsafe {
                    self.ctx.device.cmd_clear_color_image(
                        cmd,
                        post.edges.raw,
                        vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                        &vk::ClearColorValue::default(),
                        &[vk::ImageSubresourceRange {
                            aspect_mask: vk::ImageAspectFlags::COLOR,
                            base_mip_level: 0,
                            level_count: 1,
                            base_array_layer: 0,
                            layer_count: 1,
                        }],
                    )
                };
            }
            d.extractor.record(
                cmd, profiler, d.volume, d.dims, d.spacing, d.eye, &d.params, None, d.buffer,
            )?;
            let view = RasterView {
                // Canny's edge image holds classes: 2 is an edge, 1 a candidate the composite
                // draws as none; a line pixel of coverage c is 1 + c there.
                value: 1.0 + edge_offset as f32,
                floor: edge_offset as f32,
                ..d.view
            };
            d.extractor.record_raster(
                cmd,
                profiler,
                d.buffer,
                &view,
                &l.focus_depth,
                &post.edges,
            )?;
        }
        let context = match style.def.abstraction {
            None => &l.context,
            Some(a) => {
                let (name, pipeline, mut push) = match a {
                    Abstraction::Kuwahara => ("kuwahara", &self.kuwahara, base),
                    Abstraction::Saturation => ("saturation", &self.saturation, base),
                };
                push.size_mode[3] = p.kuwahara_radius as i32;
                push.params[0] = p.saturation;
                profiler.pass(cmd, name, |_| {
                    run(pipeline, &[&l.context], &post.context, push)
                })?;
                &post.context
            }
        };
        profiler.pass(cmd, "style_composite", |_| {
            let push = PostPush {
                edge: [
                    p.edge_color[0],
                    p.edge_color[1],
                    p.edge_color[2],
                    p.edge_opacity,
                ],
                flags: [
                    (p.edge_width.max(1) as i32 - 1) / 2,
                    (style.def.edges.is_some() || has_lines) as i32,
                    edge_offset,
                    0,
                ],
                ..base
            };
            if style.def.edges.is_none() && !has_lines {
                // The binding still needs an image: a defined one.
                post.edges.transition(cmd, Access::ComputeRead);
            }
            run(
                &self.composite,
                &[&l.focus_phong, context, &post.edges],
                &layers.composite,
                push,
            )
        })
    }

    /// The hysteresis series on `post.edges`, in place.
    fn record_hysteresis(
        &self,
        cmd: vk::CommandBuffer,
        post: &PostTargets,
        base: PostPush,
    ) -> Result<()> {
        let ctx = &self.ctx;
        let groups = group_count([post.size[0], post.size[1], 1], [LOCAL, LOCAL, 1]);
        unsafe {
            ctx.device
                .cmd_fill_buffer(cmd, post.changed.raw, 0, vk::WHOLE_SIZE, 0);
        }
        memory_transition(ctx, cmd, Access::TransferWrite, Access::TransferWrite);
        unsafe {
            ctx.device
                .cmd_update_buffer(cmd, post.changed.raw, 0, &1u32.to_ne_bytes());
        }
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
    use crate::gpu::interface::assert_glsl_layout;

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
            "/glsl/common/post.glsl"
        ))
        .unwrap();
        assert!(src.contains(&format!("#define POST_LOCAL {LOCAL}")));
    }
}
