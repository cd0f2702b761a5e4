//! Graphics pipelines for dynamic rendering (no render-pass objects): formats of the colour and
//! depth attachments are part of the pipeline description, blending is per attachment, and
//! resources are pushed like compute ones (see `pipeline.rs`). [`begin_rendering`] transitions the
//! attachments through the barrier table and opens a dynamic-rendering scope.

use crate::barrier::{access_info, Access};
use crate::context::Context;
use crate::pipeline::{shader_module, specialization_entries, Bind, BindingKind, PipelineLayout};
use crate::resources::Image;
use crate::VkContext;
use ash::vk;
use std::sync::Arc;
use vellum_error::Result;

/// Blending of one colour attachment.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Blend {
    /// The fragment replaces what is there.
    Replace,
    /// Premultiplied-alpha "over": dst = src + (1 − src.a) · dst, for back-to-front compositing.
    PremultipliedOver,
}

/// Which fragments pass the depth test, against the depth already in the attachment.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum DepthTest {
    /// Nearer fragments only.
    Less,
    /// Nearer fragments and those at the same depth.
    LessOrEqual,
}

impl DepthTest {
    fn op(self) -> vk::CompareOp {
        match self {
            DepthTest::Less => vk::CompareOp::LESS,
            DepthTest::LessOrEqual => vk::CompareOp::LESS_OR_EQUAL,
        }
    }
}

/// Depth testing of a pipeline.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct DepthState {
    /// The depth attachment's format.
    pub format: vk::Format,
    /// The depth test.
    pub compare: DepthTest,
    /// Whether fragments write depth.
    pub write: bool,
}

/// Everything that defines a graphics pipeline.
#[derive(Clone, Debug)]
pub struct GraphicsDesc<'a> {
    /// The name in messages, labels and the pipeline cache.
    pub name: &'a str,
    /// The vertex shader, by its path under glsl/.
    pub vertex_shader: &'a str,
    /// The fragment shader, by its path under glsl/.
    pub fragment_shader: &'a str,
    /// The bindings of set 0, in binding order.
    pub bindings: &'a [BindingKind],
    /// Bytes of push constants, shared by both stages.
    pub push_constant_bytes: u32,
    /// Bytes per vertex of the single vertex buffer, whose one attribute (location 0) is a vec3;
    /// 0 for pipelines that make their vertices from `gl_VertexIndex`.
    pub vertex_stride: u32,
    /// The formats of the colour attachments, in location order.
    pub color_formats: &'a [vk::Format],
    /// The blending of each colour attachment.
    pub blend: &'a [Blend],
    /// Depth testing, or none.
    pub depth: Option<DepthState>,
    /// Fragment-shader specialisation constants, `constant_id = i`.
    pub fragment_constants: &'a [u32],
}

/// A graphics pipeline with its layout.
pub struct GraphicsPipeline {
    ctx: Arc<Context>,
    /// The pipeline.
    pub raw: vk::Pipeline,
    /// Its layout (set 0 and the push constants).
    pub layout: PipelineLayout,
    /// The name in messages and labels.
    pub name: String,
}

impl GraphicsPipeline {
    /// Builds the pipeline described by `desc`.
    pub fn new(ctx: &Arc<Context>, desc: &GraphicsDesc) -> Result<Self> {
        assert_eq!(
            desc.color_formats.len(),
            desc.blend.len(),
            "{}: one blend state per colour attachment",
            desc.name
        );
        let stages_flags = vk::ShaderStageFlags::VERTEX | vk::ShaderStageFlags::FRAGMENT;
        let layout = PipelineLayout::new(
            ctx,
            desc.name,
            desc.bindings,
            desc.push_constant_bytes,
            stages_flags,
        )?;
        let vs = shader_module(ctx, desc.vertex_shader)?;
        let fs = match shader_module(ctx, desc.fragment_shader) {
            Ok(m) => m,
            Err(e) => {
                unsafe { ctx.device.destroy_shader_module(vs, None) };
                return Err(e);
            }
        };
        let entries = specialization_entries(desc.fragment_constants);
        let spec = vk::SpecializationInfo::default()
            .map_entries(&entries)
            .data(bytemuck::cast_slice(desc.fragment_constants));
        let mut fs_stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::FRAGMENT)
            .module(fs)
            .name(c"main");
        if !desc.fragment_constants.is_empty() {
            fs_stage = fs_stage.specialization_info(&spec);
        }
        let stages = [
            vk::PipelineShaderStageCreateInfo::default()
                .stage(vk::ShaderStageFlags::VERTEX)
                .module(vs)
                .name(c"main"),
            fs_stage,
        ];

