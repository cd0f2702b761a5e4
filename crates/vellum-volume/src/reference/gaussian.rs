//! CPU reference for the spatial importance map (SPEC IM1, paper eq. 1): a separable Gaussian blur
//! with f64 accumulation, then ΔD = G∗V − V. It is written for clarity and checked independently of
//! the GPU code; rayon keeps it usable on real volumes.

use crate::Volume;
use rayon::prelude::*;
use vellum_error::{Error, Result};

/// The normalised 1D kernel for radius `radius_voxels`: σ = R/3, taps −R..R sampled at voxel
/// centres, scaled to sum 1 (paper §3.2).
pub fn gaussian_kernel(radius_voxels: u32) -> Result<Vec<f64>> {
    if radius_voxels == 0 {
        return Err(Error::Invalid(
            "the Gaussian radius must be at least 1 voxel (σ = R/3)".into(),
        ));
    }
    let r = radius_voxels as i64;
    let sigma = radius_voxels as f64 / 3.0;
    let raw: Vec<f64> = (-r..=r)
        .map(|k| (-(k * k) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = raw.iter().sum();
    Ok(raw.into_iter().map(|w| w / sum).collect())
}

/// Convolves `data` (x fastest) along `axis` with `kernel`, clamping at the borders.
pub(crate) fn convolve_axis(
    data: &[f64],
    dims: [usize; 3],
    axis: usize,
    kernel: &[f64],
) -> Vec<f64> {
    let r = (kernel.len() / 2) as i64;
    let stride = [1, dims[0], dims[0] * dims[1]][axis];
    let n = dims[axis] as i64;
    let mut out = vec![0.0; data.len()];
    // Each output slice along z is independent for x and y passes; for z, split by voxel instead.
    out.par_chunks_mut(dims[0])
        .enumerate()
        .for_each(|(row, out_row)| {
            let y = row % dims[1];
            let z = row / dims[1];
            for (x, o) in out_row.iter_mut().enumerate() {
                let c = [x, y, z][axis] as i64;
                let base = x + dims[0] * (y + dims[1] * z) - c as usize * stride;
                let mut acc = 0.0;
                for (i, w) in kernel.iter().enumerate() {
                    let q = (c + i as i64 - r).clamp(0, n - 1) as usize;
                    acc += w * data[base + q * stride];
                }
                *o = acc;
            }
        });
    out
}

/// The Gaussian blur G∗V of `v` with radius `radius_voxels`, as f64.
pub(crate) fn gaussian_blur(v: &Volume, radius_voxels: u32) -> Result<Vec<f64>> {
    let kernel = gaussian_kernel(radius_voxels)?;
    let mut data: Vec<f64> = (0..v.len())
        .into_par_iter()
        .map(|i| v.data.get_f64(i))
        .collect();
    for axis in 0..3 {
        data = convolve_axis(&data, v.dims, axis, &kernel);
    }
    Ok(data)
}

/// ΔD = G∗V − V (paper eq. 1), in f64.
pub fn importance_map(v: &Volume, radius_voxels: u32) -> Result<Vec<f64>> {
    let mut blurred = gaussian_blur(v, radius_voxels)?;
    blurred
        .par_iter_mut()
        .enumerate()
        .for_each(|(i, b)| *b -= v.data.get_f64(i));
    Ok(blurred)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::VoxelData;

    #[test]
    fn kernel_is_normalised_and_symmetric() {
        for r in [1, 5, 10] {
            let k = gaussian_kernel(r).unwrap();
            assert_eq!(k.len(), 2 * r as usize + 1);
            assert!((k.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            for i in 0..k.len() {
                assert_eq!(k[i], k[k.len() - 1 - i]);
            }
        }
        // R = 1: σ = 1/3, so the side taps are exp(-4.5) relative to the centre.
        let k = gaussian_kernel(1).unwrap();
        assert!((k[0] / k[1] - (-4.5f64).exp()).abs() < 1e-12);
        assert!(gaussian_kernel(0).is_err());
    }

    #[test]
    fn constant_volume_has_zero_map() {
        let v = Volume::new([7, 5, 3], [1.0; 3], VoxelData::F32(vec![3.5; 105])).unwrap();
        let dd = importance_map(&v, 2).unwrap();
        assert!(dd.iter().all(|d| d.abs() < 1e-12));
    }

    #[test]
    fn step_edge_gives_signed_map() {
        // A step along x: the low side near the edge blurs upwards (positive ΔD), the high side
        // downwards (negative), as the paper's Fig. 2 describes.
        let dims = [16, 2, 2];
        let data: Vec<f32> = (0..64)
            .map(|i| if i % 16 < 8 { 0.0 } else { 1.0 })
            .collect();
        let v = Volume::new(dims, [1.0; 3], VoxelData::F32(data)).unwrap();
        let dd = importance_map(&v, 3).unwrap();
        assert!(dd[7] > 0.0 && dd[8] < 0.0);
        assert!(dd[0].abs() < 1e-12 && dd[15].abs() < 1e-12);
    }
}
