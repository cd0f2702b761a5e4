//! The classification of a scene on the GPU: the focus, the importance modulation, and the
//! persistent textures of the 1D transfer function (256×1) and the occlusion transfer function
//! (256×256 over intensity × occlusion). The textures are created once and re-uploaded through
//! the frame's staging ring only when their contents change, so a frame after a
//! transfer-function edit uploads 4 KiB and nothing else. Focus and modulation are uniforms,
//! written every frame.

use crate::classify::modulation::Modulation;
use crate::classify::transfer::TransferFunction;
use crate::classify::Focus;
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::transfer::record_upload_from;
use vellum_gpu::Format;
use vellum_gpu::{Access, Context, Frame, Image, ImageDesc};

pub(crate) use crate::classify::transfer::TF_SIZE;
/// Entries along each axis of the occlusion transfer-function table.
pub(crate) const OTF_SIZE: usize = crate::classify::otf::TABLE_SIZE;

// RGBA32F: the tables' float RGBA as computed on the host; 8 bits would flatten low opacities.
const FORMAT: Format = Format::R32G32B32A32_SFLOAT;

/// A table and the image it is uploaded to.
struct Table {
    image: Image,
    texels: Vec<[f32; 4]>,
    dirty: bool,
}

impl Table {
    fn new(
        ctx: &Arc<Context>,
        name: &str,
        extent: [u32; 2],
        texels: Vec<[f32; 4]>,
    ) -> Result<Self> {
        Ok(Table {
            image: Image::new(ctx, name, &ImageDesc::new_2d(FORMAT, extent))?,
            texels,
            dirty: true,
        })
    }

    fn set(&mut self, texels: Vec<[f32; 4]>) {
        if texels != self.texels {
            self.texels = texels;
            self.dirty = true;
        }
    }

    fn record(&mut self, frame: &mut Frame, ctx: &Context, next: Access) -> Result<()> {
        if self.dirty {
            let src = frame.staging.push(bytemuck::cast_slice(&self.texels), 16)?;
            record_upload_from(ctx, frame.cmd, src, &self.image, next);
            self.dirty = false;
        } else {
            self.image.transition(frame.cmd, next);
        }
        Ok(())
    }
}

/// The classification of a scene: focus, modulation and the transfer-function textures.
pub struct GpuClassification {
    ctx: Arc<Context>,
    /// What the first level of a two-level frame renders.
    pub focus: Focus,
    /// Importance modulation; its ΔD volume must be attached to the volume textures when active.
    pub modulation: Modulation,
    transfer: Table,
    /// The occlusion TF table, or a 1×1 stand-in while none is used (shaders bind something).
    occlusion: Table,
    uses_occlusion: bool,
    /// Segments from a label volume beside the input, which the ray caster colours, hides and
    /// puts in the focus level by id (`classify::labels`).
    pub labels: Option<crate::classify::labels::GpuLabels>,
    /// Channels of a store mixed in one ray by the ray caster (`classify::channels`).
    pub channels: Option<crate::classify::channels::GpuChannels>,
}

impl GpuClassification {
    /// Creates the textures for `tf` with `focus`, no occlusion transfer function and no
    /// modulation.
    pub fn new(ctx: &Arc<Context>, tf: &TransferFunction, focus: Focus) -> Result<Self> {
        Ok(GpuClassification {
            ctx: ctx.clone(),
            focus,
            modulation: Modulation::default(),
            transfer: Table::new(
                ctx,
                "transfer function",
                [TF_SIZE as u32, 1],
                tf.table(TF_SIZE),
            )?,
            occlusion: Table::new(ctx, "occlusion transfer function", [1, 1], vec![[0.0; 4]])?,
            uses_occlusion: false,
            labels: None,
            channels: None,
        })
    }

    /// Sets the 1D transfer function; the texture is re-uploaded only if its table changed.
    pub fn set_transfer(&mut self, tf: &TransferFunction) {
        self.transfer.set(tf.table(TF_SIZE));
    }

    /// Sets (or clears) the occlusion transfer-function table, `table[o * 256 + s]`, which then
    /// replaces the 1D function in the shaders.
    pub fn set_occlusion_table(&mut self, table: Option<Vec<[f32; 4]>>) -> Result<()> {
        match table {
            None => self.uses_occlusion = false,
            Some(t) => {
                if t.len() != OTF_SIZE * OTF_SIZE {
                    return Err(Error::Invalid(format!(
                        "an occlusion transfer-function table needs {OTF_SIZE}×{OTF_SIZE} entries, not {}",
                        t.len()
                    )));
                }
                if self.occlusion.image.desc.extent[0] as usize != OTF_SIZE {
                    // First use: the full-size texture replaces the stand-in (created once).
                    self.occlusion = Table::new(
                        &self.ctx,
                        "occlusion transfer function",
                        [OTF_SIZE as u32; 2],
                        t,
                    )?;
                } else {
                    self.occlusion.set(t);
                }
                self.uses_occlusion = true;
            }
        }
        Ok(())
    }

    /// The 1D table as uploaded (for empty-space decisions on the CPU).
    pub(crate) fn transfer_table(&self) -> &[[f32; 4]] {
        &self.transfer.texels
    }

    /// Whether the occlusion transfer function replaces the 1D one.
    pub(crate) fn uses_occlusion(&self) -> bool {
        self.uses_occlusion
    }

    /// Records the uploads of changed tables and leaves both textures readable by `next`
    /// (fragment or compute sampling).
    pub fn record(&mut self, frame: &mut Frame, next: Access) -> Result<()> {
        let ctx = self.ctx.clone();
        self.transfer.record(frame, &ctx, next)?;
        if let Some(labels) = self.labels.as_mut() {
            labels.record(frame, Access::ComputeRead)?;
        }
        if let Some(channels) = self.channels.as_mut() {
            channels.record(frame)?;
        }
        self.occlusion.record(frame, &ctx, next)
    }

    /// The 1D transfer-function texture.
    pub(crate) fn transfer_image(&self) -> &Image {
        &self.transfer.image
    }

    /// The occlusion transfer-function texture (a stand-in when none is set).
    pub(crate) fn occlusion_image(&self) -> &Image {
        &self.occlusion.image
    }
}
