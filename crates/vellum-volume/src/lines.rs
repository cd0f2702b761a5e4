//! Object-space lines on the implicit surface f = τ (SPEC TL5; Burns et al. 2005, DeCarlo et al.
//! 2003): silhouettes (n·v = 0) and suggestive contours (κ_r = 0 with D_w κ_r > 0). The CPU twin
//! of `glsl/lines/extract.comp`: the same arithmetic in the same order, in f32.
//!
//! **Quantities at grid vertices** (in physical units, so anisotropic spacing bends nothing):
//! f; g = ∇f by central differences (clamped at the borders); the Hessian H by second central
//! differences; n = −g/|g| (f is higher inside); v the unit vector towards the eye; n·v; and
//! κ_r = −(wᵀ H w) / (|g| |w|²) with w = v − (n·v) n, the view projected on the tangent plane.
//! A sphere gives κ_r = 1/r > 0 everywhere.
//!
//! **Extraction**: each cell splits into six tetrahedra around its main diagonal (the Kuhn
//! split, whose face diagonals agree between neighbouring cells). In a tetrahedron the surface
//! f = τ is one triangle or two, with every quantity interpolated linearly along the edges. In a
//! triangle the line h = 0 (h = n·v or κ_r) is the segment between the two edges where h changes
//! sign. An endpoint on a face is computed from that face's edges only, so the segments of
//! neighbouring cells meet exactly: the lines have no gaps.
//!
//! **Suggestive contours** keep a segment only where it is front facing (n·v > 0), away from the
//! view-aligned region where w vanishes (the angle between n and v at least θ_c), and where
//! κ_r grows along w: D_w κ_r > t_d. In a triangle κ_r is linear, so its gradient is exact there.

use rayon::prelude::*;

/// Where the eye is, in the volume's physical frame (index × spacing).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Eye {
    /// Orthographic: the unit direction towards the eye.
    Direction([f32; 3]),
    /// Perspective: the eye's position.
    Point([f32; 3]),
}

/// Which lines and how they are filtered.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineParams {
    /// τ, on the same scale as the values.
    pub iso: f32,
    /// Find silhouettes (n · v = 0).
    pub silhouettes: bool,
    /// Find suggestive contours.
    pub suggestive: bool,
    /// θ_c in degrees: suggestive contours closer than this to facing the viewer are dropped.
    pub min_angle_deg: f32,
    /// t_d: the least D_w κ_r (per physical unit²) of a suggestive contour.
    pub derivative_threshold: f32,
    /// Visit every `stride`-th cell along each axis (1 = all; 2 = the interactive mode).
    pub stride: u32,
    /// Smooth the values first with the importance map's Gaussian of this radius in voxels
    /// (σ = R/3; 0 = none). Curvature is a second derivative: on raw CT or MRI, noise alone
    /// makes κ_r cross zero everywhere, and suggestive contours become speckle. [`extract`] takes
    /// values already smoothed ([`smoothed`]); the GPU passes smooth for themselves.
    pub smooth: u32,
    /// GPU only: the seeded traversal (Burns et al.) instead of a visit of the cells, for the
    /// interactive mode. It starts from the previous extraction's segments and a sparse grid of
    /// seeds and follows the lines cell to cell for a bounded number of rounds: cheaper than
    /// every cell, with whole curves near where they were, but lines far from any seed may be
    /// missing or shorter. The CPU reference ignores it (it has no previous frame).
    pub seeded: bool,
}

/// `--line-smooth auto` smooths when the quantisation step is at least this fraction of the
/// surfaces' gradient (see [`auto_smooth_radius`]).
pub(crate) const AUTO_SMOOTH_FROM: f64 = 0.003;
/// ... and with radius 2 from this fraction on.
pub(crate) const AUTO_SMOOTH_WIDE_FROM: f64 = 0.03;

