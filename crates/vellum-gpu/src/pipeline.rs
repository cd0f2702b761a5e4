//! Compute pipelines with push descriptors. A pipeline is described by its shader, the kinds of its
//! bindings (set 0, binding = position in the list) and the size of its push constants; a dispatch
//! pushes the resources and the constants, so no descriptor pools or sets exist anywhere.

use crate::barrier::access_info;
use crate::context::Context;
use crate::resources::{Buffer, BufferSlice, Image, Sampler};
use crate::shaders;
use crate::VkContext;
use ash::vk;
use std::sync::Arc;
use vellum_error::{Error, Result};

/// The kind of one binding in set 0.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum BindingKind {
    /// A storage image (`image3D`, `image2D`, read and written).
    StorageImage,
    /// A combined image sampler.
    SampledImage,
    /// A storage buffer.
    StorageBuffer,
    /// A uniform buffer.
    UniformBuffer,
}

impl BindingKind {
    fn descriptor_type(self) -> vk::DescriptorType {
        match self {
            BindingKind::StorageImage => vk::DescriptorType::STORAGE_IMAGE,
            BindingKind::SampledImage => vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
            BindingKind::StorageBuffer => vk::DescriptorType::STORAGE_BUFFER,
            BindingKind::UniformBuffer => vk::DescriptorType::UNIFORM_BUFFER,
        }
    }
}

/// Most bindings one dispatch or draw pushes (the ray caster has 17).
pub(crate) const MAX_BINDINGS: usize = 32;

