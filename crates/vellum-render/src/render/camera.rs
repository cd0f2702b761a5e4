//! An orbit camera around the volume, in Vulkan's clip-space conventions.
//!
//! The scene is the volume box centred at the origin in world units (millimetres, voxel spacing
//! applied); `radius` is the box's bounding-sphere radius. Distances and pan are multiples of that
//! radius so one camera spec frames any volume the same way.
//!
//! ## Axes
//! Volume +z is "up" (the slice axis of medical scans). The eye sits on a sphere around the target:
//! `eye - target = distance·radius · (sin(az)·cos(el), −cos(az)·cos(el), sin(el))`.
//! - azimuth 0, elevation 0: the eye is on −y looking towards +y, with +z up and +x to the right
//!   (a frontal view of a head whose face points to −y);
//! - positive azimuth turns the eye counter-clockwise about +z as seen from above (azimuth 90 puts
//!   the eye on +x);
//! - positive elevation lifts the eye towards +z (elevation 90 looks straight down).
//!
//! ## Clip space
//! Right-handed view space, depth range [0, 1] (near → 0), and clip-space y pointing down, as
//! Vulkan rasterises: a world point above the target (+z) lands at negative NDC y, the top of the image.

use glam::{Mat4, Vec2, Vec3, Vec4};
use vellum_error::{Error, Result};

/// An orbit camera. Angles in degrees; `distance` and `pan` in multiples of the bounding-sphere radius.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Rotation of the eye about +z, degrees; 0 looks from −y towards +y.
    pub azimuth_deg: f32,
    /// Tilt of the eye towards +z, degrees, in [−90, 90].
    pub elevation_deg: f32,
    /// Eye-to-target distance in bounding-sphere radii; default 2.5. Must exceed 1 in perspective.
    pub distance: f32,
    /// Orthographic instead of perspective projection.
    pub ortho: bool,
    /// Vertical field of view in degrees; in orthographic mode it sets the framing (see `Camera::projection`).
    pub fov_y_deg: f32,
    /// Shift of eye and target in the image plane (x right, y up), in bounding-sphere radii.
    pub pan: Vec2,
}

impl Default for Camera {
    fn default() -> Self {
        Camera {
            azimuth_deg: 0.0,
            elevation_deg: 0.0,
            distance: 2.5,
            ortho: false,
            fov_y_deg: 50.0,
            pan: Vec2::ZERO,
        }
    }
}

/// Margin, in radii, added around the bounding sphere when choosing near and far planes, so the
/// proxy polygons at the sphere's extremes are never clipped by rounding.
const DEPTH_MARGIN: f32 = 0.01;