/// The smoothing radius of `--line-smooth auto` for `v`: 0 (none), 1 or 2 voxels.
///
/// Suggestive contours are zeros of a curvature, a second derivative, and on integer data the
/// quantisation step makes second differences jump where the surface is smooth: a smooth sphere
/// stored as uint8 gets about 140 spurious segments unsmoothed, and none after a Gaussian of
/// radius 1. The rule compares the step q (one data unit for integer voxels, none for floats)
/// with g, the 90th percentile of the non-zero gradient magnitudes (central differences, data
/// units per voxel, over up to a million sampled voxels), which is the gradient across the
/// volume's surfaces: no smoothing for q/g < `AUTO_SMOOTH_FROM`, radius 1 up to
/// `AUTO_SMOOTH_WIDE_FROM`, radius 2 above. Measured q/g: smooth float phantoms 0; the uint8
/// sphere 0.023; CT heads 0.002–0.004 (16-bit), the chest CT 0.019, brain MRI 0.037 (8-bit).
/// Noise in float data is not measured: such data need `--line-smooth N` by hand.
pub fn auto_smooth_radius(v: &crate::Volume) -> u32 {
    match &v.data {
        crate::VoxelData::U8(d) => smooth_radius_of(d, v.dims),
        crate::VoxelData::U16(d) => smooth_radius_of(d, v.dims),
        crate::VoxelData::I16(d) => smooth_radius_of(d, v.dims),
        crate::VoxelData::F32(_) => 0,
    }
}

/// [`auto_smooth_radius`] of integer voxels `d` of size `dims`.
fn smooth_radius_of<T: Copy + Into<f64> + Sync>(d: &[T], dims: [usize; 3]) -> u32 {
    let Some(g90) = surface_gradient(d, dims) else {
        return 0;
    };
    let ratio = 1.0 / g90 as f64;
    match ratio {
        r if r < AUTO_SMOOTH_FROM => 0,
        r if r < AUTO_SMOOTH_WIDE_FROM => 1,
        _ => 2,
    }
}

/// The 90th percentile of the central-difference gradient magnitude over every `stride`-th
/// interior voxel of `d` (at most about a million), read from the voxels' own slice (no
/// per-voxel test of the type); `None` where none is above zero or the volume has no interior.
fn surface_gradient<T: Copy + Into<f64> + Sync>(d: &[T], dims: [usize; 3]) -> Option<f32> {
    let [nx, ny, nz] = dims;
    if nx < 3 || ny < 3 || nz < 3 {
        return None;
    }
    let at = |x: usize, y: usize, z: usize| -> f64 { d[x + nx * (y + ny * z)].into() };
    let inner = (nx - 2) * (ny - 2) * (nz - 2);
    let stride = inner.div_ceil(1 << 20).max(1);
    // Every `stride`-th interior voxel in order (x fastest), row by row: in the row (y, z), the
    // x whose interior index (x - 1) + base is a multiple of `stride`. Squared magnitudes, whose
    // order is the magnitudes' (the square root is taken of the one picked).
    let row = nx - 2;
    let mut squares: Vec<f64> = (1..nz - 1)
        .into_par_iter()
        .flat_map_iter(|z| {
            (1..ny - 1).flat_map(move |y| {
                let base = row * ((y - 1) + (ny - 2) * (z - 1));
                let first = (stride - base % stride) % stride;
                (1 + first..nx - 1).step_by(stride).filter_map(move |x| {
                    let g = [
                        at(x + 1, y, z) - at(x - 1, y, z),
                        at(x, y + 1, z) - at(x, y - 1, z),
                        at(x, y, z + 1) - at(x, y, z - 1),
                    ];
                    let s = g[0] * g[0] + g[1] * g[1] + g[2] * g[2];
                    (s > 0.0).then_some(s)
                })
            })
        })
        .collect();
    if squares.is_empty() {
        return None;
    }
    let k = (squares.len() * 9 / 10).min(squares.len() - 1);
    let (_, s90, _) = squares.select_nth_unstable_by(k, f64::total_cmp);
    // As f32, as the magnitudes were kept before (rounding is monotone, so the pick is the same).
    Some((0.5 * s90.sqrt()) as f32)
}

