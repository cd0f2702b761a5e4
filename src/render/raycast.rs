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
use crate::render::slicer::SliceUniforms;
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
    /// equal world steps. The modes (two levels, world steps) are selected by the pipeline's
    /// [`Variant`]; the shader reads only y, z and bit 0 of w, each behind its variant bit.
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

/// Per texel i of a 256-texel transfer function, the larger opacity of texels i and i + 1: a
/// bound on every opacity linear filtering returns for intensities between their centres (and
/// below the first centre or above the last, where it clamps). The ray caster's walk tests samples
/// against it before classifying them.
pub fn opacity_bounds(table: &[[f32; 4]]) -> [f32; 256] {
    let mut out = [0.0f32; 256];
    let n = table.len();
    for (i, o) in out.iter_mut().enumerate() {
        let a = |j: usize| table.get(j.min(n.saturating_sub(1))).map_or(0.0, |t| t[3]);
        *o = a(i).max(a(i + 1));
    }
    out
}

/// The bits of `raycast.comp`'s specialisation constant `VARIANT` (`shade.glsl`).
///
/// A CPU rasteriser such as lavapipe runs both sides of every branch its SIMD lanes could diverge
/// on, and does not skip a block whose condition is a uniform that happens to be false: a frame
/// without occlusion TFs still paid for their two texture fetches at every sample. So the ray
/// caster is compiled per set-up, with what a frame does not use left out. Modes (two levels,
/// world steps) select code; the other bits enable code that still tests its uniform, so setting
/// one is never wrong, only slower.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct Variant(pub u32);

impl Variant {
    pub const TWO_LEVEL: u32 = 1;
    pub const SKIP_EMPTY: u32 = 2;
    pub const JITTER: u32 = 4;
    pub const REFINE_ISO: u32 = 8;
    pub const WORLD_STEPS: u32 = 16;
    pub const OTF: u32 = 32;
    pub const MOD_OPACITY: u32 = 64;
    pub const MOD_SHADE: u32 = 128;

    /// The variant for a frame with these options, level mode and uniforms.
    pub fn of(options: &RayOptions, two_level: bool, uniforms: &SliceUniforms) -> Self {
        let bits = [
            (two_level, Self::TWO_LEVEL),
            (options.skip_empty, Self::SKIP_EMPTY),
            (options.jitter.is_some(), Self::JITTER),
            (options.refine_iso && two_level, Self::REFINE_ISO),
            (options.sampling == Sampling::WorldSteps, Self::WORLD_STEPS),
            (uniforms.focus[3] > 0.5, Self::OTF),
            (uniforms.mod_flags[1] != 0, Self::MOD_OPACITY),
            (uniforms.mod_flags[3] != 0, Self::MOD_SHADE),
        ];
        Variant(bits.iter().filter(|(on, _)| *on).map(|(_, b)| b).sum())
    }
}

/// The ray caster's pipelines, one per variant, built when a frame first needs one and kept.
/// At most 256 exist; a session uses a handful.
#[derive(Default)]
pub struct RayPipelines {
    built: std::sync::Mutex<std::collections::HashMap<Variant, Arc<ComputePipeline>>>,
}

impl RayPipelines {
    /// The pipeline of `variant`, built on first use.
    pub fn get(&self, ctx: &Arc<Context>, variant: Variant) -> Result<Arc<ComputePipeline>> {
        let mut built = self
            .built
            .lock()
            .map_err(|_| Error::Invalid("the ray caster's pipeline cache was poisoned".into()))?;
        if let Some(p) = built.get(&variant) {
            return Ok(p.clone());
        }
        let p = Arc::new(ComputePipeline::with_constants(
            ctx,
            "render/raycast.comp",
            &RAY_BINDINGS,
            std::mem::size_of::<RayPush>() as u32,
            &[variant.0],
        )?);
        built.insert(variant, p.clone());
        Ok(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn push_constants_fit_the_guaranteed_minimum() {
        assert!(std::mem::size_of::<RayPush>() <= 128);
    }

    #[test]
    fn opacity_bounds_cover_linear_filtering() {
        // A ramp from texel 100 to 110 and one spike at 200.
        let table: Vec<[f32; 4]> = (0..256)
            .map(|i| {
                let a = match i {
                    100..=110 => (i - 99) as f32 / 11.0,
                    111..=199 => 1.0,
                    200 => 0.5,
                    _ => 0.0,
                };
                [1.0, 1.0, 1.0, a]
            })
            .collect();
        let b = opacity_bounds(&table);
        // Every value filtering can return between texel centres i and i + 1 is at most b[i].
        for i in 0..256usize {
            for k in 0..=8 {
                let w = k as f32 / 8.0;
                let j = (i + 1).min(255);
                let filtered = table[i][3] * (1.0 - w) + table[j][3] * w;
                assert!(filtered <= b[i], "texel {i}, weight {w}");
            }
        }
        assert_eq!(b[98], 0.0);
        assert_eq!(b[99], table[100][3]);
        assert_eq!(b[199], 1.0);
        assert_eq!(b[201], 0.0);
        assert_eq!(b[255], 0.0);
    }

    #[test]
    fn variants_follow_the_frame() {
        let mut u: SliceUniforms = bytemuck::Zeroable::zeroed();
        let o = RayOptions::default();
        assert_eq!(Variant::of(&o, false, &u).0, Variant::SKIP_EMPTY);
        u.focus[3] = 1.0;
        u.mod_flags = [1, 1, 0, 3];
        let o = RayOptions {
            jitter: Some(3),
            refine_iso: true,
            sampling: Sampling::WorldSteps,
            skip_empty: false,
            ..Default::default()
        };
        assert_eq!(Variant::of(&o, true, &u).0, 0xff & !Variant::SKIP_EMPTY);
        // Refinement only exists in two levels.
        assert_eq!(Variant::of(&o, false, &u).0 & Variant::REFINE_ISO, 0);
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