/// A resource bound at dispatch time; its position in the slice is its binding number.
#[derive(Copy, Clone)]
pub enum Bind<'a> {
    /// An image as a storage image.
    StorageImage(&'a Image),
    /// The image's second view (`ImageDesc::alias`), as a storage image.
    StorageImageAlias(&'a Image),
    /// An image with its sampler.
    Sampled(&'a Image, &'a Sampler),
    /// A whole buffer as a storage buffer.
    StorageBuffer(&'a Buffer),
    /// A whole buffer as uniforms.
    Uniform(&'a Buffer),
    /// Uniforms at a range of a buffer, e.g. a frame's staging ring.
    UniformSlice(BufferSlice),
    /// A read-only storage range of a buffer, e.g. per-frame tables in the staging ring.
    StorageSlice(BufferSlice),
}

impl Bind<'_> {
    fn kind(&self) -> BindingKind {
        match self {
            Bind::StorageImage(_) | Bind::StorageImageAlias(_) => BindingKind::StorageImage,
            Bind::Sampled(..) => BindingKind::SampledImage,
            Bind::StorageBuffer(_) | Bind::StorageSlice(_) => BindingKind::StorageBuffer,
            Bind::Uniform(_) | Bind::UniformSlice(_) => BindingKind::UniformBuffer,
        }
    }
}

/// A descriptor-set layout for push descriptors plus a pipeline layout with push constants. Shared
/// by compute and graphics pipelines.
pub struct PipelineLayout {
    ctx: Arc<Context>,
    /// The layout of set 0 (push descriptors).
    pub(crate) set_layout: vk::DescriptorSetLayout,
    /// The pipeline layout.
    pub raw: vk::PipelineLayout,
    /// The bindings of set 0, in binding order.
    pub bindings: Vec<BindingKind>,
    /// Bytes of push constants.
    pub push_constant_bytes: u32,
    /// The stages the push constants and bindings are visible to.
    pub stages: vk::ShaderStageFlags,
}

impl PipelineLayout {
    /// Creates the layouts for `bindings` and `push_constant_bytes` of constants seen by `stages`.
    pub fn new(
        ctx: &Arc<Context>,
        name: &str,
        bindings: &[BindingKind],
        push_constant_bytes: u32,
        stages: vk::ShaderStageFlags,
    ) -> Result<Self> {
        let vk_bindings: Vec<_> = bindings
            .iter()
            .enumerate()
            .map(|(i, k)| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(i as u32)
                    .descriptor_type(k.descriptor_type())
                    .descriptor_count(1)
                    .stage_flags(stages)
            })
            .collect();
        let info = vk::DescriptorSetLayoutCreateInfo::default()
            .flags(vk::DescriptorSetLayoutCreateFlags::PUSH_DESCRIPTOR_KHR)
            .bindings(&vk_bindings);
        let set_layout = unsafe { ctx.device.create_descriptor_set_layout(&info, None) }
            .vk(format!("creating the set layout of {name}"))?;
        let set_layouts = [set_layout];
        let ranges = [vk::PushConstantRange {
            stage_flags: stages,
            offset: 0,
            size: push_constant_bytes,
        }];
        let mut layout_info = vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts);
        if push_constant_bytes > 0 {
            layout_info = layout_info.push_constant_ranges(&ranges);
        }
        let raw = match unsafe { ctx.device.create_pipeline_layout(&layout_info, None) }
            .vk(format!("creating the layout of {name}"))
        {
            Ok(l) => l,
            Err(e) => {
                unsafe { ctx.device.destroy_descriptor_set_layout(set_layout, None) };
                return Err(e);
            }
        };
        ctx.set_name(raw, name);
        Ok(PipelineLayout {
            ctx: ctx.clone(),
            set_layout,
            raw,
            bindings: bindings.to_vec(),
            push_constant_bytes,
            stages,
        })
    }

    /// Pushes `binds` and `push` constants for the pipeline bound at `bind_point`.
    pub fn push(
        &self,
        cmd: vk::CommandBuffer,
        bind_point: vk::PipelineBindPoint,
        name: &str,
        binds: &[Bind],
        push: &[u8],
    ) -> Result<()> {
        let mismatch = |msg: String| Error::Pipeline {
            name: name.to_string(),
            msg,
        };
        if binds.len() != self.bindings.len()
            || binds
                .iter()
                .zip(&self.bindings)
                .any(|(b, k)| b.kind() != *k)
        {
            return Err(mismatch(format!("expected bindings {:?}", self.bindings)));
        }
        if push.len() as u32 != self.push_constant_bytes {
            return Err(mismatch(format!(
                "expected {} bytes of push constants, got {}",
                self.push_constant_bytes,
                push.len()
            )));
        }
        if binds.len() > MAX_BINDINGS {
            return Err(mismatch(format!(
                "{} bindings are more than the {MAX_BINDINGS} a dispatch pushes",
                binds.len()
            )));
        }
        // On the stack: a steady frame's dispatches allocate nothing.
        let mut image_infos = [vk::DescriptorImageInfo::default(); MAX_BINDINGS];
        let mut buffer_infos = [vk::DescriptorBufferInfo::default(); MAX_BINDINGS];
        let (mut ni, mut nb) = (0, 0);
        for b in binds {
            match b {
                Bind::StorageImage(img) => {
                    image_infos[ni] = vk::DescriptorImageInfo::default()
                        .image_view(img.view)
                        .image_layout(access_info(img.access()).layout);
                    ni += 1;
                }
                Bind::StorageImageAlias(img) => {
                    if img.alias_view == vk::ImageView::null() {
                        return Err(Error::Invalid(format!(
                            "image {} has no second view to bind",
                            img.name
                        )));
                    }
                    image_infos[ni] = vk::DescriptorImageInfo::default()
                        .image_view(img.alias_view)
                        .image_layout(access_info(img.access()).layout);
                    ni += 1;
                }
                Bind::Sampled(img, s) => {
                    image_infos[ni] = vk::DescriptorImageInfo::default()
                        .image_view(img.view)
                        .sampler(s.raw)
                        .image_layout(access_info(img.access()).layout);
                    ni += 1;
                }
                Bind::StorageBuffer(buf) | Bind::Uniform(buf) => {
                    buffer_infos[nb] = vk::DescriptorBufferInfo::default()
                        .buffer(buf.raw)
                        .offset(0)
                        .range(vk::WHOLE_SIZE);
                    nb += 1;
                }
                Bind::UniformSlice(slice) | Bind::StorageSlice(slice) => {
                    buffer_infos[nb] = vk::DescriptorBufferInfo::default()
                        .buffer(slice.raw)
                        .offset(slice.offset)
                        .range(slice.size);
                    nb += 1;
                }
            }
        }
        let (mut ii, mut bi) = (0, 0);
        let mut writes = [vk::WriteDescriptorSet::default(); MAX_BINDINGS];
        for (i, b) in binds.iter().enumerate() {
            let w = vk::WriteDescriptorSet::default()
                .dst_binding(i as u32)
                .descriptor_type(b.kind().descriptor_type());
            writes[i] = match b {
                Bind::StorageImage(_) | Bind::StorageImageAlias(_) | Bind::Sampled(..) => {
                    ii += 1;
                    w.image_info(std::slice::from_ref(&image_infos[ii - 1]))
                }
                Bind::StorageBuffer(_)
                | Bind::Uniform(_)
                | Bind::UniformSlice(_)
                | Bind::StorageSlice(_) => {
                    bi += 1;
                    w.buffer_info(std::slice::from_ref(&buffer_infos[bi - 1]))
                }
            };
        }
        let writes = &writes[..binds.len()];
        unsafe {
            self.ctx
                .push_descriptor
                .cmd_push_descriptor_set(cmd, bind_point, self.raw, 0, writes);
            if !push.is_empty() {
                self.ctx
                    .device
                    .cmd_push_constants(cmd, self.raw, self.stages, 0, push);
            }
        }
        Ok(())
    }
}

