//! Procedural test volumes, so every technique can be run and tested without data files.
//!
//! Phantoms are f32 with values in [0, 1] and unit spacing: the simplest honest representation of
//! an analytic function. Voxel (i, j, k) samples the point (c(i), c(j), c(k)) with
//! c(i) = 2i/(n-1) - 1, so the first and last voxel centres lie on the faces of [-1, 1]^3.

use rayon::prelude::*;

use super::{Volume, VoxelData};
use vellum_error::{Error, Result};

/// Grid size used when a spec gives none.
pub(crate) const DEFAULT_SIZE: usize = 128;
/// Largest grid size a spec may ask for (1024^3 f32 voxels are 4 GiB).
pub(crate) const MAX_SIZE: usize = 1024;

/// Parses `phantom:NAME[:N]` (NAME is `shepp-logan` or `nested`) and builds the phantom. Returns
/// `None` when `spec` does not start with `phantom:`, so callers can fall back to file loading.
pub fn parse_spec(spec: &str) -> Option<Result<Volume>> {
    Some(Phantom::parse(spec, MAX_SIZE)?.map(|p| p.volume()))
}

/// Largest grid size a streamed phantom may have: one made a box at a time (`vellum convert`),
/// whose memory does not follow its size.
pub const MAX_STREAMED_SIZE: usize = 16384;

/// The analytic phantoms.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Kind {
    /// The 3D Shepp–Logan head.
    SheppLogan,
    /// Nested shells of different values.
    Nested,
    /// A ball.
    Sphere,
    /// A torus.
    Torus,
    /// An ellipsoid.
    Ellipsoid,
}

/// A phantom named by a spec, not yet sampled: the whole grid ([`Phantom::volume`]) or any box of
/// it (`Phantom::sample_box`) gives the same voxels.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct Phantom {
    /// Which phantom.
    pub kind: Kind,
    /// Voxels per axis.
    pub n: usize,
}

impl Phantom {
    /// Parses `phantom:NAME[:N]` with N at most `max`; `None` when `spec` is not a phantom.
    pub fn parse(spec: &str, max: usize) -> Option<Result<Phantom>> {
        let rest = spec.strip_prefix("phantom:")?;
        Some(parse(rest, max))
    }

    /// The whole grid.
    pub fn volume(&self) -> Volume {
        self.sample_box([0; 3], [self.n; 3])
    }

    /// Voxels `lo .. lo + size` of the grid (clamped to it), as a volume of that size.
    pub(crate) fn sample_box(&self, lo: [usize; 3], size: [usize; 3]) -> Volume {
        let n = self.n;
        let size: [usize; 3] = std::array::from_fn(|a| size[a].min(n.saturating_sub(lo[a])));
        let b = GridBox { n, lo, size };
        match self.kind {
            Kind::SheppLogan => shepp_logan_box(&b),
            Kind::Nested => b.sample(nested_at),
            Kind::Sphere => b.sample(sphere_at),
            Kind::Torus => b.sample(torus_at),
            Kind::Ellipsoid => b.sample(ellipsoid_at),
        }
    }
}

fn parse(rest: &str, max: usize) -> Result<Phantom> {
    let (name, size) = rest.split_once(':').unwrap_or((rest, ""));
    let n = if size.is_empty() {
        DEFAULT_SIZE
    } else {
        size.parse::<usize>()
            .ok()
            .filter(|n| (1..=max).contains(n))
            .ok_or_else(|| {
                Error::Invalid(format!(
                    "phantom size '{size}' is invalid; expected a whole number from 1 to {max}"
                ))
            })?
    };
    let kind = match name {
        "shepp-logan" | "shepp_logan" => Kind::SheppLogan,
        "nested" => Kind::Nested,
        "sphere" => Kind::Sphere,
        "torus" => Kind::Torus,
        "ellipsoid" => Kind::Ellipsoid,
        other => return Err(Error::Invalid(format!(
            "unknown phantom '{other}'; expected phantom:NAME[:N] with NAME shepp-logan, nested, sphere, torus or ellipsoid"
        ))),
    };
    Ok(Phantom { kind, n })
}

