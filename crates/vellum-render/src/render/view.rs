//! What a frame looks at and how: the [`View`] (camera, size, planes, levels, lighting, style,
//! renderer), the ray caster's [`RayOptions`], and the geometry every renderer derives from it
//! once per frame: the volume's [`WorldBox`] and the `FrameCamera`. Plain CPU data; no Vulkan.
//!
//! ## Spaces
//! World space is LPS millimetres scaled so that the box's longest edge is 1, centred at the
//! origin, for a volume whose orientation is known; otherwise the box's own axes. The box frame is
//! the volume's index axes at the same scale. The box is turned into world space by the volume's
//! direction matrix R about its centre, so box-frame quantities are R^T applied to world ones and
//! box → clip is VP · R.

use crate::render::camera::Camera;
use crate::render::style::Style;
use glam::{Mat3, Mat4, Vec3};
use vellum_error::{Error, Result};
use vellum_volume::geometry::Geometry;

/// Phong lighting with a headlight (the light comes from the eye).
#[derive(Copy, Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Lighting {
    /// Ambient coefficient k_a, at least 0.
    pub ambient: f32,
    /// Diffuse coefficient k_d, at least 0.
    pub diffuse: f32,
    /// Specular coefficient k_s, at least 0.
    pub specular: f32,
    /// Specular exponent.
    pub shininess: f32,
}

impl Default for Lighting {
    fn default() -> Self {
        Lighting {
            ambient: 0.25,
            diffuse: 0.75,
            specular: 0.35,
            shininess: 24.0,
        }
    }
}

impl Lighting {
    /// Checks that the coefficients are finite and not negative.
    pub fn validate(&self) -> Result<()> {
        let all = [self.ambient, self.diffuse, self.specular, self.shininess];
        if all.iter().all(|c| c.is_finite() && *c >= 0.0) {
            Ok(())
        } else {
            Err(Error::Invalid(format!(
                "lighting {self:?} is invalid; expected finite coefficients >= 0"
            )))
        }
    }
}

/// What a frame looks at and how: everything but the volume and its classification.
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    /// The camera around the volume's box (its distance replaced when `fit`).
    pub camera: Camera,
    /// The image size in pixels, width and height.
    pub size: [u32; 2],
    /// Number of slice planes; `None` picks about two per voxel along the longest axis.
    pub slices: Option<u32>,
    /// Draw one level, all context, instead of the two levels (focus and context) and their layers.
    pub one_pass: bool,
    /// The Phong headlight's coefficients.
    pub lighting: Lighting,
    /// A perceptual style (two-level frames only), recorded after the levels.
    pub style: Option<Style>,
    /// Frame the volume's projected bounding box (replacing the camera's distance).
    pub fit: bool,
    /// Ray cast instead of slicing (same planes, same layers; see `render::raycast`).
    pub raycast: Option<RayOptions>,
}

/// Margin left around a fitted volume, as a fraction of the image's half-size.
pub(crate) const FIT_MARGIN: f32 = 0.05;

/// Most slice planes a frame may draw.
pub(crate) const MAX_SLICES: u32 = 16384;

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
    /// With an isosurface focus (`iso`), refine the first hit between the plane in front of the
    /// surface and the one behind it (four steps of regula falsi on the trilinear intensity), for
    /// an exact depth and a surface without slicing rings. Off by default: it moves samples, so
    /// images no longer match the slicer's.
    pub refine_iso: bool,
    /// Where samples lie: on the slicer's planes (the default, images comparable with the
    /// slicer's), or at equal steps of the plane spacing along each ray.
    pub sampling: Sampling,
    /// Sample only inside this box of texture coordinates, `[lo, hi)` (one rank's region of an
    /// MPI job; a bound at or past the volume's edge is open). Not part of a scene file.
    #[serde(skip)]
    pub region: Option<[[f32; 3]; 2]>,
    /// Whether rays in core walk four samples at a time to their next contributing sample
    /// (`render::raycast::walk_batch`); `None` takes the device's default. The image is the same
    /// either way. Not part of a scene file.
    #[serde(skip)]
    pub walk_batch: Option<bool>,
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
            region: None,
            walk_batch: None,
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

/// The volume's box in world units: physical size scaled so that its longest edge is 1, centred
/// at the origin, and turned into world space by `rot`.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct WorldBox {
    /// Half extents along the box's axes.
    pub half: Vec3,
    /// Box axes → world (LPS for an oriented volume; identity otherwise).
    pub(crate) rot: Mat3,
    /// The longest physical edge in millimetres (what one world unit is).
    pub(crate) longest: f64,
    /// The smallest voxel spacing in world units.
    pub voxel: f64,
}

