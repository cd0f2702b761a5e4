//! Ambient occlusion by FFT convolution (issue 16, SPEC OS1 at the paper's large radii).
//!
//! O = (M ∗ K) / (1_V ∗ K): the numerator is the visibility M convolved with the neighbourhood
//! kernel K (the ball of radius R, or the separable Gaussian); the denominator is the kernel weight
//! that falls inside the volume, because neighbours outside are left out of sum and count. The
//! cost of the numerator does not depend on R.
//!
//! - **Padding.** Along each axis the volume of N voxels is zero-padded to P ≥ N + reach, with
//!   reach = min(R, N − 1) (offsets beyond N − 1 never land in the volume, so the kernel is cut
//!   there). P is the next size whose prime factors are 2, 3 and 5. Then circular convolution
//!   equals linear convolution at every voxel of the volume.
//! - **Kernel spectrum.** K is real and even, so its DFT is real: one f32 per frequency of the
//!   half spectrum. It is computed once per (kernel, P) and cached by the caller.
//! - **Denominator.** It is never transformed. Along an axis, the kernel's in-volume extent at x
//!   depends only on (min(x, reach), min(N − 1 − x, reach)): at most 2·reach + 1 classes, and one
//!   class for the whole interior. `Denominator` tabulates the exact weight for every triple of
//!   classes (integer counts for the ball, by 2D prefix sums over (dy, dz); products of 1D sums for
//!   the separable Gaussian). That is exact, where a transform of 1_V would carry FFT round-off
//!   into every division, and it costs well under a transform.
//! - **Stride.** The convolution runs at full resolution and the output samples it at o · stride:
//!   the same "exact at each sampled voxel" promise as the runs method, at the cost of a full
//!   resolution transform (which does not grow with R, while a downsampled grid would change the
//!   neighbourhood's shape).

pub(crate) mod cpu;
pub mod gpu;

use crate::classify::mapping::Neighbourhood;
use rayon::prelude::*;
use vellum_error::{Error, Result};

/// The neighbourhood kernel of one occlusion computation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kernel {
    /// Weight 1 where |d| ≤ R.
    Ball(u32),
    /// Weight exp(−|d|²/2σ²), σ = R/3, where |d|∞ ≤ R (the separable passes' kernel).
    Gaussian(u32),
}

impl Kernel {
    /// The kernel of `neighbourhood` with radius R = `radius` in voxels.
    pub fn new(neighbourhood: Neighbourhood, radius: u32) -> Self {
        match neighbourhood {
            Neighbourhood::Ball => Kernel::Ball(radius),
            Neighbourhood::Gaussian => Kernel::Gaussian(radius),
        }
    }

    /// Its radius R in voxels.
    pub fn radius(&self) -> u32 {
        match *self {
            Kernel::Ball(r) | Kernel::Gaussian(r) => r,
        }
    }

    /// The 1D weight of the separable Gaussian at offset d.
    fn gauss(r: u32, d: i64) -> f64 {
        let sigma = (r as f64 / 3.0).max(1e-3);
        (-((d * d) as f64) / (2.0 * sigma * sigma)).exp()
    }

    /// K at offset (dx, dy, dz).
    pub(crate) fn weight(&self, d: [i64; 3]) -> f32 {
        match *self {
            Kernel::Ball(r) => {
                let r = r as i64;
                (d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= r * r) as u8 as f32
            }
            Kernel::Gaussian(r) => {
                if d.iter().any(|&c| c.abs() > r as i64) {
                    0.0
                } else {
                    (Self::gauss(r, d[0]) * Self::gauss(r, d[1]) * Self::gauss(r, d[2])) as f32
                }
            }
        }
    }
}

/// How far the kernel reaches along an axis of n voxels: offsets beyond n − 1 never land inside.
pub(crate) fn reach(radius: u32, n: usize) -> usize {
    (radius as usize).min(n.saturating_sub(1))
}