/// Smooth phantoms for line drawings: 0.5 + 0.5 tanh(d / SMOOTH_WIDTH) of a signed distance d
/// (positive inside, in [-1, 1] coordinates), so f = 0.5 is the exact shape and every derivative
/// exists.
pub(crate) const SMOOTH_WIDTH: f64 = 0.08;
/// Radius of `phantom:sphere` in [-1, 1] coordinates.
pub const SPHERE_RADIUS: f64 = 0.6;
/// Major and minor radius of `phantom:torus` (axis along z).
pub const TORUS_RADII: [f64; 2] = [0.55, 0.25];
/// Semi-axes of `phantom:ellipsoid`.
pub(crate) const ELLIPSOID_AXES: [f64; 3] = [0.75, 0.5, 0.35];

fn smooth(d: f64) -> f32 {
    (0.5 + 0.5 * (d / SMOOTH_WIDTH).tanh()) as f32
}

/// A sphere of radius [`SPHERE_RADIUS`] at the centre, with a smooth profile.
pub fn smooth_sphere(n: usize) -> Volume {
    Phantom {
        kind: Kind::Sphere,
        n,
    }
    .volume()
}

fn sphere_at(x: f64, y: f64, z: f64) -> f32 {
    smooth(SPHERE_RADIUS - (x * x + y * y + z * z).sqrt())
}

/// A torus around z with radii [`TORUS_RADII`], with a smooth profile: saddle-shaped on the inside.
pub fn smooth_torus(n: usize) -> Volume {
    Phantom {
        kind: Kind::Torus,
        n,
    }
    .volume()
}

fn torus_at(x: f64, y: f64, z: f64) -> f32 {
    let [big, small] = TORUS_RADII;
    let q = (x * x + y * y).sqrt() - big;
    smooth(small - (q * q + z * z).sqrt())
}

/// An ellipsoid with semi-axes `ELLIPSOID_AXES`, with a smooth profile (an approximate distance:
/// the level set f = 0.5 is the exact ellipsoid).
pub fn smooth_ellipsoid(n: usize) -> Volume {
    Phantom {
        kind: Kind::Ellipsoid,
        n,
    }
    .volume()
}

fn ellipsoid_at(x: f64, y: f64, z: f64) -> f32 {
    let [a, b, c] = ELLIPSOID_AXES;
    let k = ((x / a).powi(2) + (y / b).powi(2) + (z / c).powi(2)).sqrt();
    smooth((1.0 - k) * c)
}

/// A box `lo .. lo + size` of an n³ grid whose voxel centres lie at c(i) = 2i/(n-1) - 1.
struct GridBox {
    n: usize,
    lo: [usize; 3],
    size: [usize; 3],
}

impl GridBox {
    /// The coordinate of grid index `i` in [-1, 1].
    fn c(&self, i: usize) -> f64 {
        if self.n > 1 {
            2.0 * i as f64 / (self.n - 1) as f64 - 1.0
        } else {
            0.0
        }
    }

    /// Fills the box row by row: `row(y, z, out)` writes the row at grid (y, z) whose first
    /// voxel is grid x = lo[0]. Rows run in parallel.
    fn rows(&self, row: impl Fn(f64, f64, &mut [f32]) + Sync) -> Volume {
        let [w, h, d] = self.size;
        let mut data = vec![0f32; w * h * d];
        if w > 0 {
            data.par_chunks_mut(w).enumerate().for_each(|(r, out)| {
                let (y, z) = (self.lo[1] + r % h, self.lo[2] + r / h);
                row(self.c(y), self.c(z), out);
            });
        }
        Volume {
            dims: self.size,
            spacing: [1.0; 3],
            data: VoxelData::F32(data),
            geometry: Default::default(),
        }
    }

    /// Fills the box with `f(x, y, z)` at the voxel centres.
    fn sample(&self, f: fn(f64, f64, f64) -> f32) -> Volume {
        self.rows(|y, z, out| {
            for (i, v) in out.iter_mut().enumerate() {
                *v = f(self.c(self.lo[0] + i), y, z);
            }
        })
    }
}