/// The values of `v` normalised to [0, 1] over its range (as [`extract`] and the GPU passes see
/// them), after the Gaussian of radius `radius` voxels when it is not 0: the CPU twin of the
/// smoothing the GPU passes do (`ImportanceMap::record_blur_of_texture`).
pub fn smoothed(v: &crate::Volume, radius: u32) -> vellum_error::Result<Vec<f32>> {
    let st = crate::stats::stats(v, 0);
    let lo = st.min;
    let scale = if st.max > st.min {
        1.0 / (st.max - st.min)
    } else {
        0.0
    };
    let norm = |b: f64| ((b - lo) * scale) as f32;
    if radius == 0 {
        return Ok((0..v.len()).map(|i| norm(v.data.get_f64(i))).collect());
    }
    let blurred = crate::reference::gaussian::gaussian_blur(v, radius)?;
    Ok(blurred.into_iter().map(norm).collect())
}

impl Default for LineParams {
    fn default() -> Self {
        LineParams {
            iso: 0.5,
            silhouettes: true,
            suggestive: true,
            min_angle_deg: 20.0,
            derivative_threshold: 1e-4,
            stride: 1,
            smooth: 0,
            seeded: false,
        }
    }
}

/// Kind of a segment (the w of its first endpoint).
pub const SILHOUETTE: f32 = 0.0;
/// Kind of a suggestive-contour segment.
pub const SUGGESTIVE: f32 = 1.0;

/// One segment in voxel index coordinates; `a[3]` is its kind.
#[repr(C)]
#[derive(Copy, Clone, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Segment {
    /// The first endpoint; its w is the kind.
    pub a: [f32; 4],
    /// The second endpoint.
    pub b: [f32; 4],
}

impl Segment {
    /// The kind: [`SILHOUETTE`] or [`SUGGESTIVE`].
    pub fn kind(&self) -> f32 {
        self.a[3]
    }
    /// Length in voxels.
    pub fn length(&self) -> f32 {
        let d: [f32; 3] = std::array::from_fn(|i| self.b[i] - self.a[i]);
        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
    }
}

/// The six tetrahedra of a cell, as cube-corner indices (bit 0 x, bit 1 y, bit 2 z).
pub(crate) const TETS: [[usize; 4]; 6] = [
    [0, 1, 3, 7],
    [0, 1, 5, 7],
    [0, 2, 3, 7],
    [0, 2, 6, 7],
    [0, 4, 5, 7],
    [0, 4, 6, 7],
];

/// Quantities at a vertex or an interpolated point.
#[derive(Clone, Copy, Debug, Default)]
struct Point {
    /// Position in index coordinates.
    p: [f32; 3],
    /// Gradient (physical units).
    g: [f32; 3],
    ndotv: f32,
    kappa: f32,
}

