//! A window's surface and swapchain: creation from raw window handles, recreation on resize,
//! acquire and present, and the two layout transitions a frame needs around its drawing.
//!
//! Semaphores: one "acquired" per frame slot (reused only after the slot's fence has signalled,
//! see [`crate::Frames::next_slot`]) and one "rendered" per swapchain image (an image is
//! acquired again only after its previous presentation has consumed the semaphore).

use crate::Context;
use crate::VkContext;
use ash::vk;
use raw_window_handle::{RawDisplayHandle, RawWindowHandle};
use std::sync::Arc;
use vellum_error::{Error, Result};

/// A surface and its swapchain.
pub struct Swapchain {
    ctx: Arc<Context>,
    surface_fn: ash::khr::surface::Instance,
    surface: vk::SurfaceKHR,
    swapchain_fn: ash::khr::swapchain::Device,
    swapchain: vk::SwapchainKHR,
    /// Colour format of the images (8-bit UNORM where offered, so values equal the PNG's).
    pub format: vk::Format,
    /// Size in pixels.
    pub extent: [u32; 2],
    images: Vec<vk::Image>,
    views: Vec<vk::ImageView>,
    acquired: Vec<vk::Semaphore>,
    rendered: Vec<vk::Semaphore>,
    present_mode: vk::PresentModeKHR,
}

/// An acquired image: record into it, then [`Swapchain::present`] it.
#[derive(Copy, Clone, Debug)]
pub struct Acquired {
    /// The image's index in the swapchain.
    pub index: u32,
    /// The image.
    pub image: vk::Image,
    /// Its view.
    pub view: vk::ImageView,
    /// Signalled when the image may be written: the frame's submission waits on it.
    pub acquired: vk::Semaphore,
    /// The frame's submission signals it; presentation waits on it.
    pub rendered: vk::Semaphore,
}

impl Swapchain {
    /// Creates the surface of a window and a swapchain of `size` with one acquire semaphore per
    /// frame slot (`slots`). `vsync` chooses FIFO; otherwise MAILBOX or IMMEDIATE where offered.
    ///
    /// # Safety
    /// The window behind the handles must outlive the swapchain.
    pub unsafe fn new(
        ctx: &Arc<Context>,
        display: RawDisplayHandle,
        window: RawWindowHandle,
        size: [u32; 2],
        slots: usize,
        vsync: bool,
    ) -> Result<Self> {
        if !ctx.can_present() {
            return Err(Error::Invalid(
                "the device was created without VK_KHR_swapchain".into(),
            ));
        }
        let surface =
            unsafe { ash_window::create_surface(&ctx.entry, &ctx.instance, display, window, None) }
                .vk("creating the window's surface")?;
        let surface_fn = ash::khr::surface::Instance::new(&ctx.entry, &ctx.instance);
        let supported = unsafe {
            surface_fn.get_physical_device_surface_support(ctx.physical, ctx.queue_family, surface)
        };
        if !matches!(supported, Ok(true)) {
            unsafe { surface_fn.destroy_surface(surface, None) };
            return Err(Error::NoDevice(format!(
                "{} cannot present to this window from its graphics queue",
                ctx.info.name
            )));
        }
        let swapchain_fn = ash::khr::swapchain::Device::new(&ctx.instance, &ctx.device);
        let modes =
            unsafe { surface_fn.get_physical_device_surface_present_modes(ctx.physical, surface) }
                .unwrap_or_default();
        let present_mode = if vsync {
            vk::PresentModeKHR::FIFO
        } else {
            [vk::PresentModeKHR::MAILBOX, vk::PresentModeKHR::IMMEDIATE]
                .into_iter()
                .find(|m| modes.contains(m))
                .unwrap_or(vk::PresentModeKHR::FIFO)
        };
        let mut sc = Swapchain {
            ctx: ctx.clone(),
            surface_fn,
            surface,
            swapchain_fn,
            swapchain: vk::SwapchainKHR::null(),
            format: vk::Format::UNDEFINED,
            extent: [0, 0],
            images: Vec::new(),
            views: Vec::new(),
            acquired: Vec::new(),
            rendered: Vec::new(),
            present_mode,
        };
        for _ in 0..slots.max(1) {
            let s = unsafe {
                ctx.device
                    .create_semaphore(&vk::SemaphoreCreateInfo::default(), None)
            }
            .vk("creating an acquire semaphore")?;
            sc.acquired.push(s);
        }
        sc.recreate(size)?;
        Ok(sc)
    }

