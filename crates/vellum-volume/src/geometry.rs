//! Where a volume lies in patient or world space: its origin and direction matrix, next to its
//! spacing (which `Volume` keeps).
//!
//! ## Convention
//! Geometry is expressed in **LPS** (x towards the patient's left, y posterior, z superior), as
//! ITK and DICOM do; readers convert RAS sources (NIfTI, NRRD `right-anterior-superior`) by
//! negating x and y. The physical point of voxel index (i, j, k) is
//! `origin + D · (i·sx, j·sy, k·sz)`, where column c of the direction matrix `D` (`direction[r][c]`,
//! row-major as ITK prints it) is the unit vector of index axis c.
//!
//! A volume whose file says nothing about its placement (raw data, phantoms, NRRD without `space`)
//! has origin 0, the identity, and [`Space::Unknown`]: renderers then keep their own axis
//! convention rather than claiming an anatomical one.

use vellum_error::{Error, Result};

/// The space the geometry is expressed in.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Default, serde::Serialize)]
pub enum Space {
    /// Left-posterior-superior patient space (anatomical orientation known).
    Lps,
    /// No anatomical orientation known: origin and directions are the file's (or defaults).
    #[default]
    Unknown,
}

/// Origin and directions of a volume's index axes.
#[derive(Copy, Clone, Debug, PartialEq, serde::Serialize)]
pub struct Geometry {
    /// Physical position of voxel (0, 0, 0), in the space's units (millimetres).
    pub origin: [f64; 3],
    /// Row-major 3×3; column c is the unit direction of index axis c.
    pub direction: [[f64; 3]; 3],
    /// The space the origin and directions are in (LPS, or unknown).
    pub space: Space,
}

impl Default for Geometry {
    fn default() -> Self {
        Geometry {
            origin: [0.0; 3],
            direction: IDENTITY,
            space: Space::Unknown,
        }
    }
}

/// The identity direction matrix.
pub const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// Tolerance on orthonormality of a direction matrix (columns of unit length, pairwise
/// perpendicular), as a deviation of dot products.
pub(crate) const ORTHO_TOLERANCE: f64 = 1e-3;

impl Geometry {
    /// Geometry in LPS from an origin and the three axis direction vectors (any length; they are
    /// normalised), checked.
    pub fn lps(origin: [f64; 3], axes: [[f64; 3]; 3]) -> Result<Self> {
        let mut direction = [[0.0; 3]; 3];
        for (c, axis) in axes.iter().enumerate() {
            let len = norm(*axis);
            if !(len.is_finite() && len > 0.0) {
                return Err(Error::Invalid(format!(
                    "direction of axis {c} {axis:?} is zero or not finite; expected a non-zero vector"
                )));
            }
            for r in 0..3 {
                direction[r][c] = axis[r] / len;
            }
        }
        let g = Geometry {
            origin,
            direction,
            space: Space::Lps,
        };
        g.validate()?;
        Ok(g)
    }

    /// The unit direction of index axis `c`.
    pub fn axis(&self, c: usize) -> [f64; 3] {
        [
            self.direction[0][c],
            self.direction[1][c],
            self.direction[2][c],
        ]
    }

    /// Checks: finite origin and directions; unit, mutually perpendicular columns (within
    /// `ORTHO_TOLERANCE`); a non-zero determinant.
    pub fn validate(&self) -> Result<()> {
        if !self.origin.iter().all(|v| v.is_finite()) {
            return Err(Error::Invalid(format!(
                "origin {:?} is not finite; expected three finite numbers",
                self.origin
            )));
        }
        if !self.direction.iter().flatten().all(|v| v.is_finite()) {
            return Err(Error::Invalid(format!(
                "direction matrix {:?} is not finite",
                self.direction
            )));
        }
        for a in 0..3 {
            for b in a..3 {
                let d = dot(self.axis(a), self.axis(b));
                let want = if a == b { 1.0 } else { 0.0 };
                if (d - want).abs() > ORTHO_TOLERANCE {
                    return Err(Error::Invalid(format!(
                        "direction matrix {:?} is not orthonormal (axes {a} and {b} have dot product {d:.4}); expected a rotation, possibly with a reflection",
                        self.direction
                    )));
                }
            }
        }
        Ok(())
    }

    /// The physical point of continuous voxel index `index` for voxel `spacing`.
    #[cfg(test)]
    pub(crate) fn point(&self, index: [f64; 3], spacing: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|r| {
            self.origin[r]
                + (0..3)
                    .map(|c| self.direction[r][c] * index[c] * spacing[c])
                    .sum::<f64>()
        })
    }

    /// What vellum does with a volume whose orientation is unknown, in one sentence: `info` and
    /// `render` say it once.
    pub const UNKNOWN_ORIENTATION: &'static str = "the file gives no orientation, so its axes are kept as stored (seen from azimuth 0: x to the right, y away, z up; no anatomical view names)";

    /// Whether the anatomical orientation is known.
    pub fn is_oriented(&self) -> bool {
        self.space == Space::Lps
    }

    /// Where each index axis points, as a three-letter code in the space's letters (L/R, P/A,
    /// S/I for LPS), e.g. "LPS" for the identity, "RAS" for a NIfTI-style flip; "oblique" is
    /// appended when an axis is more than 1° off its closest anatomical axis. For an unknown
    /// space, "unknown".
    pub fn orientation_code(&self) -> String {
        if !self.is_oriented() {
            return "unknown".into();
        }
        let letters = [('L', 'R'), ('P', 'A'), ('S', 'I')];
        let mut code = String::new();
        let mut oblique = false;
        for c in 0..3 {
            let a = self.axis(c);
            let (r, v) = (0..3)
                .map(|r| (r, a[r]))
                .max_by(|x, y| x.1.abs().total_cmp(&y.1.abs()))
                .expect("three components");
            code.push(if v >= 0.0 { letters[r].0 } else { letters[r].1 });
            oblique |= v.abs() < (1.0f64).to_radians().cos();
        }
        if oblique {
            code.push_str(" (oblique)");
        }
        code
    }
}

/// Converts a RAS vector or point to LPS (and back): x and y change sign.
pub(crate) fn ras_to_lps(v: [f64; 3]) -> [f64; 3] {
    [-v[0], -v[1], v[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_points_and_checks() {
        let g = Geometry::lps(
            [1.0, 2.0, 3.0],
            [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        )
        .unwrap();
        assert_eq!(g.orientation_code(), "LPS");
        assert_eq!(g.point([1.0, 1.0, 1.0], [2.0, 3.0, 4.0]), [3.0, 5.0, 7.0]);
        let ras = Geometry::lps(
            [0.0; 3],
            [[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]],
        )
        .unwrap();
        assert_eq!(ras.orientation_code(), "RAS");
        let (s, c) = (30f64.to_radians().sin(), 30f64.to_radians().cos());
        let rot = Geometry::lps([0.0; 3], [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]).unwrap();
        assert_eq!(rot.orientation_code(), "LPS (oblique)");
        assert!(Geometry::lps(
            [0.0; 3],
            [[1.0, 0.0, 0.0], [1.0, 0.1, 0.0], [0.0, 0.0, 1.0]]
        )
        .unwrap_err()
        .to_string()
        .contains("not orthonormal"));
        assert!(Geometry::lps(
            [f64::NAN, 0.0, 0.0],
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        )
        .unwrap_err()
        .to_string()
        .contains("not finite"));
        assert!(Geometry::lps([0.0; 3], [[0.0; 3], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).is_err());
        assert_eq!(Geometry::default().orientation_code(), "unknown");
    }
}
