//! RAII buffers, images and samplers. Each holds an `Arc<Context>` and frees its memory and handle
//! in `Drop`, so an early return on error never leaks.

use crate::barrier::{image_barrier, Access};
use crate::context::Context;
use crate::VkContext;
use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;
use std::cell::Cell;
use std::sync::Arc;
use vellum_error::{Error, Result};

/// Where a buffer lives and how the host reaches it.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(crate) enum BufferLocation {
    /// Device memory the host never maps.
    Gpu,
    /// Host-written staging or uniform data.
    Upload,
    /// Host-read results.
    Readback,
}

/// Description of a buffer to create.
#[derive(Clone, Debug)]
pub struct BufferDesc {
    /// Size in bytes.
    pub size: u64,
    /// What the buffer is used for.
    pub usage: vk::BufferUsageFlags,
    /// Device-local, or host-visible for uploads or readbacks.
    pub(crate) location: BufferLocation,
}

impl BufferDesc {
    /// A host-visible buffer that copies from.
    pub fn staging(size: u64) -> Self {
        BufferDesc {
            size,
            usage: vk::BufferUsageFlags::TRANSFER_SRC,
            location: BufferLocation::Upload,
        }
    }
    /// A host-visible buffer that copies land in.
    pub fn readback(size: u64) -> Self {
        BufferDesc {
            size,
            usage: vk::BufferUsageFlags::TRANSFER_DST,
            location: BufferLocation::Readback,
        }
    }
    /// A device-local storage buffer.
    pub fn storage(size: u64) -> Self {
        BufferDesc {
            size,
            usage: vk::BufferUsageFlags::STORAGE_BUFFER
                | vk::BufferUsageFlags::TRANSFER_SRC
                | vk::BufferUsageFlags::TRANSFER_DST,
            location: BufferLocation::Gpu,
        }
    }
    /// Adds use as the arguments of an indirect dispatch or draw.
    pub fn indirect(mut self) -> Self {
        self.usage |= vk::BufferUsageFlags::INDIRECT_BUFFER;
        self
    }

    /// Places the buffer in host-visible memory the host reads after the GPU has written it.
    pub fn host_read(mut self) -> Self {
        self.location = BufferLocation::Readback;
        self
    }

    /// A host-written uniform buffer.
    pub fn uniform(size: u64) -> Self {
        BufferDesc {
            size,
            usage: vk::BufferUsageFlags::UNIFORM_BUFFER,
            location: BufferLocation::Upload,
        }
    }
}

fn allocate(
    ctx: &Context,
    name: &str,
    requirements: vk::MemoryRequirements,
    location: MemoryLocation,
    linear: bool,
) -> Result<Allocation> {
    let a = ctx
        .allocator()
        .allocate(&AllocationCreateDesc {
            name,
            requirements,
            location,
            linear,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        })
        .map_err(|cause| Error::Alloc {
            what: name.to_string(),
            cause: cause.to_string(),
        })?;
    ctx.count_allocation(a.size());
    Ok(a)
}

fn free(ctx: &Context, allocation: Option<Allocation>) {
    if let Some(a) = allocation {
        ctx.count_free(a.size());
        if let Err(e) = ctx.allocator().free(a) {
            log::error!("freeing GPU memory failed: {e}");
        }
    }
}

/// A buffer with its memory.
pub struct Buffer {
    ctx: Arc<Context>,
    /// The buffer.
    pub raw: vk::Buffer,
    allocation: Option<Allocation>,
    /// Its size in bytes.
    pub size: u64,
    /// The name in messages, labels and the transfer counts.
    pub name: String,
}