    /// Recreates the swapchain at `size` (clamped to what the surface allows). Waits for the
    /// device to go idle first: resizing is rare, and the old images may be in use.
    pub fn recreate(&mut self, size: [u32; 2]) -> Result<()> {
        let ctx = self.ctx.clone();
        unsafe { ctx.device.device_wait_idle() }.vk("waiting before resizing the swapchain")?;
        let caps = unsafe {
            self.surface_fn
                .get_physical_device_surface_capabilities(ctx.physical, self.surface)
        }
        .vk("reading the surface's capabilities")?;
        let formats = unsafe {
            self.surface_fn
                .get_physical_device_surface_formats(ctx.physical, self.surface)
        }
        .vk("listing the surface's formats")?;
        let chosen = formats
            .iter()
            .find(|f| {
                matches!(
                    f.format,
                    vk::Format::B8G8R8A8_UNORM | vk::Format::R8G8B8A8_UNORM
                ) && f.color_space == vk::ColorSpaceKHR::SRGB_NONLINEAR
            })
            .or(formats.first())
            .copied()
            .ok_or_else(|| Error::NoDevice("the window's surface offers no format".into()))?;
        let extent = if caps.current_extent.width != u32::MAX {
            caps.current_extent
        } else {
            vk::Extent2D {
                width: size[0].clamp(caps.min_image_extent.width, caps.max_image_extent.width),
                height: size[1].clamp(caps.min_image_extent.height, caps.max_image_extent.height),
            }
        };
        let mut count = caps.min_image_count + 1;
        if caps.max_image_count > 0 {
            count = count.min(caps.max_image_count);
        }
        let old = self.swapchain;
        let info = vk::SwapchainCreateInfoKHR::default()
            .surface(self.surface)
            .min_image_count(count)
            .image_format(chosen.format)
            .image_color_space(chosen.color_space)
            .image_extent(extent)
            .image_array_layers(1)
            .image_usage(vk::ImageUsageFlags::COLOR_ATTACHMENT)
            .image_sharing_mode(vk::SharingMode::EXCLUSIVE)
            .pre_transform(caps.current_transform)
            .composite_alpha(vk::CompositeAlphaFlagsKHR::OPAQUE)
            .present_mode(self.present_mode)
            .clipped(true)
            .old_swapchain(old);
        let swapchain = unsafe { self.swapchain_fn.create_swapchain(&info, None) }
            .vk("creating the swapchain")?;
        self.destroy_images();
        if old != vk::SwapchainKHR::null() {
            unsafe { self.swapchain_fn.destroy_swapchain(old, None) };
        }
        self.swapchain = swapchain;
        self.format = chosen.format;
        self.extent = [extent.width, extent.height];
        self.images = unsafe { self.swapchain_fn.get_swapchain_images(swapchain) }
            .vk("listing the swapchain's images")?;
        for (i, &image) in self.images.iter().enumerate() {
            let view_info = vk::ImageViewCreateInfo::default()
                .image(image)
                .view_type(vk::ImageViewType::TYPE_2D)
                .format(chosen.format)
                .subresource_range(color_range());
            let view = unsafe { ctx.device.create_image_view(&view_info, None) }
                .vk("creating a swapchain image view")?;
            self.views.push(view);
            let s = unsafe {
                ctx.device
                    .create_semaphore(&vk::SemaphoreCreateInfo::default(), None)
            }
            .vk("creating a present semaphore")?;
            self.rendered.push(s);
            ctx.set_name(image, &format!("swapchain image {i}"));
        }
        Ok(())
    }

    fn destroy_images(&mut self) {
        let d = &self.ctx.device;
        for v in self.views.drain(..) {
            unsafe { d.destroy_image_view(v, None) };
        }
        for s in self.rendered.drain(..) {
            unsafe { d.destroy_semaphore(s, None) };
        }
        self.images.clear();
    }

    /// Acquires the next image for frame slot `slot`. `None` means the swapchain no longer
    /// matches the window: recreate it and try again.
    pub fn acquire(&mut self, slot: usize) -> Result<Option<Acquired>> {
        let sem = self.acquired[slot % self.acquired.len()];
        match unsafe {
            self.swapchain_fn
                .acquire_next_image(self.swapchain, u64::MAX, sem, vk::Fence::null())
        } {
            Ok((index, _suboptimal)) => Ok(Some(Acquired {
                index,
                image: self.images[index as usize],
                view: self.views[index as usize],
                acquired: sem,
                rendered: self.rendered[index as usize],
            })),
            Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => Ok(None),
            Err(e) => Err(e).vk("acquiring a swapchain image"),
        }
    }