        let vb = [vk::VertexInputBindingDescription {
            binding: 0,
            stride: desc.vertex_stride,
            input_rate: vk::VertexInputRate::VERTEX,
        }];
        let va = [vk::VertexInputAttributeDescription {
            location: 0,
            binding: 0,
            format: vk::Format::R32G32B32_SFLOAT,
            offset: 0,
        }];
        let vertex_input = if desc.vertex_stride > 0 {
            vk::PipelineVertexInputStateCreateInfo::default()
                .vertex_binding_descriptions(&vb)
                .vertex_attribute_descriptions(&va)
        } else {
            vk::PipelineVertexInputStateCreateInfo::default()
        };
        let assembly = vk::PipelineInputAssemblyStateCreateInfo::default()
            .topology(vk::PrimitiveTopology::TRIANGLE_LIST);
        let viewport = vk::PipelineViewportStateCreateInfo::default()
            .viewport_count(1)
            .scissor_count(1);
        let raster = vk::PipelineRasterizationStateCreateInfo::default()
            .polygon_mode(vk::PolygonMode::FILL)
            .cull_mode(vk::CullModeFlags::NONE)
            .front_face(vk::FrontFace::COUNTER_CLOCKWISE)
            .line_width(1.0);
        let multisample = vk::PipelineMultisampleStateCreateInfo::default()
            .rasterization_samples(vk::SampleCountFlags::TYPE_1);
        let attachments: Vec<_> = desc
            .blend
            .iter()
            .map(|b| {
                let a = vk::PipelineColorBlendAttachmentState::default()
                    .color_write_mask(vk::ColorComponentFlags::RGBA);
                match b {
                    Blend::Replace => a,
                    Blend::PremultipliedOver => a
                        .blend_enable(true)
                        .src_color_blend_factor(vk::BlendFactor::ONE)
                        .dst_color_blend_factor(vk::BlendFactor::ONE_MINUS_SRC_ALPHA)
                        .color_blend_op(vk::BlendOp::ADD)
                        .src_alpha_blend_factor(vk::BlendFactor::ONE)
                        .dst_alpha_blend_factor(vk::BlendFactor::ONE_MINUS_SRC_ALPHA)
                        .alpha_blend_op(vk::BlendOp::ADD),
                }
            })
            .collect();
        let blend = vk::PipelineColorBlendStateCreateInfo::default().attachments(&attachments);
        let depth = match desc.depth {
            Some(d) => vk::PipelineDepthStencilStateCreateInfo::default()
                .depth_test_enable(true)
                .depth_write_enable(d.write)
                .depth_compare_op(d.compare.op()),
            None => vk::PipelineDepthStencilStateCreateInfo::default(),
        };
        let dynamic_states = [vk::DynamicState::VIEWPORT, vk::DynamicState::SCISSOR];
        let dynamic = vk::PipelineDynamicStateCreateInfo::default().dynamic_states(&dynamic_states);
        let mut rendering = vk::PipelineRenderingCreateInfo::default()
            .color_attachment_formats(desc.color_formats)
            .depth_attachment_format(
                desc.depth
                    .map(|d| d.format)
                    .unwrap_or(vk::Format::UNDEFINED),
            );
        let info = [vk::GraphicsPipelineCreateInfo::default()
            .stages(&stages)
            .vertex_input_state(&vertex_input)
            .input_assembly_state(&assembly)
            .viewport_state(&viewport)
            .rasterization_state(&raster)
            .multisample_state(&multisample)
            .color_blend_state(&blend)
            .depth_stencil_state(&depth)
            .dynamic_state(&dynamic)
            .layout(layout.raw)
            .push_next(&mut rendering)];
        let result = unsafe {
            ctx.device
                .create_graphics_pipelines(vk::PipelineCache::null(), &info, None)
        };
        unsafe {
            ctx.device.destroy_shader_module(vs, None);
            ctx.device.destroy_shader_module(fs, None);
        }
        let raw = result
            .map_err(|(_, r)| r)
            .vk(format!("creating graphics pipeline {}", desc.name))?[0];
        ctx.set_name(raw, desc.name);
        Ok(GraphicsPipeline {
            ctx: ctx.clone(),
            raw,
            layout,
            name: desc.name.to_string(),
        })
    }

    /// Binds the pipeline, its resources and push constants, and sets a full-target viewport.
    pub fn bind<P: bytemuck::Pod>(
        &self,
        cmd: vk::CommandBuffer,
        binds: &[Bind],
        push: &P,
        extent: [u32; 2],
    ) -> Result<()> {
        let d = &self.ctx.device;
        unsafe {
            d.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, self.raw);
            let viewport = vk::Viewport {
                x: 0.0,
                y: 0.0,
                width: extent[0] as f32,
                height: extent[1] as f32,
                min_depth: 0.0,
                max_depth: 1.0,
            };
            d.cmd_set_viewport(cmd, 0, &[viewport]);
            d.cmd_set_scissor(
                cmd,
                0,
                &[vk::Rect2D {
                    offset: vk::Offset2D::default(),
                    extent: vk::Extent2D {
                        width: extent[0],
                        height: extent[1],
                    },
                }],
            );
        }
        self.layout.push(
            cmd,
            vk::PipelineBindPoint::GRAPHICS,
            &self.name,
            binds,
            bytemuck::bytes_of(push),
        )
    }
}