impl Buffer {
    /// Creates and binds a buffer named `name`.
    pub fn new(ctx: &Arc<Context>, name: &str, desc: &BufferDesc) -> Result<Self> {
        let info = vk::BufferCreateInfo::default()
            .size(desc.size.max(4))
            .usage(desc.usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        let raw = unsafe { ctx.device.create_buffer(&info, None) }
            .vk(format!("creating buffer {name}"))?;
        let requirements = unsafe { ctx.device.get_buffer_memory_requirements(raw) };
        let location = match desc.location {
            BufferLocation::Gpu => MemoryLocation::GpuOnly,
            BufferLocation::Upload => MemoryLocation::CpuToGpu,
            BufferLocation::Readback => MemoryLocation::GpuToCpu,
        };
        let allocation = match allocate(ctx, name, requirements, location, true) {
            Ok(a) => a,
            Err(e) => {
                unsafe { ctx.device.destroy_buffer(raw, None) };
                return Err(e);
            }
        };
        // Construct the guard first so that a failed bind still frees both.
        let buffer = Buffer {
            ctx: ctx.clone(),
            raw,
            allocation: Some(allocation),
            size: desc.size,
            name: name.to_string(),
        };
        let a = buffer.allocation.as_ref().expect("just set");
        unsafe { ctx.device.bind_buffer_memory(raw, a.memory(), a.offset()) }
            .vk(format!("binding memory of buffer {name}"))?;
        ctx.set_name(raw, name);
        Ok(buffer)
    }

    /// A host-written buffer of `usage` holding `bytes` (uniforms, vertices, small tables).
    pub fn from_bytes(
        ctx: &Arc<Context>,
        name: &str,
        usage: vk::BufferUsageFlags,
        bytes: &[u8],
    ) -> Result<Self> {
        let mut b = Buffer::new(
            ctx,
            name,
            &BufferDesc {
                size: bytes.len().max(4) as u64,
                usage,
                location: BufferLocation::Upload,
            },
        )?;
        b.write(bytes)?;
        Ok(b)
    }

    /// A host-written storage buffer holding `bytes` (tables, kernels, weights that shaders
    /// read).
    pub fn storage_from_bytes(ctx: &Arc<Context>, name: &str, bytes: &[u8]) -> Result<Self> {
        Self::from_bytes(ctx, name, vk::BufferUsageFlags::STORAGE_BUFFER, bytes)
    }

    /// The mapped bytes of a host-visible buffer.
    pub fn mapped(&self) -> Option<&[u8]> {
        self.allocation
            .as_ref()
            .and_then(|a| a.mapped_slice())
            .map(|s| &s[..self.size as usize])
    }

    /// The mapped bytes of a host-visible buffer, writable.
    pub fn mapped_mut(&mut self) -> Option<&mut [u8]> {
        let size = self.size as usize;
        self.allocation
            .as_mut()
            .and_then(|a| a.mapped_slice_mut())
            .map(|s| &mut s[..size])
    }

    /// Copies `data` into a host-visible buffer.
    pub fn write(&mut self, data: &[u8]) -> Result<()> {
        let name = self.name.clone();
        let dst = self.mapped_mut().ok_or_else(|| Error::Pipeline {
            name,
            msg: "buffer is not host-visible".into(),
        })?;
        dst[..data.len()].copy_from_slice(data);
        Ok(())
    }
}

impl Drop for Buffer {
    fn drop(&mut self) {
        // Deferred while a submission that may use the buffer is in flight (gpu/lifetime.rs).
        let (raw, allocation) = (self.raw, self.allocation.take());
        self.ctx.retire(Box::new(move |ctx| {
            unsafe { ctx.device.destroy_buffer(raw, None) };
            free(ctx, allocation);
        }));
    }
}

/// A byte range of a buffer, by raw handle: what a frame's staging ring hands out. It is valid as
/// long as the buffer, which the ring keeps alive until the frame that used it has completed.
#[derive(Copy, Clone, Debug)]
pub struct BufferSlice {
    /// The buffer.
    pub raw: vk::Buffer,
    /// Where the slice starts, in bytes.
    pub offset: u64,
    /// Its size in bytes.
    pub size: u64,
}

impl Buffer {
    /// The whole buffer as a slice.
    pub(crate) fn slice(&self) -> BufferSlice {
        BufferSlice {
            raw: self.raw,
            offset: 0,
            size: self.size,
        }
    }
}

/// Description of an image to create (`ImageDesc::new_3d(format, extent)`).
#[derive(Clone, Debug)]
pub struct ImageDesc {
    /// The texel format.
    pub format: vk::Format,
    /// Texels along x, y, z (z is 1 for a 2D image).
    pub extent: [u32; 3],
    /// 2D or 3D.
    pub(crate) image_type: vk::ImageType,
    /// What the image is used for.
    pub usage: vk::ImageUsageFlags,
    /// A second view in this format of the same texels (`Image::alias_view`, bound with
    /// `Bind::StorageImageAlias`), e.g. R32_UINT over R32_SFLOAT for atomics; the image is then
    /// created with a mutable format.
    pub alias: Option<vk::Format>,
}

impl ImageDesc {
    /// A 3D image usable as storage, sampled and copy source/destination.
    pub fn new_3d(format: vk::Format, extent: [u32; 3]) -> Self {
        ImageDesc {
            format,
            extent,
            image_type: vk::ImageType::TYPE_3D,
            usage: vk::ImageUsageFlags::STORAGE
                | vk::ImageUsageFlags::SAMPLED
                | vk::ImageUsageFlags::TRANSFER_SRC
                | vk::ImageUsageFlags::TRANSFER_DST,
            alias: None,
        }
    }