/// The smallest size ≥ n whose prime factors are 2, 3 and 5.
pub(crate) fn smooth_size(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut k = m;
        for p in [2, 3, 5] {
            while k.is_multiple_of(p) {
                k /= p;
            }
        }
        if k == 1 {
            return m;
        }
        m += 1;
    }
}

/// The padded transform size for `dims` and `radius`: P ≥ N + reach per axis, 2·3·5-smooth.
pub fn padded_dims(dims: [usize; 3], radius: u32) -> [usize; 3] {
    dims.map(|n| smooth_size(n + reach(radius, n)))
}

/// Checks that `pad` is large enough for `dims` and `radius` (a sweep may share a larger one).
pub(crate) fn check_pad(dims: [usize; 3], pad: [usize; 3], radius: u32) -> Result<()> {
    for a in 0..3 {
        if pad[a] < dims[a] + reach(radius, dims[a]) || smooth_size(pad[a]) != pad[a] {
            return Err(Error::Invalid(format!(
                "padded size {pad:?} cannot hold a radius-{radius} convolution of {dims:?}"
            )));
        }
    }
    Ok(())
}

/// The exact denominator 1_V ∗ K, tabulated over per-axis boundary classes:
/// `den(x, y, z) = table[cx[x] + nx·(cy[y] + ny·cz[z])]`.
#[derive(Clone, Debug)]
pub(crate) struct Denominator {
    /// Class of each coordinate, per axis.
    pub(crate) class: [Vec<u32>; 3],
    /// Number of classes per axis.
    pub(crate) classes: [usize; 3],
    /// The in-volume kernel weight of every triple of classes, the x class fastest.
    pub table: Vec<f32>,
}

/// Per axis: each coordinate's class, and each class's (lo, hi) offset range.
type AxisClasses = (Vec<u32>, Vec<(usize, usize)>);

/// Per axis: the class of each coordinate and each class's in-volume offset range, as the
/// unordered pair (lo, hi) with lo ≤ hi: the kernel is symmetric, so [−a, b] and [−b, a] weigh
/// the same, which halves the classes near a border shared by both ends.
fn axis_classes(n: usize, reach: usize) -> AxisClasses {
    let mut ids = Vec::with_capacity(n);
    let mut ranges: Vec<(usize, usize)> = Vec::new();
    let mut index = std::collections::HashMap::new();
    for x in 0..n {
        let (a, b) = (x.min(reach), (n - 1 - x).min(reach));
        let key = (a.min(b), a.max(b));
        let id = *index.entry(key).or_insert_with(|| {
            ranges.push(key);
            ranges.len() - 1
        });
        ids.push(id as u32);
    }
    (ids, ranges)
}

/// Entries of the denominator table for `dims` and `radius`.
pub fn denominator_entries(dims: [usize; 3], radius: u32) -> usize {
    dims.iter()
        .map(|&n| axis_classes(n, reach(radius, n)).1.len())
        .product()
}

/// floor(sqrt(n)), exact for integers.
fn isqrt(n: i64) -> i64 {
    let mut r = (n as f64).sqrt() as i64;
    while r * r > n {
        r -= 1;
    }
    while (r + 1) * (r + 1) <= n {
        r += 1;
    }
    r
}

