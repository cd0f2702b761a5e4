//! CPU references of the occlusion spectrum (SPEC OS1–OS3): brute-force ambient occlusion, the
//! mean of the visibility mapping M over the voxels of the volume within distance R (voxels outside
//! the volume are left out of sum and count), the Gaussian-weighted variant, and the 2D histogram.

use rayon::prelude::*;

/// M(s) for normalised intensity s: the visibility mappings of SPEC OS2.
#[derive(Clone, Debug, PartialEq)]
pub enum Visibility {
    /// M(s) = s.
    Ramp,
    /// M(s) = clamp((s − t0) / (t1 − t0), 0, 1), cut-offs on the normalised range.
    Truncated {
        /// The lower cut-off.
        t0: f32,
        /// The upper cut-off.
        t1: f32,
    },
    /// M(s) = opacity of a transfer function, 256 entries at the knots i / 255, the nearest taken.
    Table(Vec<f32>),
}

impl Visibility {
    /// M(s), as the shaders compute it.
    pub fn apply(&self, s: f32) -> f32 {
        match self {
            Visibility::Ramp => s.clamp(0.0, 1.0),
            Visibility::Truncated { t0, t1 } => ((s - t0) / (t1 - t0).max(1e-6)).clamp(0.0, 1.0),
            Visibility::Table(t) => t[((s * 255.0 + 0.5).floor() as i64).clamp(0, 255) as usize],
        }
    }
}

/// Σ w·M / Σ w over the voxels of the volume within the box |d|∞ ≤ R around each of `points`,
/// where `weight(dx, dy, dz)` gives w (or `None` to leave the offset out).
fn weighted_mean_at(
    intensity: &[f32],
    dims: [usize; 3],
    m: &Visibility,
    radius: i64,
    points: &[[usize; 3]],
    weight: impl Fn(i64, i64, i64) -> Option<f64> + Sync,
) -> Vec<f64> {
    let mapped: Vec<f64> = intensity.par_iter().map(|&s| m.apply(s) as f64).collect();
    let inside = |c: i64, a: usize| c >= 0 && c < dims[a] as i64;
    points
        .par_iter()
        .map(|&[x, y, z]| {
            let (mut num, mut den) = (0.0f64, 0.0f64);
            for dz in -radius..=radius {
                for dy in -radius..=radius {
                    for dx in -radius..=radius {
                        let (xx, yy, zz) = (x as i64 + dx, y as i64 + dy, z as i64 + dz);
                        if !(inside(xx, 0) && inside(yy, 1) && inside(zz, 2)) {
                            continue;
                        }
                        if let Some(w) = weight(dx, dy, dz) {
                            num += w * mapped
                                [xx as usize + dims[0] * (yy as usize + dims[1] * zz as usize)];
                            den += w;
                        }
                    }
                }
            }
            if den > 0.0 {
                num / den
            } else {
                0.0
            }
        })
        .collect()
}

/// Brute-force ball occlusion at the voxels `points` of `intensity` (normalised, x fastest): the
/// mean of M over the voxels of the volume with |d| ≤ R.
pub fn ball_at(
    intensity: &[f32],
    dims: [usize; 3],
    m: &Visibility,
    radius: i64,
    points: &[[usize; 3]],
) -> Vec<f64> {
    let r2 = radius * radius;
    weighted_mean_at(intensity, dims, m, radius, points, |dx, dy, dz| {
        (dx * dx + dy * dy + dz * dz <= r2).then_some(1.0)
    })
}

/// Gaussian-weighted occlusion at `points`: w = exp(−|d|²/2σ²), σ = R/3, over |d|∞ ≤ R (separable,
/// as the GPU passes).
pub fn gaussian_at(
    intensity: &[f32],
    dims: [usize; 3],
    m: &Visibility,
    radius: i64,
    points: &[[usize; 3]],
) -> Vec<f64> {
    let sigma = (radius as f64 / 3.0).max(1e-3);
    let w = |d: i64| (-(d * d) as f64 / (2.0 * sigma * sigma)).exp();
    weighted_mean_at(intensity, dims, m, radius, points, |dx, dy, dz| {
        Some(w(dx) * w(dy) * w(dz))
    })
}

/// The occlusion spectrum: counts of (intensity bin, occlusion bin), row-major by occlusion bin.
/// `occlusion` may be coarser than `intensity` by `stride` (voxel p reads occlusion p / stride).
pub fn spectrum(
    intensity: &[f32],
    dims: [usize; 3],
    occlusion: &[f32],
    out_dims: [usize; 3],
    stride: usize,
    bins: [usize; 2],
) -> Vec<u32> {
    let mut counts = vec![0u32; bins[0] * bins[1]];
    for (i, &s) in intensity.iter().enumerate() {
        let (x, y, z) = (
            i % dims[0],
            (i / dims[0]) % dims[1],
            i / (dims[0] * dims[1]),
        );
        let o = occlusion[x / stride + out_dims[0] * (y / stride + out_dims[1] * (z / stride))];
        let bx = ((s * bins[0] as f32) as i64).clamp(0, bins[0] as i64 - 1) as usize;
        let by = ((o * bins[1] as f32) as i64).clamp(0, bins[1] as i64 - 1) as usize;
        counts[by * bins[0] + bx] += 1;
    }
    counts
}