    /// A 2D image; set `usage` for attachments.
    pub fn new_2d(format: vk::Format, extent: [u32; 2]) -> Self {
        ImageDesc {
            format,
            extent: [extent[0], extent[1], 1],
            image_type: vk::ImageType::TYPE_2D,
            usage: vk::ImageUsageFlags::SAMPLED
                | vk::ImageUsageFlags::TRANSFER_SRC
                | vk::ImageUsageFlags::TRANSFER_DST,
            alias: None,
        }
    }

    /// A 2D colour attachment that shaders also sample, write as storage and copy from (the
    /// render targets).
    pub fn color_target(format: vk::Format, extent: [u32; 2]) -> Self {
        Self::new_2d(format, extent).usage(
            vk::ImageUsageFlags::COLOR_ATTACHMENT
                | vk::ImageUsageFlags::SAMPLED
                | vk::ImageUsageFlags::STORAGE
                | vk::ImageUsageFlags::TRANSFER_SRC,
        )
    }

    /// A 2D depth attachment.
    pub fn depth_target(format: vk::Format, extent: [u32; 2]) -> Self {
        Self::new_2d(format, extent).usage(vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT)
    }

    /// A 2D image that compute shaders write and sample, copied to and from (image-space
    /// passes).
    pub fn storage_2d(format: vk::Format, extent: [u32; 2]) -> Self {
        Self::new_2d(format, extent).usage(
            vk::ImageUsageFlags::STORAGE
                | vk::ImageUsageFlags::SAMPLED
                | vk::ImageUsageFlags::TRANSFER_SRC
                | vk::ImageUsageFlags::TRANSFER_DST,
        )
    }

    /// Replaces the usage flags.
    pub fn usage(mut self, usage: vk::ImageUsageFlags) -> Self {
        self.usage = usage;
        self
    }

    /// Adds a second view in `format` (same texel size) beside the image's own.
    pub fn alias(mut self, format: vk::Format) -> Self {
        self.alias = Some(format);
        self
    }