fn lerp(a: &Point, b: &Point, t: f32) -> Point {
    let l = |x: f32, y: f32| x + t * (y - x);
    Point {
        p: std::array::from_fn(|i| l(a.p[i], b.p[i])),
        g: std::array::from_fn(|i| l(a.g[i], b.g[i])),
        ndotv: l(a.ndotv, b.ndotv),
        kappa: l(a.kappa, b.kappa),
    }
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn normalize(a: [f32; 3]) -> [f32; 3] {
    let l = dot(a, a).sqrt().max(1e-30);
    a.map(|c| c / l)
}

/// The unit view vector at physical position `x`.
fn view_at(eye: Eye, x: [f32; 3]) -> [f32; 3] {
    match eye {
        Eye::Direction(d) => normalize(d),
        Eye::Point(e) => normalize([e[0] - x[0], e[1] - x[1], e[2] - x[2]]),
    }
}

/// n·v and κ_r from the gradient and Hessian (xx, yy, zz, xy, xz, yz) at a point with view v.
fn surface_terms(g: [f32; 3], h: [f32; 6], v: [f32; 3]) -> (f32, f32) {
    let gl = dot(g, g).sqrt().max(1e-30);
    let n = g.map(|c| -c / gl);
    let ndotv = dot(n, v);
    let w: [f32; 3] = std::array::from_fn(|i| v[i] - ndotv * n[i]);
    let ww = dot(w, w);
    let hw = [
        h[0] * w[0] + h[3] * w[1] + h[4] * w[2],
        h[3] * w[0] + h[1] * w[1] + h[5] * w[2],
        h[4] * w[0] + h[5] * w[1] + h[2] * w[2],
    ];
    let kappa = if ww > 1e-12 {
        -dot(w, hw) / (gl * ww)
    } else {
        0.0
    };
    (ndotv, kappa)
}

/// Extracts the lines of `values` (x fastest, `dims`; `spacing` in physical units per voxel).
pub fn extract(
    values: &[f32],
    dims: [usize; 3],
    spacing: [f32; 3],
    eye: Eye,
    params: &LineParams,
) -> Vec<Segment> {
    let [nx, ny, nz] = dims;
    if nx < 2 || ny < 2 || nz < 2 {
        return Vec::new();
    }
    let s = params.stride.max(1) as usize;
    let at = |x: i64, y: i64, z: i64| {
        let c = |v: i64, n: usize| v.clamp(0, n as i64 - 1) as usize;
        values[c(x, nx) + nx * (c(y, ny) + ny * c(z, nz))]
    };
    let cos_c = params.min_angle_deg.to_radians().cos();
    (0..nz - 1)
        .into_par_iter()
        .filter(|z| z % s == 0)
        .flat_map_iter(|z| {
            let mut out = Vec::new();
            for y in (0..ny - 1).step_by(s) {
                for x in (0..nx - 1).step_by(s) {
                    cell(
                        &at,
                        [x as i64, y as i64, z as i64],
                        spacing,
                        eye,
                        params,
                        cos_c,
                        &mut out,
                    );
                }
            }
            out
        })
        .collect()
}

fn cell(
    at: &dyn Fn(i64, i64, i64) -> f32,
    c: [i64; 3],
    spacing: [f32; 3],
    eye: Eye,
    params: &LineParams,
    cos_c: f32,
    out: &mut Vec<Segment>,
) {
    let corner = |i: usize| {
        [
            c[0] + (i & 1) as i64,
            c[1] + (i >> 1 & 1) as i64,
            c[2] + (i >> 2 & 1) as i64,
        ]
    };
    let f: [f32; 8] = std::array::from_fn(|i| {
        let q = corner(i);
        at(q[0], q[1], q[2])
    });
    let tau = params.iso;
    let inside = f.iter().filter(|&&v| v >= tau).count();
    if inside == 0 || inside == 8 {
        return;
    }
    let pts: [Point; 8] = std::array::from_fn(|i| {
        let [x, y, z] = corner(i);
        let d = |dx: i64, dy: i64, dz: i64| at(x + dx, y + dy, z + dz);
        let f0 = d(0, 0, 0);
        let [sx, sy, sz] = spacing;
        let g = [
            (d(1, 0, 0) - d(-1, 0, 0)) / (2.0 * sx),
            (d(0, 1, 0) - d(0, -1, 0)) / (2.0 * sy),
            (d(0, 0, 1) - d(0, 0, -1)) / (2.0 * sz),
        ];
        let h = [
            (d(1, 0, 0) - 2.0 * f0 + d(-1, 0, 0)) / (sx * sx),
            (d(0, 1, 0) - 2.0 * f0 + d(0, -1, 0)) / (sy * sy),
            (d(0, 0, 1) - 2.0 * f0 + d(0, 0, -1)) / (sz * sz),
            (d(1, 1, 0) - d(1, -1, 0) - d(-1, 1, 0) + d(-1, -1, 0)) / (4.0 * sx * sy),
            (d(1, 0, 1) - d(1, 0, -1) - d(-1, 0, 1) + d(-1, 0, -1)) / (4.0 * sx * sz),
            (d(0, 1, 1) - d(0, 1, -1) - d(0, -1, 1) + d(0, -1, -1)) / (4.0 * sy * sz),
        ];
        let p = [x as f32, y as f32, z as f32];
        let v = view_at(eye, [p[0] * sx, p[1] * sy, p[2] * sz]);
        let (ndotv, kappa) = surface_terms(g, h, v);
        Point { p, g, ndotv, kappa }
    });
    for tet in TETS {
        let s: [f32; 4] = tet.map(|i| f[i] - tau);
        let ins: Vec<usize> = (0..4).filter(|&k| s[k] >= 0.0).collect();
        // Always from the lower corner index to the higher: the neighbouring tetrahedron that
        // shares the edge then computes the bit-identical point.
        let cross = |a: usize, b: usize| {
            let (a, b) = if tet[a] < tet[b] { (a, b) } else { (b, a) };
            let t = s[a] / (s[a] - s[b]);
            lerp(&pts[tet[a]], &pts[tet[b]], t)
        };
        match ins.len() {
            1 | 3 => {
                // The lone vertex (inside or outside) and its three edges.
                let lone = if ins.len() == 1 {
                    ins[0]
                } else {
                    (0..4).find(|k| !ins.contains(k)).unwrap_or(0)
                };
                let others: Vec<usize> = (0..4).filter(|&k| k != lone).collect();
                let tri = [
                    cross(lone, others[0]),
                    cross(lone, others[1]),
                    cross(lone, others[2]),
                ];
                triangle(&tri, spacing, eye, params, cos_c, out);
            }
            2 => {
                let (a, b) = (ins[0], ins[1]);
                let outs: Vec<usize> = (0..4).filter(|k| !ins.contains(k)).collect();
                let (c2, d2) = (outs[0], outs[1]);
                let (ac, ad, bd, bc) = (cross(a, c2), cross(a, d2), cross(b, d2), cross(b, c2));
                triangle(&[ac, ad, bd], spacing, eye, params, cos_c, out);
                triangle(&[ac, bd, bc], spacing, eye, params, cos_c, out);
            }
            _ => {}
        }
    }
}

/// Lexicographic order of positions.
fn before(a: &[f32; 3], b: &[f32; 3]) -> bool {
    (a[0], a[1], a[2]) < (b[0], b[1], b[2])
}

/// The zero segment of `h` over triangle `t`, if h changes sign on it.
fn zero_segment(t: &[Point; 3], h: impl Fn(&Point) -> f32) -> Option<(Point, Point)> {
    let v = [h(&t[0]), h(&t[1]), h(&t[2])];
    let mut ends = Vec::with_capacity(2);
    for (i, j) in [(0, 1), (1, 2), (2, 0)] {
        if (v[i] >= 0.0) != (v[j] >= 0.0) {
            // In a fixed order of the two points (by position), so that the triangle across the
            // edge computes the bit-identical endpoint.
            let (i, j) = if before(&t[i].p, &t[j].p) {
                (i, j)
            } else {
                (j, i)
            };
            ends.push(lerp(&t[i], &t[j], v[i] / (v[i] - v[j])));
        }
    }
    (ends.len() == 2).then(|| (ends[0], ends[1]))
}

fn triangle(
    t: &[Point; 3],
    spacing: [f32; 3],
    eye: Eye,
    params: &LineParams,
    cos_c: f32,
    out: &mut Vec<Segment>,
) {
    let seg = |a: &Point, b: &Point, kind: f32| Segment {
        a: [a.p[0], a.p[1], a.p[2], kind],
        b: [b.p[0], b.p[1], b.p[2], 0.0],
    };
    if params.silhouettes {
        if let Some((a, b)) = zero_segment(t, |p| p.ndotv) {
            out.push(seg(&a, &b, SILHOUETTE));
        }
    }
    if params.suggestive {
        if let Some((a, b)) = zero_segment(t, |p| p.kappa) {
            let phys = |p: [f32; 3]| [p[0] * spacing[0], p[1] * spacing[1], p[2] * spacing[2]];
            let m = lerp(&a, &b, 0.5);
            let x = phys(m.p);
            let n = normalize(m.g.map(|c| -c));
            let v = view_at(eye, x);
            let ndotv = dot(n, v);
            // κ_r's gradient in the triangle's plane, from its three values.
            let (p0, p1, p2) = (phys(t[0].p), phys(t[1].p), phys(t[2].p));
            let e1: [f32; 3] = std::array::from_fn(|i| p1[i] - p0[i]);
            let e2: [f32; 3] = std::array::from_fn(|i| p2[i] - p0[i]);
            let (d1, d2) = (t[1].kappa - t[0].kappa, t[2].kappa - t[0].kappa);
            let (a11, a12, a22) = (dot(e1, e1), dot(e1, e2), dot(e2, e2));
            let det = a11 * a22 - a12 * a12;
            if ndotv > 0.0 && ndotv < cos_c && det > 1e-20 {
                let ca = (d1 * a22 - d2 * a12) / det;
                let cb = (d2 * a11 - d1 * a12) / det;
                let grad: [f32; 3] = std::array::from_fn(|i| ca * e1[i] + cb * e2[i]);
                let w = normalize(std::array::from_fn(|i| v[i] - ndotv * n[i]));
                if dot(grad, w) > params.derivative_threshold {
                    out.push(seg(&a, &b, SUGGESTIVE));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The surface gradient by the plain definition: interior voxel `k * stride` of the linear
    /// interior index, its magnitude, the 90th percentile.
    fn plain_surface_gradient(d: &[u16], [nx, ny, nz]: [usize; 3]) -> Option<f32> {
        let at = |x: usize, y: usize, z: usize| d[x + nx * (y + ny * z)] as f64;
        let inner = (nx - 2) * (ny - 2) * (nz - 2);
        let stride = inner.div_ceil(1 << 20).max(1);
        let mut m: Vec<f32> = (0..inner.div_ceil(stride))
            .filter_map(|k| {
                let i = k * stride;
                let (x, y, z) = (
                    1 + i % (nx - 2),
                    1 + (i / (nx - 2)) % (ny - 2),
                    1 + i / ((nx - 2) * (ny - 2)),
                );
                let g = [
                    at(x + 1, y, z) - at(x - 1, y, z),
                    at(x, y + 1, z) - at(x, y - 1, z),
                    at(x, y, z + 1) - at(x, y, z - 1),
                ];
                let m = 0.5 * (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
                (m > 0.0).then_some(m as f32)
            })
            .collect();
        let k = (m.len() * 9 / 10).min(m.len().checked_sub(1)?);
        Some(*m.select_nth_unstable_by(k, f32::total_cmp).1)
    }

    #[test]
    fn the_surface_gradient_samples_the_voxels_the_plain_definition_does() {
        // 1.1 M interior voxels (every second sampled; rows of odd length, so the sampled x
        // moves from row to row), and 4 k (every one); a hash for content.
        for dims in [[107, 103, 105], [18, 17, 20]] {
            let n = dims[0] * dims[1] * dims[2];
            let d: Vec<u16> = (0..n as u64)
                .map(|i| ((i.wrapping_mul(2_654_435_761) >> 7) % 4000) as u16)
                .collect();
            assert_eq!(surface_gradient(&d, dims), plain_surface_gradient(&d, dims));
        }
        assert_eq!(surface_gradient(&[7u16; 27], [3, 3, 3]), None);
        assert_eq!(surface_gradient(&[7u16; 8], [2, 2, 2]), None);
    }
}