impl Drop for PipelineLayout {
    fn drop(&mut self) {
        // Deferred while a submission that may use it is in flight (gpu/lifetime.rs).
        let (raw, set_layout) = (self.raw, self.set_layout);
        self.ctx.retire(Box::new(move |ctx| unsafe {
            ctx.device.destroy_pipeline_layout(raw, None);
            ctx.device.destroy_descriptor_set_layout(set_layout, None);
        }));
    }
}

/// Map entries for 32-bit specialisation constants: `constants[i]` is `constant_id = i`.
pub(crate) fn specialization_entries(constants: &[u32]) -> Vec<vk::SpecializationMapEntry> {
    (0..constants.len() as u32)
        .map(|i| vk::SpecializationMapEntry {
            constant_id: i,
            offset: 4 * i,
            size: 4,
        })
        .collect()
}

/// Creates a shader module from the embedded SPIR-V of `shader`.
pub(crate) fn shader_module(ctx: &Context, shader: &str) -> Result<vk::ShaderModule> {
    let words = shaders::spirv(shader)?;
    let info = vk::ShaderModuleCreateInfo::default().code(&words);
    unsafe { ctx.device.create_shader_module(&info, None) }
        .vk(format!("creating shader module {shader}"))
}

/// A compute pipeline.
pub struct ComputePipeline {
    ctx: Arc<Context>,
    /// The pipeline.
    pub raw: vk::Pipeline,
    /// Its layout (set 0 and the push constants).
    pub layout: PipelineLayout,
    /// The name in messages and labels.
    pub name: String,
}

impl ComputePipeline {
    /// Builds the pipeline for `shader` (a path under glsl/).
    pub fn new(
        ctx: &Arc<Context>,
        shader: &str,
        bindings: &[BindingKind],
        push_constant_bytes: u32,
    ) -> Result<Self> {
        Self::with_constants(ctx, shader, bindings, push_constant_bytes, &[])
    }

