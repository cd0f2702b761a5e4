//! The render targets of a frame as named, persistent layers: `composite`, and for two-level
//! frames `focus.phong`, `focus.diffuse`, `focus.depth` (linear distance along the view direction),
//! its D32 twin used for depth testing, and `context`. They live across frames, are reallocated only
//! when the size changes (the old ones are released once the frames using them complete), and can
//! be sampled by passes recorded after the renderer's (edges, abstraction, lines).

use crate::error::{Error, Result};
use crate::gpu::transfer::{record_readback, staging_buffer};
use crate::gpu::{Buffer, Context, Image, ImageDesc};
use ash::vk;
use std::sync::Arc;

/// Colour layers: premultiplied RGBA in float.
pub const COLOR: vk::Format = vk::Format::R32G32B32A32_SFLOAT;
/// The linear focus depth.
pub const LINEAR_DEPTH: vk::Format = vk::Format::R32_SFLOAT;
/// The depth-test buffer of the focus.
pub const DEPTH: vk::Format = vk::Format::D32_SFLOAT;

/// Names of the layers, as in the EXR output and for [`FrameTargets::layer`].
pub const LAYER_NAMES: [&str; 5] = [
    "focus.phong",
    "focus.diffuse",
    "focus.depth",
    "context",
    "composite",
];

/// The two-level layers.
pub struct TargetLayers {
    pub focus_phong: Image,
    pub focus_diffuse: Image,
    /// Linear depth of the nearest focus sample (+inf where none).
    pub focus_depth: Image,
    pub context: Image,
    /// D32 depth of the nearest focus sample, tested by the context pass.
    pub depth: Image,
}

/// The images of one size.
pub struct TargetImages {
    pub size: [u32; 2],
    pub composite: Image,
    pub layers: Option<TargetLayers>,
    /// The style passes' images, from the first styled frame on.
    pub post: Option<crate::render::post::PostTargets>,
}

/// Persistent targets, resized on demand.
pub struct FrameTargets {
    ctx: Arc<Context>,
    images: Option<TargetImages>,
    two_level: bool,
}

fn target(ctx: &Arc<Context>, name: &str, format: vk::Format, [w, h]: [u32; 2]) -> Result<Image> {
    let usage = if format == DEPTH {
        vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT
    } else {
        vk::ImageUsageFlags::COLOR_ATTACHMENT
            | vk::ImageUsageFlags::SAMPLED
            | vk::ImageUsageFlags::STORAGE
            | vk::ImageUsageFlags::TRANSFER_SRC
    };
    Image::new(ctx, name, &ImageDesc::new_2d(format, [w, h]).usage(usage))
}

impl FrameTargets {
    /// No images until the first frame says what size it needs.
    pub fn new(ctx: &Arc<Context>) -> Self {
        FrameTargets {
            ctx: ctx.clone(),
            images: None,
            two_level: false,
        }
    }

    /// Makes sure the targets have `size`, with the two-level layers when `two_level` and the
    /// style passes' images when `styled`. Allocates only on a change of size or the first frame
    /// that needs more.
    pub fn ensure(
        &mut self,
        size: [u32; 2],
        two_level: bool,
        styled: bool,
    ) -> Result<&TargetImages> {
        let ctx = &self.ctx;
        if self.images.as_ref().is_none_or(|i| i.size != size) {
            self.images = Some(TargetImages {
                size,
                composite: target(ctx, "composite", COLOR, size)?,
                layers: None,
                post: None,
            });
        }
        let images = self.images.as_mut().expect("set above");
        if two_level && images.layers.is_none() {
            images.layers = Some(TargetLayers {
                focus_phong: target(ctx, "focus.phong", COLOR, size)?,
                focus_diffuse: target(ctx, "focus.diffuse", COLOR, size)?,
                focus_depth: target(ctx, "focus.depth", LINEAR_DEPTH, size)?,
                context: target(ctx, "context", COLOR, size)?,
                depth: target(ctx, "focus.depth.d32", DEPTH, size)?,
            });
        }
        if styled && images.post.is_none() {
            images.post = Some(crate::render::post::PostTargets::new(ctx, size)?);
        }
        self.two_level = two_level;
        Ok(images)
    }