    /// Presents an image whose frame has been submitted. Returns false when the swapchain should
    /// be recreated (out of date or suboptimal).
    pub fn present(&mut self, image: &Acquired) -> Result<bool> {
        let waits = [image.rendered];
        let swapchains = [self.swapchain];
        let indices = [image.index];
        let info = vk::PresentInfoKHR::default()
            .wait_semaphores(&waits)
            .swapchains(&swapchains)
            .image_indices(&indices);
        let queue = self.ctx.queue();
        match unsafe { self.swapchain_fn.queue_present(*queue, &info) } {
            Ok(false) => Ok(true),
            Ok(true) | Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => Ok(false),
            Err(e) => Err(e).vk("presenting a swapchain image"),
        }
    }

    /// Records the transition of an acquired image to a colour attachment (its old contents are
    /// dropped). The submission waits on `acquired` at the colour-output stage, which this
    /// barrier's source stage chains with.
    pub fn record_begin(&self, cmd: vk::CommandBuffer, image: &Acquired) {
        let b = vk::ImageMemoryBarrier2::default()
            .src_stage_mask(vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT)
            .src_access_mask(vk::AccessFlags2::NONE)
            .dst_stage_mask(vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT)
            .dst_access_mask(
                vk::AccessFlags2::COLOR_ATTACHMENT_WRITE | vk::AccessFlags2::COLOR_ATTACHMENT_READ,
            )
            .old_layout(vk::ImageLayout::UNDEFINED)
            .new_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
            .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .image(image.image)
            .subresource_range(color_range());
        self.barrier(cmd, b);
    }

    /// Records the transition of a drawn image to presentation.
    pub fn record_end(&self, cmd: vk::CommandBuffer, image: &Acquired) {
        let b = vk::ImageMemoryBarrier2::default()
            .src_stage_mask(vk::PipelineStageFlags2::COLOR_ATTACHMENT_OUTPUT)
            .src_access_mask(vk::AccessFlags2::COLOR_ATTACHMENT_WRITE)
            .dst_stage_mask(vk::PipelineStageFlags2::NONE)
            .dst_access_mask(vk::AccessFlags2::NONE)
            .old_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
            .new_layout(vk::ImageLayout::PRESENT_SRC_KHR)
            .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .image(image.image)
            .subresource_range(color_range());
        self.barrier(cmd, b);
    }

    fn barrier(&self, cmd: vk::CommandBuffer, b: vk::ImageMemoryBarrier2) {
        let barriers = [b];
        let dep = vk::DependencyInfo::default().image_memory_barriers(&barriers);
        unsafe { self.ctx.device.cmd_pipeline_barrier2(cmd, &dep) };
    }
}

fn color_range() -> vk::ImageSubresourceRange {
    vk::ImageSubresourceRange {
        aspect_mask: vk::ImageAspectFlags::COLOR,
        base_mip_level: 0,
        level_count: 1,
        base_array_layer: 0,
        layer_count: 1,
    }
}

impl Drop for Swapchain {
    fn drop(&mut self) {
        unsafe {
            let _ = self.ctx.device.device_wait_idle();
        }
        self.destroy_images();
        unsafe {
            for s in self.acquired.drain(..) {
                self.ctx.device.destroy_semaphore(s, None);
            }
            if self.swapchain != vk::SwapchainKHR::null() {
                self.swapchain_fn.destroy_swapchain(self.swapchain, None);
            }
            self.surface_fn.destroy_surface(self.surface, None);
        }
    }
}

/// What a context must be created with to present to windows on `display`: the instance
/// extensions of its surface, and the swapchain extension.
pub fn presentation(
    display: raw_window_handle::RawDisplayHandle,
) -> Result<crate::context::Presentation> {
    let exts = ash_window::enumerate_required_extensions(display)
        .map_err(|e| Error::Invalid(format!("no Vulkan surface for this display: {e}")))?;
    Ok(crate::context::Presentation {
        instance_extensions: exts
            .iter()
            // SAFETY: ash-window returns pointers to static NUL-terminated extension names.
            .map(|&p| unsafe { std::ffi::CStr::from_ptr(p) })
            .collect(),
        swapchain: true,
    })
}