/// One ellipsoid of the Shepp–Logan table: intensity added, semi-axes, centre, Euler angles (degrees).
struct Ellipsoid {
    a: f64,
    axes: [f64; 3],
    centre: [f64; 3],
    phi: f64,
    theta: f64,
    psi: f64,
}

const fn e(a: f64, axes: [f64; 3], centre: [f64; 3], phi: f64, theta: f64, psi: f64) -> Ellipsoid {
    Ellipsoid {
        a,
        axes,
        centre,
        phi,
        theta,
        psi,
    }
}

/// The "modified" 3D Shepp–Logan head of M. Schabel's `phantom3d` (MATLAB Central, 2006): Kak &
/// Slaney's ten ellipsoids with Toft's higher-contrast intensities (skull 1, brain 0.2, ventricles
/// 0, small features 0.3), so structures are visible at a glance.
const SHEPP_LOGAN: [Ellipsoid; 10] = [
    e(1.0, [0.6900, 0.920, 0.810], [0.0, 0.0, 0.0], 0.0, 0.0, 0.0),
    e(
        -0.8,
        [0.6624, 0.874, 0.780],
        [0.0, -0.0184, 0.0],
        0.0,
        0.0,
        0.0,
    ),
    e(
        -0.2,
        [0.1100, 0.310, 0.220],
        [0.22, 0.0, 0.0],
        -18.0,
        0.0,
        10.0,
    ),
    e(
        -0.2,
        [0.1600, 0.410, 0.280],
        [-0.22, 0.0, 0.0],
        18.0,
        0.0,
        10.0,
    ),
    e(
        0.1,
        [0.2100, 0.250, 0.410],
        [0.0, 0.35, -0.15],
        0.0,
        0.0,
        0.0,
    ),
    e(0.1, [0.0460, 0.046, 0.050], [0.0, 0.1, 0.25], 0.0, 0.0, 0.0),
    e(
        0.1,
        [0.0460, 0.046, 0.050],
        [0.0, -0.1, 0.25],
        0.0,
        0.0,
        0.0,
    ),
    e(
        0.1,
        [0.0460, 0.023, 0.050],
        [-0.08, -0.605, 0.0],
        0.0,
        0.0,
        0.0,
    ),
    e(
        0.1,
        [0.0230, 0.023, 0.020],
        [0.0, -0.606, 0.0],
        0.0,
        0.0,
        0.0,
    ),
    e(
        0.1,
        [0.0230, 0.046, 0.020],
        [0.06, -0.605, 0.0],
        0.0,
        0.0,
        0.0,
    ),
];

/// The 3D Shepp–Logan head phantom (`SHEPP_LOGAN`) on an n^3 grid, values clamped to [0, 1].
/// As in `phantom3d`, each ellipsoid tests the grid point rotated by its z-x-z Euler angles about
/// the origin and then offset by its centre.
pub fn shepp_logan(n: usize) -> Volume {
    Phantom {
        kind: Kind::SheppLogan,
        n,
    }
    .volume()
}

/// One Shepp–Logan ellipsoid ready to test: its rotation's rows, and its bounding box in grid
/// coordinates (centre and half extent per axis).
struct Placed<'a> {
    el: &'a Ellipsoid,
    rows: [[f64; 3]; 3],
    centre: [f64; 3],
    half: [f64; 3],
}