    /// Builds the pipeline with specialisation constants: `constants[i]` is `constant_id = i`
    /// (32-bit int or bool each).
    pub fn with_constants(
        ctx: &Arc<Context>,
        shader: &str,
        bindings: &[BindingKind],
        push_constant_bytes: u32,
        constants: &[u32],
    ) -> Result<Self> {
        let layout = PipelineLayout::new(
            ctx,
            shader,
            bindings,
            push_constant_bytes,
            vk::ShaderStageFlags::COMPUTE,
        )?;
        let module = shader_module(ctx, shader)?;
        let entries = specialization_entries(constants);
        let spec = vk::SpecializationInfo::default()
            .map_entries(&entries)
            .data(bytemuck::cast_slice(constants));
        let mut stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module)
            .name(c"main");
        if !constants.is_empty() {
            stage = stage.specialization_info(&spec);
        }
        let info = [vk::ComputePipelineCreateInfo::default()
            .stage(stage)
            .layout(layout.raw)];
        let result = unsafe {
            ctx.device
                .create_compute_pipelines(vk::PipelineCache::null(), &info, None)
        };
        unsafe { ctx.device.destroy_shader_module(module, None) };
        let raw = result
            .map_err(|(_, r)| r)
            .vk(format!("creating compute pipeline {shader}"))?[0];
        ctx.set_name(raw, shader);
        Ok(ComputePipeline {
            ctx: ctx.clone(),
            raw,
            layout,
            name: shader.to_string(),
        })
    }

    /// Binds the pipeline, pushes `binds` and `push`, and dispatches `groups` workgroups.
    pub fn dispatch<P: bytemuck::Pod>(
        &self,
        cmd: vk::CommandBuffer,
        binds: &[Bind],
        push: &P,
        groups: [u32; 3],
    ) -> Result<()> {
        let limit = self.ctx.info.max_compute_work_group_count;
        if groups.iter().zip(limit).any(|(&g, l)| g > l) {
            return Err(Error::Pipeline {
                name: self.name.clone(),
                msg: format!("{groups:?} workgroups exceed the device limit {limit:?}"),
            });
        }
        self.bind(cmd, binds, push)?;
        unsafe {
            self.ctx
                .device
                .cmd_dispatch(cmd, groups[0], groups[1], groups[2])
        };
        Ok(())
    }
}

impl ComputePipeline {
    /// Binds the pipeline, pushes `binds` and `push`, and dispatches the workgroup counts stored
    /// at `offset` of `args` (a VkDispatchIndirectCommand written by an earlier pass).
    pub fn dispatch_indirect<P: bytemuck::Pod>(
        &self,
        cmd: vk::CommandBuffer,
        binds: &[Bind],
        push: &P,
        args: &crate::Buffer,
        offset: u64,
    ) -> Result<()> {
        self.bind(cmd, binds, push)?;
        unsafe { self.ctx.device.cmd_dispatch_indirect(cmd, args.raw, offset) };
        Ok(())
    }

    /// Binds the pipeline and pushes `binds` and `push`.
    fn bind<P: bytemuck::Pod>(
        &self,
        cmd: vk::CommandBuffer,
        binds: &[Bind],
        push: &P,
    ) -> Result<()> {
        unsafe {
            self.ctx
                .device
                .cmd_bind_pipeline(cmd, vk::PipelineBindPoint::COMPUTE, self.raw)
        };
        self.layout.push(
            cmd,
            vk::PipelineBindPoint::COMPUTE,
            &self.name,
            binds,
            bytemuck::bytes_of(push),
        )
    }
}

impl Drop for ComputePipeline {
    fn drop(&mut self) {
        let raw = self.raw;
        self.ctx.retire(Box::new(move |ctx| unsafe {
            ctx.device.destroy_pipeline(raw, None)
        }));
    }
}

/// Workgroups needed to cover `extent` with groups of `local` invocations.
pub fn group_count(extent: [u32; 3], local: [u32; 3]) -> [u32; 3] {
    [
        extent[0].div_ceil(local[0]),
        extent[1].div_ceil(local[1]),
        extent[2].div_ceil(local[2]),
    ]
}
