//! CPU reference of the Sobel gradient (SPEC TL1): central difference (−1, 0, 1) along an axis,
//! smoothed by (1, 2, 1) along the other two, divided by 32 so that a unit ramp has a unit
//! gradient, then divided by the voxel spacing. Borders are clamped. f64 throughout.

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

#[cfg(test)]
mod tests {
    use super::*;

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
