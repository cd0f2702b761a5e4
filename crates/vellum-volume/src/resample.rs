//! Trilinear resampling to a new grid, voxel centres aligned (the corner voxels map onto each
//! other). Used to bring real scans to the sizes of the papers' benchmark tables.

use crate::{check_dims, Volume, VoxelData};
use rayon::prelude::*;
use vellum_error::Result;

/// The value at `p` (in voxels, voxel i's centre at i) of the grid of `dims` whose voxel i (x
/// fastest) is `value(i)`, by trilinear interpolation, clamped at the edges as a texture's
/// sampler clamps: what a linear filter reads there. Corners of weight 0 are not read.
pub fn trilinear_at(value: impl Fn(usize) -> f64, dims: [usize; 3], p: [f64; 3]) -> f64 {
    let mut lo = [0usize; 3];
    let mut f = [0f64; 3];
    for a in 0..3 {
        let x = p[a].clamp(0.0, (dims[a] - 1) as f64);
        lo[a] = (x.floor() as usize).min(dims[a].saturating_sub(2));
        f[a] = x - lo[a] as f64;
    }
    let mut sum = 0.0;
    for corner in 0..8 {
        let b = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
        let w: f64 = (0..3)
            .map(|a| if b[a] == 1 { f[a] } else { 1.0 - f[a] })
            .product();
        if w > 0.0 {
            let c: [usize; 3] = std::array::from_fn(|a| (lo[a] + b[a]).min(dims[a] - 1));
            sum += w * value(c[0] + dims[0] * (c[1] + dims[1] * c[2]));
        }
    }
    sum
}

/// `v` resampled to `dims` with trilinear interpolation. The physical extent is kept, so the
/// spacing changes; the voxel type is kept (integers are rounded).
pub fn trilinear(v: &Volume, dims: [usize; 3]) -> Result<Volume> {
    check_dims(dims)?;
    let scale: [f64; 3] = std::array::from_fn(|a| {
        if dims[a] > 1 {
            (v.dims[a] - 1) as f64 / (dims[a] - 1) as f64
        } else {
            0.0
        }
    });
    let spacing: [f64; 3] =
        std::array::from_fn(|a| v.spacing[a] * v.dims[a] as f64 / dims[a] as f64);
    let n = dims[0] * dims[1] * dims[2];
    let sample = |i: usize| -> f64 {
        let p = [
            i % dims[0],
            (i / dims[0]) % dims[1],
            i / (dims[0] * dims[1]),
        ];
        let mut lo = [0usize; 3];
        let mut hi = [0usize; 3];
        let mut f = [0f64; 3];
        for a in 0..3 {
            let x = p[a] as f64 * scale[a];
            lo[a] = (x.floor() as usize).min(v.dims[a] - 1);
            hi[a] = (lo[a] + 1).min(v.dims[a] - 1);
            f[a] = x - lo[a] as f64;
        }
        let mut acc = 0.0;
        for corner in 0..8 {
            let pick = |a: usize| {
                if corner >> a & 1 == 1 {
                    (hi[a], f[a])
                } else {
                    (lo[a], 1.0 - f[a])
                }
            };
            let (x, wx) = pick(0);
            let (y, wy) = pick(1);
            let (z, wz) = pick(2);
            let w = wx * wy * wz;
            if w != 0.0 {
                acc += w * v.data.get_f64(v.index(x, y, z));
            }
        }
        acc
    };
    let data = match &v.data {
        VoxelData::U8(_) => VoxelData::U8(
            (0..n)
                .into_par_iter()
                .map(|i| sample(i).round() as u8)
                .collect(),
        ),
        VoxelData::U16(_) => VoxelData::U16(
            (0..n)
                .into_par_iter()
                .map(|i| sample(i).round() as u16)
                .collect(),
        ),
        VoxelData::I16(_) => VoxelData::I16(
            (0..n)
                .into_par_iter()
                .map(|i| sample(i).round() as i16)
                .collect(),
        ),
        VoxelData::F32(_) => {
            VoxelData::F32((0..n).into_par_iter().map(|i| sample(i) as f32).collect())
        }
    };
    // The same box in space: origin and directions are kept.
    Volume::new(dims, spacing, data)?.with_geometry(v.geometry)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_and_linear_ramp() {
        let data: Vec<f32> = (0..4 * 3 * 2).map(|i| (i % 4) as f32).collect();
        let v = Volume::new([4, 3, 2], [1.0; 3], VoxelData::F32(data)).unwrap();
        assert_eq!(trilinear(&v, [4, 3, 2]).unwrap().data, v.data);
        // A ramp along x resampled to 7 samples is still a ramp: 0, 0.5, ..., 3.
        let up = trilinear(&v, [7, 3, 2]).unwrap();
        let VoxelData::F32(d) = &up.data else {
            panic!()
        };
        for (x, value) in d.iter().take(7).enumerate() {
            assert!((value - x as f32 * 0.5).abs() < 1e-6);
        }
    }
}