    /// Whether the format is a depth format (changes the aspect).
    pub(crate) fn is_depth(&self) -> bool {
        matches!(
            self.format,
            vk::Format::D32_SFLOAT
                | vk::Format::D16_UNORM
                | vk::Format::D24_UNORM_S8_UINT
                | vk::Format::D32_SFLOAT_S8_UINT
        )
    }
}

/// Bytes per texel for the formats vellum uses.
pub(crate) fn format_size(format: vk::Format) -> usize {
    match format {
        vk::Format::R8_UNORM | vk::Format::R8_UINT | vk::Format::R8_SNORM | vk::Format::R8_SINT => {
            1
        }
        vk::Format::R16_UNORM
        | vk::Format::R16_UINT
        | vk::Format::R16_SINT
        | vk::Format::R16_SNORM
        | vk::Format::R16_SFLOAT => 2,
        vk::Format::R32_SFLOAT | vk::Format::R32_UINT | vk::Format::R32_SINT => 4,
        vk::Format::R16G16_UNORM => 4,
        vk::Format::D32_SFLOAT
        | vk::Format::B8G8R8A8_UNORM
        | vk::Format::R8G8B8A8_UNORM
        | vk::Format::R8G8B8A8_SRGB => 4,
        vk::Format::R16G16B16A16_SFLOAT | vk::Format::R16G16B16A16_UNORM => 8,
        vk::Format::R32G32B32A32_SFLOAT => 16,
        other => panic!("format_size: {other:?} is not used by vellum"),
    }
}

/// An image, its view and its memory. It remembers its last [`Access`] for barriers.
pub struct Image {
    ctx: Arc<Context>,
    /// The image.
    pub raw: vk::Image,
    /// Its view in its own format.
    pub view: vk::ImageView,
    /// The view in `desc.alias`'s format; null without one.
    pub(crate) alias_view: vk::ImageView,
    allocation: Option<Allocation>,
    /// What it was made from.
    pub desc: ImageDesc,
    /// The name in messages, labels and the transfer counts.
    pub name: String,
    access: Cell<Access>,
    /// The next transition may drop the contents (old layout UNDEFINED); it still waits for
    /// `access`.
    discarded: Cell<bool>,
}

/// How `desc`'s image is created (one mip level and layer, optimal tiling).
fn create_info(desc: &ImageDesc) -> vk::ImageCreateInfo<'static> {
    let [w, h, d] = desc.extent;
    vk::ImageCreateInfo::default()
        .image_type(desc.image_type)
        .format(desc.format)
        .extent(vk::Extent3D {
            width: w,
            height: h,
            depth: d,
        })
        .mip_levels(1)
        .array_layers(1)
        .samples(vk::SampleCountFlags::TYPE_1)
        .tiling(vk::ImageTiling::OPTIMAL)
        .usage(desc.usage)
        .sharing_mode(vk::SharingMode::EXCLUSIVE)
        .initial_layout(vk::ImageLayout::UNDEFINED)
        .flags(match desc.alias {
            Some(_) => vk::ImageCreateFlags::MUTABLE_FORMAT,
            None => vk::ImageCreateFlags::empty(),
        })
}

/// The bytes the device would allocate for an image of `desc`, asked without making one (Vulkan
/// 1.3's `vkGetDeviceImageMemoryRequirements`): its texels and the driver's padding.
pub fn image_memory_bytes(ctx: &Context, desc: &ImageDesc) -> u64 {
    let info = create_info(desc);
    let query = vk::DeviceImageMemoryRequirements::default().create_info(&info);
    let mut out = vk::MemoryRequirements2::default();
    unsafe {
        ctx.device
            .get_device_image_memory_requirements(&query, &mut out)
    };
    out.memory_requirements.size
}

impl Image {
    /// Creates an image with a view covering it, named `name`.
    pub fn new(ctx: &Arc<Context>, name: &str, desc: &ImageDesc) -> Result<Self> {
        let [w, h, d] = desc.extent;
        let info = create_info(desc);
        let raw = unsafe { ctx.device.create_image(&info, None) }.vk(format!(
            "creating image {name} ({w}x{h}x{d} {:?})",
            desc.format
        ))?;
        let requirements = unsafe { ctx.device.get_image_memory_requirements(raw) };
        let allocation = match allocate(ctx, name, requirements, MemoryLocation::GpuOnly, false) {
            Ok(a) => a,
            Err(e) => {
                unsafe { ctx.device.destroy_image(raw, None) };
                return Err(e);
            }
        };
        let mut image = Image {
            ctx: ctx.clone(),
            raw,
            view: vk::ImageView::null(),
            alias_view: vk::ImageView::null(),
            allocation: Some(allocation),
            desc: desc.clone(),
            name: name.to_string(),
            access: Cell::new(Access::Undefined),
            discarded: Cell::new(false),
        };
        let a = image.allocation.as_ref().expect("just set");
        unsafe { ctx.device.bind_image_memory(raw, a.memory(), a.offset()) }
            .vk(format!("binding memory of image {name}"))?;
        let view_type = if desc.image_type == vk::ImageType::TYPE_3D {
            vk::ImageViewType::TYPE_3D
        } else {
            vk::ImageViewType::TYPE_2D
        };
        let view_info = vk::ImageViewCreateInfo::default()
            .image(raw)
            .view_type(view_type)
            .format(desc.format)
            .subresource_range(vk::ImageSubresourceRange {
                aspect_mask: image.aspect(),
                base_mip_level: 0,
                level_count: 1,
                base_array_layer: 0,
                layer_count: 1,
            });
        image.view = unsafe { ctx.device.create_image_view(&view_info, None) }
            .vk(format!("creating the view of image {name}"))?;
        if let Some(format) = desc.alias {
            image.alias_view = unsafe {
                ctx.device
                    .create_image_view(&view_info.format(format), None)
            }
            .vk(format!("creating the {format:?} view of image {name}"))?;
            ctx.set_name(image.alias_view, name);
        }
        ctx.set_name(raw, name);
        ctx.set_name(image.view, name);
        Ok(image)
    }