impl Drop for GraphicsPipeline {
    fn drop(&mut self) {
        // Deferred while a submission that may use it is in flight (gpu/lifetime.rs).
        let raw = self.raw;
        self.ctx.retire(Box::new(move |ctx| unsafe {
            ctx.device.destroy_pipeline(raw, None)
        }));
    }
}

/// How an attachment starts: cleared to a value, or loaded as it is.
#[derive(Copy, Clone, Debug)]
pub enum Load {
    /// Cleared to this colour (or depth in the first component).
    Clear([f32; 4]),
    /// Loaded as it is.
    Keep,
}

/// Transitions `colors` and `depth` to attachment use and opens a dynamic-rendering scope over
/// the extent of the first attachment. Close it with [`end_rendering`].
pub fn begin_rendering(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    colors: &[(&Image, Load)],
    depth: Option<(&Image, Load)>,
) {
    let extent = colors
        .first()
        .map(|c| c.0)
        .or(depth.map(|d| d.0))
        .map(|i| i.desc.extent)
        .unwrap_or([1, 1, 1]);
    let attachment = |image: &Image, load: Load, next: Access| {
        if matches!(load, Load::Clear(_)) {
            image.discard();
        }
        image.transition(cmd, next);
        let (op, clear) = match load {
            Load::Clear(c) => (
                vk::AttachmentLoadOp::CLEAR,
                if next == Access::DepthAttachment {
                    vk::ClearValue {
                        depth_stencil: vk::ClearDepthStencilValue {
                            depth: c[0],
                            stencil: 0,
                        },
                    }
                } else {
                    vk::ClearValue {
                        color: vk::ClearColorValue { float32: c },
                    }
                },
            ),
            Load::Keep => (vk::AttachmentLoadOp::LOAD, vk::ClearValue::default()),
        };
        vk::RenderingAttachmentInfo::default()
            .image_view(image.view)
            .image_layout(access_info(next).layout)
            .load_op(op)
            .store_op(vk::AttachmentStoreOp::STORE)
            .clear_value(clear)
    };
    let color_infos: Vec<_> = colors
        .iter()
        .map(|(img, load)| attachment(img, *load, Access::ColorAttachment))
        .collect();
    let depth_info = depth.map(|(img, load)| attachment(img, load, Access::DepthAttachment));
    open_scope(
        ctx,
        cmd,
        [extent[0], extent[1]],
        &color_infos,
        depth_info.as_ref(),
    );
}

/// Opens a dynamic-rendering scope over one colour view that is not an [`Image`] (a swapchain's),
/// already in COLOR_ATTACHMENT_OPTIMAL, cleared to `clear`. Close it with [`end_rendering`].
pub fn begin_rendering_view(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    view: vk::ImageView,
    extent: [u32; 2],
    clear: [f32; 4],
) {
    let color = [vk::RenderingAttachmentInfo::default()
        .image_view(view)
        .image_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
        .load_op(vk::AttachmentLoadOp::CLEAR)
        .store_op(vk::AttachmentStoreOp::STORE)
        .clear_value(vk::ClearValue {
            color: vk::ClearColorValue { float32: clear },
        })];
    open_scope(ctx, cmd, extent, &color, None);
}

/// `cmd_begin_rendering` over `extent` with these attachments.
fn open_scope(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    extent: [u32; 2],
    color_infos: &[vk::RenderingAttachmentInfo],
    depth_info: Option<&vk::RenderingAttachmentInfo>,
) {
    let mut info = vk::RenderingInfo::default()
        .render_area(vk::Rect2D {
            offset: vk::Offset2D::default(),
            extent: vk::Extent2D {
                width: extent[0],
                height: extent[1],
            },
        })
        .layer_count(1)
        .color_attachments(color_infos);
    if let Some(d) = depth_info {
        info = info.depth_attachment(d);
    }
    unsafe { ctx.device.cmd_begin_rendering(cmd, &info) };
}

/// Closes the scope opened by [`begin_rendering`].
pub fn end_rendering(ctx: &Context, cmd: vk::CommandBuffer) {
    unsafe { ctx.device.cmd_end_rendering(cmd) };
}