impl Camera {
    /// Parses `AZ,EL[,DIST]` (degrees, degrees, radii), e.g. `30,20,2.5`; other fields keep their
    /// defaults. The distance must be finite and greater than 1 (the eye outside the bounding sphere).
    pub fn parse(s: &str) -> Result<Camera> {
        let bad = |why: &str| {
            Error::Invalid(format!(
                "camera {s:?}: {why}; expected AZ,EL[,DIST] in degrees, degrees and bounding-sphere radii (e.g. 30,20,2.5)"
            ))
        };
        let fields: Vec<&str> = s.split(',').map(str::trim).collect();
        if !(2..=3).contains(&fields.len()) {
            return Err(bad(&format!("{} fields", fields.len())));
        }
        let num = |name: &str, f: &str| -> Result<f32> {
            match f.parse::<f32>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => Err(bad(&format!("{name} {f:?} is not a finite number"))),
            }
        };
        let mut camera = Camera {
            azimuth_deg: num("azimuth", fields[0])?,
            elevation_deg: num("elevation", fields[1])?,
            ..Camera::default()
        };
        if let Some(d) = fields.get(2) {
            camera.distance = num("distance", d)?;
        }
        camera.check().map_err(|why| bad(&why))?;
        Ok(camera)
    }

    /// Checks the fields: elevation in [−90, 90], field of view in (0, 180), distance > 1 in
    /// perspective (> 0 in orthographic), all finite. Call after changing `ortho` or `fov_y_deg`.
    pub fn validate(&self) -> Result<()> {
        self.check()
            .map_err(|why| Error::Invalid(format!("camera: {why}")))
    }

    /// What is wrong with the fields, if anything.
    fn check(&self) -> std::result::Result<(), String> {
        let fail = Err::<(), String>;
        if !(self.azimuth_deg.is_finite() && self.pan.is_finite()) {
            return fail("azimuth and pan must be finite".into());
        }
        if !(-90.0..=90.0).contains(&self.elevation_deg) {
            return fail(format!(
                "elevation {} is outside [-90, 90] degrees",
                self.elevation_deg
            ));
        }
        if !(self.fov_y_deg > 0.0 && self.fov_y_deg < 180.0) {
            return fail(format!(
                "field of view {} must be in (0, 180) degrees",
                self.fov_y_deg
            ));
        }
        let min_distance = if self.ortho { 0.0 } else { 1.0 };
        if !(self.distance.is_finite() && self.distance > min_distance) {
            return fail(format!(
                "distance {} must be greater than {min_distance} bounding-sphere radii{}",
                self.distance,
                if self.ortho {
                    ""
                } else {
                    " so the eye is outside the volume in perspective"
                }
            ));
        }
        Ok(())
    }

    /// Unit vector from the target to the eye.
    fn eye_dir(&self) -> Vec3 {
        let (sa, ca) = self.azimuth_deg.to_radians().sin_cos();
        let (se, ce) = self.elevation_deg.to_radians().sin_cos();
        Vec3::new(sa * ce, -ca * ce, se)
    }

    /// The up hint for the view: +z, or, when looking (nearly) straight down or up, the horizontal
    /// direction the camera faces at this azimuth (+y at azimuth 0), which keeps the image from
    /// spinning as the elevation passes ±90.
    fn up_hint(&self) -> Vec3 {
        if self.eye_dir().z.abs() > 0.9999 {
            let (sa, ca) = self.azimuth_deg.to_radians().sin_cos();
            Vec3::new(-sa, ca, 0.0)
        } else {
            Vec3::Z
        }
    }

    /// Orthonormal image-plane axes (right, up) in world space.
    fn image_axes(&self) -> (Vec3, Vec3) {
        let forward = -self.eye_dir();
        let right = forward.cross(self.up_hint()).normalize();
        (right, right.cross(forward))
    }

    /// The point looked at, world units: the origin shifted by `pan` in the image plane.
    pub fn target(&self, radius: f32) -> Vec3 {
        let (right, up) = self.image_axes();
        (right * self.pan.x + up * self.pan.y) * radius
    }

    /// Eye position in world units (`distance·radius` from the target).
    pub fn eye(&self, radius: f32) -> Vec3 {
        self.target(radius) + self.eye_dir() * (self.distance * radius)
    }

    /// Unit vector from the eye towards the target (the viewing direction); independent of `radius`
    /// and pan, kept in the signature for symmetry with [`Camera::eye`].
    pub fn view_dir(&self, _radius: f32) -> Vec3 {
        -self.eye_dir()
    }

    /// World → view transform (right-handed: x right, y up, the eye looks down −z).
    pub fn view(&self, radius: f32) -> Mat4 {
        let (right, up) = self.image_axes();
        let back = self.eye_dir();
        let eye = self.eye(radius);
        Mat4::from_cols(
            Vec4::new(right.x, up.x, back.x, 0.0),
            Vec4::new(right.y, up.y, back.y, 0.0),
            Vec4::new(right.z, up.z, back.z, 0.0),
            Vec4::new(-right.dot(eye), -up.dot(eye), -back.dot(eye), 1.0),
        )
    }

    /// View → clip transform for an image of `aspect` = width / height, in Vulkan conventions
    /// (depth [0, 1], y down). Near and far planes enclose the bounding sphere (near at least
    /// 1e-3·radius). Orthographic mode uses a half-height of `radius·distance·tan(fov/2)`, which is
    /// the perspective frustum's half-height at the target, so toggling keeps the framing.
    pub(crate) fn projection(&self, aspect: f32, radius: f32) -> Mat4 {
        // The eye-to-origin distance grows with pan; the sphere lies within it ± one radius.
        let centre = (self.distance * self.distance + self.pan.length_squared()).sqrt();
        let far = (centre + 1.0 + DEPTH_MARGIN) * radius;
        let half_fov = self.fov_y_deg.to_radians() * 0.5;
        // Both matrices map view z = −near to depth 0 and −far to 1, and negate y because
        // Vulkan's framebuffer y points down.
        if self.ortho {
            let near = (centre - 1.0 - DEPTH_MARGIN) * radius;
            let half_h = radius * self.distance * half_fov.tan();
            let half_w = half_h * aspect;
            let inv_depth = 1.0 / (near - far);
            Mat4::from_cols(
                Vec4::new(1.0 / half_w, 0.0, 0.0, 0.0),
                Vec4::new(0.0, -1.0 / half_h, 0.0, 0.0),
                Vec4::new(0.0, 0.0, inv_depth, 0.0),
                Vec4::new(0.0, 0.0, near * inv_depth, 1.0),
            )
        } else {
            let near = ((centre - 1.0 - DEPTH_MARGIN) * radius).max(1e-3 * radius);
            let focal = 1.0 / half_fov.tan();
            let inv_depth = 1.0 / (near - far);
            Mat4::from_cols(
                Vec4::new(focal / aspect, 0.0, 0.0, 0.0),
                Vec4::new(0.0, -focal, 0.0, 0.0),
                Vec4::new(0.0, 0.0, far * inv_depth, -1.0),
                Vec4::new(0.0, 0.0, near * far * inv_depth, 0.0),
            )
        }
    }

    /// World → clip: `projection · view`.
    pub fn view_proj(&self, aspect: f32, radius: f32) -> Mat4 {
        self.projection(aspect, radius) * self.view(radius)
    }

    /// The distance (in bounding-sphere radii) at which `corners` (world units) fill the image of
    /// `aspect` up to `margin` (a fraction of the half-size) on the tighter side: the framing of a
    /// volume's projected bounding box rather than of its bounding sphere. In perspective the eye
    /// stays outside the bounding sphere (distance ≥ 1.05).
    pub fn fit_distance(&self, corners: &[Vec3], radius: f32, aspect: f32, margin: f32) -> f32 {
        let extent = |d: f32| {
            let c = Camera {
                distance: d,
                ..*self
            };
            let m = c.view_proj(aspect, radius);
            corners
                .iter()
                .map(|&p| {
                    let q = m * p.extend(1.0);
                    (q.x / q.w).abs().max((q.y / q.w).abs())
                })
                .fold(0.0f32, f32::max)
        };
        let goal = 1.0 - margin;
        let (mut lo, mut hi) = (if self.ortho { 0.05 } else { 1.05 }, 100.0f32);
        if extent(lo) <= goal {
            return lo;
        }
        // The projected extent shrinks as the eye moves away: bisect for the goal.
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if extent(mid) > goal {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        hi
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ndc(m: Mat4, p: Vec3) -> Vec3 {
        let c = m * p.extend(1.0);
        c.truncate() / c.w
    }

    #[test]
    fn eye_is_at_distance_times_radius() {
        let radius = 80.0;
        for (az, el) in [(0.0, 0.0), (37.0, 20.0), (-120.0, -60.0), (10.0, 90.0)] {
            let c = Camera {
                azimuth_deg: az,
                elevation_deg: el,
                ..Camera::default()
            };
            let eye = c.eye(radius);
            assert!(
                (eye.length() - 2.5 * radius).abs() < 1e-3,
                "{az},{el}: {eye}"
            );
            assert!((c.view_dir(radius) + eye.normalize()).length() < 1e-5);
            let view = c.view(radius);
            assert!(view.transform_point3(eye).length() < 1e-3);
            let target = view.transform_point3(Vec3::ZERO);
            assert!(
                (target - Vec3::new(0.0, 0.0, -2.5 * radius)).length() < 1e-3,
                "{target}"
            );
        }
        let front = Camera::default().eye(1.0);
        assert!((front - Vec3::new(0.0, -2.5, 0.0)).length() < 1e-5);
        let side = Camera {
            azimuth_deg: 90.0,
            ..Camera::default()
        };
        assert!((side.eye(1.0) - Vec3::new(2.5, 0.0, 0.0)).length() < 1e-5);
    }

    #[test]
    fn origin_projects_to_centre_and_up_to_top() {
        let radius = 50.0;
        for ortho in [false, true] {
            for (az, el) in [(0.0, 0.0), (45.0, 30.0), (200.0, -45.0), (0.0, 90.0)] {
                let c = Camera {
                    azimuth_deg: az,
                    elevation_deg: el,
                    ortho,
                    ..Camera::default()
                };
                let m = c.view_proj(1.5, radius);
                let o = ndc(m, Vec3::ZERO);
                assert!(
                    o.x.abs() < 1e-5 && o.y.abs() < 1e-5,
                    "{ortho} {az},{el}: {o}"
                );
                assert!(o.z > 0.0 && o.z < 1.0, "depth {}", o.z);
                // The whole bounding sphere lies between the near and far planes.
                let eye_dir = -c.view_dir(radius);
                for p in [eye_dir * radius, -eye_dir * radius] {
                    let z = ndc(m, p).z;
                    assert!(z > 0.0 && z < 1.0, "{ortho} {az},{el}: depth {z}");
                }
                assert!(
                    ndc(m, eye_dir * radius).z < o.z,
                    "nearer must be smaller depth"
                );
            }
        }
        for ortho in [false, true] {
            let c = Camera {
                ortho,
                ..Camera::default()
            };
            let m = c.view_proj(1.0, radius);
            let up = ndc(m, Vec3::new(0.0, 0.0, 0.5 * radius));
            assert!(
                up.y < -0.1 && up.x.abs() < 1e-5,
                "+z must be at the top: {up}"
            );
            let right = ndc(m, Vec3::new(0.5 * radius, 0.0, 0.0));
            assert!(
                right.x > 0.1,
                "+x must be on the right at azimuth 0: {right}"
            );
        }
    }

    #[test]
    fn ortho_keeps_about_the_framing_of_perspective() {
        let radius = 10.0;
        let p = Camera::default();
        let o = Camera { ortho: true, ..p };
        // A point on the plane through the target, at the sphere's edge.
        let edge = Vec3::new(0.0, 0.0, radius);
        let yp = ndc(p.view_proj(1.0, radius), edge).y;
        let yo = ndc(o.view_proj(1.0, radius), edge).y;
        assert!((yp - yo).abs() < 1e-4, "{yp} vs {yo}");
    }

    #[test]
    fn pan_moves_the_image_not_the_direction() {
        let radius = 10.0;
        let c = Camera {
            pan: Vec2::new(0.3, 0.0),
            ..Camera::default()
        };
        assert_eq!(c.view_dir(radius), Camera::default().view_dir(radius));
        let o = ndc(c.view_proj(1.0, radius), Vec3::ZERO);
        assert!(
            o.x < -0.1 && o.y.abs() < 1e-5,
            "panning right moves the volume left: {o}"
        );
    }

    #[test]
    fn parse_accepts_two_or_three_fields() {
        let c = Camera::parse("30, -20").unwrap();
        assert_eq!(
            (c.azimuth_deg, c.elevation_deg, c.distance),
            (30.0, -20.0, 2.5)
        );
        let c = Camera::parse("0,90,4").unwrap();
        assert_eq!(
            (c.azimuth_deg, c.elevation_deg, c.distance),
            (0.0, 90.0, 4.0)
        );
    }

    #[test]
    fn parse_rejects_malformed_specs() {
        for s in [
            "", "30", "1,2,3,4", "a,2", "1,nan", "1,2,0.5", "1,2,1", "1,95", "1,2,inf",
        ] {
            let e = Camera::parse(s).unwrap_err().to_string();
            assert!(e.contains("AZ,EL[,DIST]"), "{s}: {e}");
        }
        assert!(Camera::parse("1,2,0.5")
            .unwrap_err()
            .to_string()
            .contains("greater than 1"));
        let close_ortho = Camera {
            distance: 0.5,
            ortho: true,
            ..Camera::default()
        };
        assert!(close_ortho.validate().is_ok());
    }
}