    /// Colour or depth aspect.
    pub fn aspect(&self) -> vk::ImageAspectFlags {
        if self.desc.is_depth() {
            vk::ImageAspectFlags::DEPTH
        } else {
            vk::ImageAspectFlags::COLOR
        }
    }

    /// A number that names this image while it lives (its Vulkan handle), to tell whether a
    /// cached result was computed from it.
    pub fn id(&self) -> u64 {
        use vk::Handle;
        self.raw.as_raw()
    }

    /// Number of texels.
    pub(crate) fn texel_count(&self) -> usize {
        self.desc.extent.iter().map(|&e| e as usize).product()
    }

    /// Size in bytes of the texel data (tightly packed).
    pub fn byte_size(&self) -> usize {
        self.texel_count() * format_size(self.desc.format)
    }

    /// The access the image was last transitioned to.
    pub(crate) fn access(&self) -> Access {
        self.access.get()
    }

    /// Records a barrier into `cmd` from the last access to `next`, if one is needed.
    pub fn transition(&self, cmd: vk::CommandBuffer, next: Access) {
        if let Some(b) = image_barrier(
            self.raw,
            self.aspect(),
            self.access.get(),
            next,
            self.discarded.get(),
        ) {
            let barriers = [b];
            let dep = vk::DependencyInfo::default().image_memory_barriers(&barriers);
            unsafe { self.ctx.device.cmd_pipeline_barrier2(cmd, &dep) };
        }
        self.access.set(next);
        self.discarded.set(false);
    }

    /// Declares the image's contents undefined (the next transition may discard them).
    pub fn discard(&self) {
        self.discarded.set(true);
    }
}

impl Drop for Image {
    fn drop(&mut self) {
        // Deferred while a submission that may use the image is in flight (gpu/lifetime.rs).
        let (raw, views, allocation) = (
            self.raw,
            [self.view, self.alias_view],
            self.allocation.take(),
        );
        self.ctx.retire(Box::new(move |ctx| {
            unsafe {
                for view in views {
                    if view != vk::ImageView::null() {
                        ctx.device.destroy_image_view(view, None);
                    }
                }
                ctx.device.destroy_image(raw, None);
            }
            free(ctx, allocation);
        }));
    }
}

/// A sampler.
pub struct Sampler {
    ctx: Arc<Context>,
    /// The sampler.
    pub raw: vk::Sampler,
}

impl Sampler {
    /// Linear or nearest filtering, clamped to the edge.
    pub fn new(ctx: &Arc<Context>, linear: bool) -> Result<Self> {
        let filter = if linear {
            vk::Filter::LINEAR
        } else {
            vk::Filter::NEAREST
        };
        let info = vk::SamplerCreateInfo::default()
            .mag_filter(filter)
            .min_filter(filter)
            .mipmap_mode(vk::SamplerMipmapMode::NEAREST)
            .address_mode_u(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .address_mode_v(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .address_mode_w(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .max_lod(0.0);
        let raw = unsafe { ctx.device.create_sampler(&info, None) }.vk("creating a sampler")?;
        Ok(Sampler {
            ctx: ctx.clone(),
            raw,
        })
    }
}

impl Drop for Sampler {
    fn drop(&mut self) {
        // Deferred while a submission that may use it is in flight (gpu/lifetime.rs).
        let raw = self.raw;
        self.ctx.retire(Box::new(move |ctx| unsafe {
            ctx.device.destroy_sampler(raw, None)
        }));
    }
}
