//! CPU reference of the Sobel gradient (SPEC TL1): central difference (−1, 0, 1) along an axis,
//! smoothed by (1, 2, 1) along the other two, divided by 32 so that a unit ramp has a unit
//! gradient, then divided by the voxel spacing. Borders are clamped. f64 throughout.
//!
//! [`sobel_at`] is the reference of the gradient the ray caster makes at a sample when a volume's
//! gradients are not stored (`shade.glsl`'s `sobel_at`): the same operator on the trilinear
//! reconstruction, which is the trilinear interpolation of [`sobel_gradient`].

use rayon::prelude::*;

/// Gradient (x, y, z, length) of `data` (x fastest) for every voxel.
pub fn sobel_gradient(data: &[f64], dims: [usize; 3], spacing: [f64; 3]) -> Vec<[f64; 4]> {
    let [nx, ny, nz] = dims;
    let at = |x: i64, y: i64, z: i64| {
        let c = |v: i64, n: usize| v.clamp(0, n as i64 - 1) as usize;
        data[c(x, nx) + nx * (c(y, ny) + ny * c(z, nz))]
    };
    (0..nx * ny * nz)
        .into_par_iter()
        .map(|i| {
            let (x, y, z) = (
                (i % nx) as i64,
                ((i / nx) % ny) as i64,
                (i / (nx * ny)) as i64,
            );
            let mut g = [0.0f64; 3];
            for dz in -1i64..=1 {
                for dy in -1i64..=1 {
                    for dx in -1i64..=1 {
                        let v = at(x + dx, y + dy, z + dz);
                        let w = [2 - dx.abs(), 2 - dy.abs(), 2 - dz.abs()].map(|w| w as f64);
                        g[0] += v * dx as f64 * w[1] * w[2];
                        g[1] += v * dy as f64 * w[0] * w[2];
                        g[2] += v * dz as f64 * w[0] * w[1];
                    }
                }
            }
            let g = [
                g[0] / (32.0 * spacing[0]),
                g[1] / (32.0 * spacing[1]),
                g[2] / (32.0 * spacing[2]),
            ];
            [
                g[0],
                g[1],
                g[2],
                (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt(),
            ]
        })
        .collect()
}

/// The value of `data` (x fastest, of `dims`) at `p` in voxel units (voxel i's centre at i), by
/// trilinear interpolation with the borders clamped, as a texture's linear filter reads it.
pub fn trilinear(data: &[f64], dims: [usize; 3], p: [f64; 3]) -> f64 {
    crate::resample::trilinear_at(|i| data[i], dims, p)
}

/// The Sobel gradient (x, y, z, length) at `p` in voxel units made from the trilinear
/// reconstruction of `data`: the operator's 26 weights times the reconstruction at whole voxels
/// from `p`. Shifting the reconstruction by whole voxels commutes with it, so inside the volume
/// this is the trilinear interpolation of [`sobel_gradient`] at `p` (in its outer half voxel,
/// where both clamp, the two may differ).
pub fn sobel_at(data: &[f64], dims: [usize; 3], spacing: [f64; 3], p: [f64; 3]) -> [f64; 4] {
    let mut g = [0.0f64; 3];
    for k in 0..27 {
        let o = [k % 3, (k / 3) % 3, k / 9].map(|v| v as f64 - 1.0);
        let w = o.map(|v| 2.0 - v.abs());
        let v = trilinear(data, dims, std::array::from_fn(|a| p[a] + o[a]));
        g[0] += v * o[0] * w[1] * w[2];
        g[1] += v * o[1] * w[0] * w[2];
        g[2] += v * o[2] * w[0] * w[1];
    }
    let g: [f64; 3] = std::array::from_fn(|a| g[a] / (32.0 * spacing[a]));
    [
        g[0],
        g[1],
        g[2],
        (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// At every voxel's centre, borders included, the gradient made at a sample is the stored
    /// one; between the centres, away from the borders, it is the trilinear interpolation of the
    /// stored ones (to rounding).
    #[test]
    fn the_gradient_at_a_sample_is_the_stored_ones_interpolated() {
        let dims = [7, 6, 5];
        let spacing = [1.0, 0.5, 2.0];
        let data: Vec<f64> = (0..dims.iter().product::<usize>())
            .map(|i| {
                let (x, y, z) = (i % 7, (i / 7) % 6, i / 42);
                ((x * 31 + y * 17 + z * 7) % 11) as f64 / 11.0
            })
            .collect();
        let stored = sobel_gradient(&data, dims, spacing);
        for (i, want) in stored.iter().enumerate() {
            let p = [i % 7, (i / 7) % 6, i / 42].map(|v| v as f64);
            let got = sobel_at(&data, dims, spacing, p);
            for a in 0..4 {
                assert!((got[a] - want[a]).abs() < 1e-12, "{i}: {got:?} {want:?}");
            }
        }
        for p in [[3.3, 2.7, 2.4], [1.5, 1.5, 1.5], [4.9, 1.1, 2.0]] {
            let got = sobel_at(&data, dims, spacing, p);
            for a in 0..3 {
                let axis: Vec<f64> = stored.iter().map(|g| g[a]).collect();
                let want = trilinear(&axis, dims, p);
                assert!(
                    (got[a] - want).abs() < 1e-12,
                    "{p:?} axis {a}: {got:?} against {want}"
                );
            }
        }
    }

    #[test]
    fn unit_ramp_has_unit_gradient_scaled_by_spacing() {
        let dims = [5, 4, 3];
        let data: Vec<f64> = (0..60).map(|i| ((i / 5) % 4) as f64).collect(); // ramp along y
        let g = sobel_gradient(&data, dims, [1.0, 2.0, 1.0]);
        let inner = 2 + 5 * (1 + 4);
        assert!((g[inner][1] - 0.5).abs() < 1e-12, "{:?}", g[inner]);
        assert!(g[inner][0].abs() < 1e-12 && g[inner][2].abs() < 1e-12);
        assert!((g[inner][3] - 0.5).abs() < 1e-12);
    }
}