impl Placed<'_> {
    fn new(el: &Ellipsoid) -> Placed<'_> {
        let (sp, cp) = el.phi.to_radians().sin_cos();
        let (st, ct) = el.theta.to_radians().sin_cos();
        let (ss, cs) = el.psi.to_radians().sin_cos();
        let rows = [
            [cp * cs - ct * sp * ss, sp * cs + ct * cp * ss, ss * st],
            [-cp * ss - ct * sp * cs, -sp * ss + ct * cp * cs, cs * st],
            [st * sp, -st * cp, ct],
        ];
        // p = Rᵀ q: the box of the rotated ellipsoid, widened by a hair so that rounding in the
        // exact test below can never fall outside it.
        let centre = std::array::from_fn(|j| (0..3).map(|i| rows[i][j] * el.centre[i]).sum());
        let half = std::array::from_fn(|j| {
            let sq: f64 = (0..3).map(|i| (rows[i][j] * el.axes[i]).powi(2)).sum();
            sq.sqrt() + 1e-9
        });
        Placed {
            el,
            rows,
            centre,
            half,
        }
    }

    fn near(&self, axis: usize, v: f64) -> bool {
        (v - self.centre[axis]).abs() <= self.half[axis]
    }

    /// Whether grid point (x, y, z) lies in the ellipsoid: the exact test of `phantom3d`.
    fn holds(&self, x: f64, y: f64, z: f64) -> bool {
        let q = self.rows.map(|row| row[0] * x + row[1] * y + row[2] * z);
        let d: f64 = (0..3)
            .map(|i| ((q[i] - self.el.centre[i]) / self.el.axes[i]).powi(2))
            .sum();
        d <= 1.0
    }
}

/// A box of the Shepp–Logan grid. Each row tests only the ellipsoids whose bounding box it
/// crosses, and each voxel only those whose box holds its x: the same sums as testing all ten,
/// at a fraction of the cost (what makes a 2048³ phantom a matter of minutes).
fn shepp_logan_box(b: &GridBox) -> Volume {
    let placed: Vec<Placed> = SHEPP_LOGAN.iter().map(Placed::new).collect();
    b.rows(|y, z, out| {
        let crossing: Vec<&Placed> = placed
            .iter()
            .filter(|p| p.near(1, y) && p.near(2, z))
            .collect();
        for (i, v) in out.iter_mut().enumerate() {
            let x = b.c(b.lo[0] + i);
            let mut sum = 0.0;
            for p in &crossing {
                if p.near(0, x) && p.holds(x, y, z) {
                    sum += p.el.a;
                }
            }
            *v = sum.clamp(0.0, 1.0) as f32;
        }
    })
}

/// Intensity of both inner spheres of the [`nested`] phantom.
pub const NESTED_CORE: f32 = 0.75;
/// Shell around the first sphere (low intensity).
pub const NESTED_LOW: f32 = 0.25;
/// Shell around the second sphere (medium intensity).
pub const NESTED_MEDIUM: f32 = 0.5;
/// Centres (x, in [-1, 1] coordinates; y = z = 0) of the low-shelled and medium-shelled structure.
pub(crate) const NESTED_CENTRES_X: [f64; 2] = [-0.45, 0.45];
/// Radius of each inner sphere.
pub(crate) const NESTED_CORE_RADIUS: f64 = 0.2;
/// Outer radius of each shell.
pub(crate) const NESTED_SHELL_RADIUS: f64 = 0.4;

/// The nested-structures phantom of the occlusion-spectrum paper (Correa & Ma, Fig. 4a/5), as the
/// project defines it: two spheres of equal intensity, one surrounded by a low-intensity shell and
/// one by a medium-intensity shell. Intensity alone cannot tell the spheres apart; their occlusion
/// differs because their surroundings do, which is what the spectrum separates. The paper gives
/// no numbers; here the spheres are 0.75, the shells 0.25 (at x = -0.45) and 0.5 (at x = +0.45),
/// background 0, spheres of radius 0.2 and shells of outer radius 0.4 in [-1, 1] coordinates.
pub fn nested(n: usize) -> Volume {
    Phantom {
        kind: Kind::Nested,
        n,
    }
    .volume()
}

fn nested_at(x: f64, y: f64, z: f64) -> f32 {
    let [cx_a, cx_b] = NESTED_CENTRES_X;
    let r = |cx: f64| ((x - cx).powi(2) + y * y + z * z).sqrt();
    let layer = |r: f64, core: f32, shell: f32| {
        if r <= NESTED_CORE_RADIUS {
            Some(core)
        } else if r <= NESTED_SHELL_RADIUS {
            Some(shell)
        } else {
            None
        }
    };
    layer(r(cx_a), NESTED_CORE, NESTED_LOW)
        .or(layer(r(cx_b), NESTED_CORE, NESTED_MEDIUM))
        .unwrap_or(0.0)
}
