//! The compute-shader ray caster (SPEC §6), beside the slicer: `glsl/render/raycast.comp`.
//!
//! It shares everything but the sampling loop with the slicer ([`crate::render::slicer`]): the
//! uniforms, the classification and shading code (`shade.glsl` with `RAYCAST` defined), the brick
//! ranges and the named layers, so styles, importance modulation, occlusion transfer functions and
//! feature maps work on it unchanged.
//!
//! ## Sampling
//! A ray samples where the slicer's view-aligned planes cross it: steps of `spacing` in depth
//! along the view direction (so `spacing / cos θ` along an off-axis ray), with the slicer's
//! opacity correction. At the same number of planes the two renderers therefore sample the same
//! points, which is what makes their images comparable pixel for pixel; the ray caster composites
//! front to back in registers, the slicer back to front in a float target.
//!
//! With `sampling: world-steps`, samples are instead one spacing apart along each ray from the box
//! entry, which is what the opacity correction assumes on every ray; images then differ from the
//! slicer's off the image centre (a test bounds by how much).
//!
//! ## Speed-ups that keep the image
//! - Empty-space skipping: bricks (16³ voxels with a one-voxel apron) that hold nothing visible
//!   under the current transfer function and focus are stepped over to the first plane behind
//!   them. Samples are never moved, so the image is the same as without skipping.
//! - Early ray termination once the accumulated opacity reaches `ert` (default 0.99): what is
//!   left behind can change a pixel by at most `1 − ert` of its value.
//!
//! ## Isosurfaces
//! With `refine_iso` and an isosurface focus, the first focus sample is moved onto the surface:
//! regula falsi between it and the previous plane's sample (which is below the isovalue). The
//! depth layer then holds the surface's depth to a small fraction of a voxel, and shading is taken
//! on the surface.
//!
//! ## Jitter
//! An optional per-pixel offset of the planes, in (−½, ½) of a spacing from a seeded hash, turns
//! the wood-grain rings that regular slicing leaves on opaque surfaces into fine noise. Off by
//! default, so that images match the slicer.

use crate::error::{Error, Result};
use crate::gpu::{BindingKind, ComputePipeline, Context};
use std::sync::Arc;

/// The ray caster's options.
#[derive(Copy, Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RayOptions {
    /// Seed of the per-pixel plane jitter; `None` for none.
    pub jitter: Option<u32>,
    /// Early ray termination: a ray stops once its opacity reaches this, in (0, 1].
    pub ert: f32,
    /// Step over bricks that hold nothing visible.
    pub skip_empty: bool,
    /// With an isosurface focus (`--iso`), refine the first hit between the plane in front of
    /// the surface and the one behind it (four steps of regula falsi on the trilinear intensity),
    /// for an exact depth and a surface without slicing rings. Off by default: it moves samples,
    /// so images no longer match the slicer's.
    pub refine_iso: bool,
    /// Where samples lie: on the slicer's planes (the default, images comparable with the
    /// slicer's), or at equal steps of the plane spacing along each ray.
    pub sampling: Sampling,
}

/// Where the ray caster samples.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Sampling {
    /// Where the slicer's view-aligned planes cross each ray: steps of the plane spacing in depth,
    /// so spacing / cos θ along an off-axis ray, with the slicer's opacity correction.
    #[default]
    Planes,
    /// Equal steps of the plane spacing along each ray, from the box entry: the opacity correction
    /// (spacing / voxel) then holds exactly on every ray, at the cost of sample positions that
    /// differ from the slicer's off the axis.
    WorldSteps,
}

impl Sampling {
    /// Parses `planes` or `world-steps`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "planes" => Ok(Sampling::Planes),
            "world-steps" => Ok(Sampling::WorldSteps),
            other => Err(Error::Invalid(format!(
                "sampling {other:?} is unknown; expected planes or world-steps"
            ))),
        }
    }
}

impl Default for RayOptions {
    fn default() -> Self {
        RayOptions {
            jitter: None,
            ert: 0.99,
            skip_empty: true,
            refine_iso: false,
            sampling: Sampling::Planes,
        }
    }
}

impl RayOptions {
    /// Checks the termination threshold.
    pub fn validate(&self) -> Result<()> {
        if self.ert > 0.0 && self.ert <= 1.0 {
            Ok(())
        } else {
            Err(Error::Invalid(format!(
                "early ray termination at opacity {} is invalid; expected a value in (0, 1] (1 keeps every sample that can still show)",
                self.ert
            )))
        }
    }
}

/// Push constants of `raycast.comp`.
#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct RayPush {
    /// Clip space to the box frame.
    pub inv_view_proj: [[f32; 4]; 4],
    /// Depth of the farthest plane's reference along the view direction, spacing, planes, ert.
    pub planes: [f32; 4],
    /// Brick counts along x, y, z, and the brick size in voxels.
    pub bricks: [i32; 4],
    /// Two levels, skip empty bricks, jitter seed (0 off), bit 0 refine isosurface hits | bit 1
    /// equal world steps.
    pub flags: [i32; 4],
}

/// Brick flag: may hold visible context (or one-pass) samples.
pub const BRICK_VISIBLE: u32 = 1;
/// Brick flag: may hold focus samples.
pub const BRICK_FOCUS: u32 = 2;

/// Bindings: the slicer's eight (`shade.glsl`), then the five layers as storage images and the
/// brick flags.
pub const RAY_BINDINGS: [BindingKind; 14] = {
    let slicer = crate::render::slicer::SLICE_BINDINGS;
    let mut all = [BindingKind::StorageImage; 14];
    let mut i = 0;
    while i < slicer.len() {
        all[i] = slicer[i];
        i += 1;
    }
    all[13] = BindingKind::StorageBuffer;
    all
};

/// Workgroup size of `raycast.comp`.
pub const LOCAL: [u32; 3] = [8, 8, 1];

/// Builds the ray caster's pipeline.
pub fn pipeline(ctx: &Arc<Context>) -> Result<ComputePipeline> {
    ComputePipeline::new(
        ctx,
        "render/raycast.comp",
        &RAY_BINDINGS,
        std::mem::size_of::<RayPush>() as u32,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn push_constants_fit_the_guaranteed_minimum() {
        assert!(std::mem::size_of::<RayPush>() <= 128);
    }

    #[test]
    fn termination_threshold_is_checked() {
        assert!(RayOptions::default().validate().is_ok());
        for bad in [0.0, -0.5, 1.5, f32::NAN] {
            let o = RayOptions {
                ert: bad,
                ..Default::default()
            };
            assert!(o.validate().is_err(), "{bad}");
        }
    }
}