impl Denominator {
    /// Tabulates the exact denominator of `kernel` for a volume of `dims` voxels.
    pub fn new(dims: [usize; 3], kernel: Kernel) -> Self {
        let r = kernel.radius();
        let axes: [AxisClasses; 3] = [0, 1, 2].map(|a| axis_classes(dims[a], reach(r, dims[a])));
        let classes = [axes[0].1.len(), axes[1].1.len(), axes[2].1.len()];
        let (rx, ry, rz) = (&axes[0].1, &axes[1].1, &axes[2].1);
        let table: Vec<f32> = match kernel {
            Kernel::Gaussian(r) => {
                let sums = |ranges: &[(usize, usize)]| -> Vec<f64> {
                    ranges
                        .iter()
                        .map(|&(lo, hi)| {
                            (-(lo as i64)..=hi as i64)
                                .map(|d| Kernel::gauss(r, d))
                                .sum()
                        })
                        .collect()
                };
                let (sx, sy, sz) = (sums(rx), sums(ry), sums(rz));
                let mut t = Vec::with_capacity(classes.iter().product());
                for z in &sz {
                    for y in &sy {
                        for x in &sx {
                            t.push((x * y * z) as f32);
                        }
                    }
                }
                t
            }
            Kernel::Ball(r) => {
                // For each x class: T(dy, dz) = the x-extent of the ball's run at (dy, dz) within
                // [−lo, hi], and its 2D prefix sums; every (y, z) class pair is then a rectangle.
                let r = r as i64;
                let (ey, ez) = (
                    reach(r as u32, dims[1]) as i64,
                    reach(r as u32, dims[2]) as i64,
                );
                let (wy, wz) = ((2 * ey + 1) as usize, (2 * ez + 1) as usize);
                let per_x: Vec<Vec<u64>> = rx
                    .par_iter()
                    .map(|&(lo, hi)| {
                        // prefix[(j + 1) + (wy + 1)·(k + 1)] = Σ T over dy index ≤ j, dz index ≤ k
                        let mut prefix = vec![0u64; (wy + 1) * (wz + 1)];
                        for k in 0..wz {
                            let dz = k as i64 - ez;
                            let mut row = 0u64;
                            for j in 0..wy {
                                let dy = j as i64 - ey;
                                let r2 = r * r - dy * dy - dz * dz;
                                if r2 >= 0 {
                                    let w = isqrt(r2);
                                    row += (w.min(lo as i64) + w.min(hi as i64) + 1) as u64;
                                }
                                prefix[(j + 1) + (wy + 1) * (k + 1)] =
                                    prefix[(j + 1) + (wy + 1) * k] + row;
                            }
                        }
                        let rect = |y0: usize, y1: usize, z0: usize, z1: usize| {
                            // inclusive index ranges [y0, y1] × [z0, z1]
                            let p = |j: usize, k: usize| prefix[j + (wy + 1) * k];
                            p(y1 + 1, z1 + 1) + p(y0, z0) - p(y0, z1 + 1) - p(y1 + 1, z0)
                        };
                        let mut out = Vec::with_capacity(ry.len() * rz.len());
                        for &(zlo, zhi) in rz {
                            for &(ylo, yhi) in ry {
                                let (y0, y1) = ((ey as usize) - ylo, ey as usize + yhi);
                                let (z0, z1) = ((ez as usize) - zlo, ez as usize + zhi);
                                out.push(rect(y0, y1, z0, z1));
                            }
                        }
                        out
                    })
                    .collect();
                let mut t = vec![0f32; classes.iter().product()];
                for (cx, col) in per_x.iter().enumerate() {
                    for (yz, &n) in col.iter().enumerate() {
                        t[cx + classes[0] * yz] = n as f32;
                    }
                }
                t
            }
        };
        let [a, b, c] = axes;
        Denominator {
            class: [a.0, b.0, c.0],
            classes,
            table,
        }
    }

    /// The denominator at voxel (x, y, z).
    #[inline]
    pub fn at(&self, x: usize, y: usize, z: usize) -> f32 {
        let [cx, cy, cz] = [&self.class[0][x], &self.class[1][y], &self.class[2][z]];
        self.table[*cx as usize + self.classes[0] * (*cy as usize + self.classes[1] * *cz as usize)]
    }
}