impl WorldBox {
    /// The box of a volume of `dims` voxels spaced `spacing` millimetres apart, oriented by
    /// `geometry`.
    pub fn new(dims: [usize; 3], spacing: [f64; 3], geometry: &Geometry) -> Self {
        let physical: [f64; 3] = std::array::from_fn(|a| dims[a] as f64 * spacing[a]);
        let longest = physical.iter().copied().fold(0.0, f64::max);
        let half = Vec3::from_array(physical.map(|p| (0.5 * p / longest) as f32));
        let rot = match geometry.is_oriented() {
            true => Mat3::from_cols_array_2d(&geometry.direction.map(|r| r.map(|v| v as f32)))
                .transpose(),
            false => Mat3::IDENTITY,
        };
        let voxel = spacing.iter().copied().fold(f64::INFINITY, f64::min) / longest;
        WorldBox {
            half,
            rot,
            longest,
            voxel,
        }
    }

    /// The box of a volume on the GPU.
    pub fn of<'v>(vol: impl Into<crate::passes::gpu_volume::VolumeRef<'v>>) -> Self {
        let vol = vol.into();
        WorldBox::new(vol.dims(), vol.spacing(), &vol.geometry())
    }

    /// The radius of the bounding sphere, the camera's unit of distance.
    pub fn radius(&self) -> f32 {
        self.half.length()
    }

    /// The eight corners in world space.
    pub fn corners(&self) -> [Vec3; 8] {
        std::array::from_fn(|i| {
            let sign = |k: usize| if (i >> k) & 1 == 1 { 1.0 } else { -1.0 };
            self.rot
                * Vec3::new(
                    sign(0) * self.half.x,
                    sign(1) * self.half.y,
                    sign(2) * self.half.z,
                )
        })
    }
}

/// The camera a frame of a volume with box `bx` seen by `view` uses: `view.camera`, with its
/// distance fitted to the projected box when `view.fit` (the viewer turns a fitted distance into
/// an explicit one before zooming).
pub fn frame_camera(bx: &WorldBox, view: &View) -> Camera {
    let mut cam = view.camera;
    if view.fit {
        let aspect = view.size[0].max(1) as f32 / view.size[1].max(1) as f32;
        cam.distance = cam.fit_distance(&bx.corners(), bx.radius(), aspect, FIT_MARGIN);
    }
    cam
}

/// The camera of one frame, computed once: the fitted [`Camera`] and what the passes need of it
/// in the box frame.
#[derive(Copy, Clone, Debug)]
pub(crate) struct FrameCamera {
    /// The view's camera, its distance fitted to the box when `View::fit`.
    pub camera: Camera,
    /// The view direction in the box frame (unit length).
    pub view_dir: Vec3,
    /// The eye in the box frame (for an orthographic camera, a point on the axis behind the box).
    pub eye: Vec3,
    /// Box frame → clip space.
    pub view_proj: Mat4,
}

impl FrameCamera {
    /// The camera of `view` around `bx`.
    pub fn new(bx: &WorldBox, view: &View) -> Self {
        let camera = frame_camera(bx, view);
        let radius = bx.radius();
        let [w, h] = view.size;
        let aspect = w as f32 / h as f32;
        FrameCamera {
            camera,
            view_dir: bx.rot.transpose() * camera.view_dir(radius),
            eye: bx.rot.transpose() * camera.eye(radius),
            view_proj: camera.view_proj(aspect, radius) * Mat4::from_mat3(bx.rot),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(fit: bool) -> View {
        View {
            camera: Camera::default(),
            size: [200, 100],
            slices: None,
            one_pass: false,
            lighting: Lighting::default(),
            style: None,
            fit,
            raycast: None,
        }
    }

    #[test]
    fn the_box_has_a_unit_longest_edge() {
        let g = Geometry::default();
        let bx = WorldBox::new([100, 50, 20], [1.0, 1.0, 2.5], &g);
        assert_eq!(bx.half, Vec3::new(0.5, 0.25, 0.25));
        assert!((bx.voxel - 0.01).abs() < 1e-12);
        assert_eq!(bx.longest, 100.0);
        assert_eq!(bx.rot, Mat3::IDENTITY);
    }

    #[test]
    fn a_fitted_camera_keeps_every_corner_in_the_image() {
        let bx = WorldBox::new([64, 64, 32], [1.0; 3], &Geometry::default());
        let v = view(true);
        let cam = FrameCamera::new(&bx, &v);
        assert_ne!(cam.camera.distance, v.camera.distance);
        for c in bx.corners() {
            let p = cam.view_proj * bx.rot.transpose().mul_vec3(c).extend(1.0);
            let ndc = p.truncate() / p.w;
            assert!(ndc.x.abs() <= 1.0 && ndc.y.abs() <= 1.0, "{ndc}");
        }
        // Without fitting, the camera is the view's.
        assert_eq!(FrameCamera::new(&bx, &view(false)).camera, v.camera);
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