    /// The images, once a frame has been recorded.
    pub fn images(&self) -> Option<&TargetImages> {
        self.images.as_ref()
    }

    /// Whether the last frame recorded was a two-level frame (its layers are current).
    pub fn two_level(&self) -> bool {
        self.two_level
    }

    /// A layer of the last frame by name ([`LAYER_NAMES`]); two-level layers only after a
    /// two-level frame.
    pub fn layer(&self, name: &str) -> Option<&Image> {
        let i = self.images.as_ref()?;
        if name == "composite" {
            return Some(&i.composite);
        }
        if name == "style.edges" {
            // The style's edge layer: image-space edges and object-space lines.
            return i.post.as_ref().map(|p| &p.edges);
        }
        let l = i.layers.as_ref().filter(|_| self.two_level)?;
        match name {
            "focus.phong" => Some(&l.focus_phong),
            "focus.diffuse" => Some(&l.focus_diffuse),
            "focus.depth" => Some(&l.focus_depth),
            "context" => Some(&l.context),
            _ => None,
        }
    }
}

/// Host buffers to read the layers of a frame into.
pub struct TargetsReadback {
    size: [u32; 2],
    composite: Buffer,
    /// focus.phong, focus.diffuse, focus.depth, context.
    layers: Option<[Buffer; 4]>,
}

impl TargetsReadback {
    /// Buffers for the current layers of `targets` (composite, plus the two-level layers after a
    /// two-level frame).
    pub fn new(ctx: &Arc<Context>, targets: &FrameTargets) -> Result<Self> {
        let images = targets
            .images()
            .ok_or_else(|| Error::Invalid("no frame has been recorded into the targets".into()))?;
        let buffer =
            |i: &Image| staging_buffer(ctx, &format!("{} readback", i.name), i.byte_size());
        let layers = match (&images.layers, targets.two_level()) {
            (Some(l), true) => Some([
                buffer(&l.focus_phong)?,
                buffer(&l.focus_diffuse)?,
                buffer(&l.focus_depth)?,
                buffer(&l.context)?,
            ]),
            _ => None,
        };
        Ok(TargetsReadback {
            size: images.size,
            composite: buffer(&images.composite)?,
            layers,
        })
    }

    /// Records the copies of the layers into the buffers.
    pub fn record(&self, cmd: vk::CommandBuffer, targets: &FrameTargets) {
        let Some(images) = targets.images() else {
            return;
        };
        let ctx = &targets.ctx;
        record_readback(ctx, cmd, &images.composite, &self.composite);
        if let (Some(b), Some(l)) = (&self.layers, &images.layers) {
            for (image, buffer) in [&l.focus_phong, &l.focus_diffuse, &l.focus_depth, &l.context]
                .into_iter()
                .zip(b)
            {
                record_readback(ctx, cmd, image, buffer);
            }
        }
    }

    /// The composite and the layers, once the frame that recorded the copies has completed.
    pub fn read(&self) -> Result<(Vec<[f32; 4]>, Option<crate::render::slicer::Layers>)> {
        let bytes = |b: &Buffer| -> Result<Vec<u8>> {
            b.mapped()
                .map(<[u8]>::to_vec)
                .ok_or_else(|| Error::Invalid("readback buffer is not host-visible".into()))
        };
        let rgba =
            |b: &Buffer| -> Result<Vec<[f32; 4]>> { Ok(bytemuck::pod_collect_to_vec(&bytes(b)?)) };
        let layers = match &self.layers {
            Some([phong, diffuse, depth, context]) => Some(crate::render::slicer::Layers {
                focus_phong: rgba(phong)?,
                focus_diffuse: rgba(diffuse)?,
                focus_depth: bytemuck::pod_collect_to_vec(&bytes(depth)?),
                context: rgba(context)?,
            }),
            None => None,
        };
        Ok((rgba(&self.composite)?, layers))
    }

    /// The size of the frame the buffers hold.
    pub fn size(&self) -> [u32; 2] {
        self.size
    }
}