/// Bytes the CPU method holds at its peak for `dims` padded to `pad`: the data spectrum, the
/// kernel spectrum, the sampled-plane inverse, the mapped input, the output and the denominator.
pub fn cpu_bytes(dims: [usize; 3], pad: [usize; 3], stride: usize, den_entries: usize) -> u64 {
    let half = (pad[0] / 2 + 1) as u64;
    let plane = half * pad[1] as u64;
    let volume = dims.iter().map(|&d| d as u64).product::<u64>() * 4;
    plane * pad[2] as u64 * 8
        + plane * pad[2] as u64 * 4
        + plane * dims[2].div_ceil(stride) as u64 * 8
        + 2 * volume
        + den_entries as u64 * 4
}

/// Refuses a CPU FFT whose working memory (`cpu_bytes`) exceeds `available`, in one sentence
/// with both figures.
pub fn check_cpu_memory(
    dims: [usize; 3],
    pad: [usize; 3],
    stride: usize,
    available: Option<u64>,
) -> Result<()> {
    let need = cpu_bytes(dims, pad, stride, denominator_entries_for_pad(dims, pad));
    match available {
        Some(have) if need > have => Err(Error::Invalid(format!(
            "`method` fft-cpu would need {:.0} MiB of memory for {dims:?} padded to {pad:?} but {:.0} MiB are available; use a smaller `radius`",
            need as f64 / 1048576.0,
            have as f64 / 1048576.0
        ))),
        _ => Ok(()),
    }
}

/// Denominator entries at the largest radius `pad` can serve.
fn denominator_entries_for_pad(dims: [usize; 3], pad: [usize; 3]) -> usize {
    (0..3)
        .map(|a| {
            axis_classes(dims[a], (pad[a] - dims[a]).min(dims[a].saturating_sub(1)))
                .1
                .len()
        })
        .product()
}

/// Memory this machine has available (MemAvailable), where the system says.
pub(crate) fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Σ K(d) over the offsets that land inside the volume, by brute force.
    fn brute(dims: [usize; 3], kernel: Kernel, p: [usize; 3]) -> f64 {
        let r = kernel.radius() as i64;
        let mut sum = 0.0;
        for dz in -r..=r {
            for dy in -r..=r {
                for dx in -r..=r {
                    let q = [p[0] as i64 + dx, p[1] as i64 + dy, p[2] as i64 + dz];
                    if (0..3).all(|a| q[a] >= 0 && q[a] < dims[a] as i64) {
                        sum += kernel.weight([dx, dy, dz]) as f64;
                    }
                }
            }
        }
        sum
    }

    #[test]
    fn denominator_is_the_in_volume_kernel_weight_at_every_voxel() {
        for dims in [[7, 5, 3], [20, 12, 7], [1, 9, 4]] {
            for r in [1, 2, 5, 12] {
                for kernel in [Kernel::Ball(r), Kernel::Gaussian(r)] {
                    let den = Denominator::new(dims, kernel);
                    for z in 0..dims[2] {
                        for y in 0..dims[1] {
                            for x in 0..dims[0] {
                                let want = brute(dims, kernel, [x, y, z]);
                                let got = den.at(x, y, z) as f64;
                                assert!(
                                    (got - want).abs() <= 1e-6 * want.max(1.0),
                                    "{dims:?} {kernel:?} at {:?}: {got} != {want}",
                                    [x, y, z]
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn classes_are_few_and_padding_is_smooth_and_sufficient() {
        // The interior is one class; each border adds at most `reach` more.
        assert_eq!(denominator_entries([256, 256, 256], 64), 65 * 65 * 65);
        assert_eq!(denominator_entries([256, 256, 256], 0), 1);
        for n in [1usize, 7, 41, 98, 256, 301, 324] {
            for r in [1u32, 8, 64, 100, 1024] {
                let p = smooth_size(n + reach(r, n));
                assert!(p >= n + reach(r, n));
                assert!(check_pad([n, n, n], [p, p, p], r).is_ok());
            }
        }
        assert_eq!(smooth_size(257), 270);
        assert_eq!(padded_dims([256, 256, 256], 64), [320, 320, 320]);
    }
}
