//! Voxels mapped linearly onto 0..=65535, the texels the renderer samples: the one conversion
//! every volume takes on its way to the GPU, in core (the whole volume) and through the brick
//! cache (each chunk a loader decodes).
//!
//! The arithmetic is the f64 of [`normalise_one`], voxel for voxel, so that the two ways onto
//! the GPU give the same texels. Written as a plain loop without a branch or a saturating cast
//! per voxel, it vectorises; where the CPU has AVX2 it runs at twice the width. On the 2048³
//! phantom's frame through the brick cache, the loaders' conversion took as much CPU as their
//! decoding (BENCHMARKS.md, fourteenth round).

use crate::VoxelData;

/// `v` normalised by `lo` and `scale` (65535 over the range): clamped to 0..=65535 and rounded
/// to nearest (adding a half and truncating rounds values ≥ 0 as `round` does). NaN maps to 0.
#[inline(always)]
pub fn normalise_one(v: f64, lo: f64, scale: f64) -> u16 {
    // `max` takes the number where one side is NaN, so NaN goes to 0, as a saturating cast takes
    // it (`clamp` keeps NaN). The value is then within 0.5..=65535.5.
    #[allow(clippy::manual_clamp)]
    let y = ((v - lo) * scale).max(0.0).min(65535.0) + 0.5;
    // SAFETY: `y` is finite and within 0.5..=65535.5 (above), so it fits an i32.
    (unsafe { y.to_int_unchecked::<i32>() }) as u16
}

/// The scale of the range `[lo, hi]` for [`normalise_one`]: 0 for an empty range, which maps
/// every voxel to 0.
pub fn scale_of([lo, hi]: [f64; 2]) -> f64 {
    if hi > lo {
        65535.0 / (hi - lo)
    } else {
        0.0
    }
}

/// The loop over one slice, inlined into each caller below so that each is compiled for its
/// own instruction set.
#[inline(always)]
fn kernel<T: Copy + Into<f64>>(src: &[T], lo: f64, scale: f64, out: &mut [u16]) {
    for (o, &v) in out.iter_mut().zip(src) {
        *o = normalise_one(v.into(), lo, scale);
    }
}

/// [`kernel`] compiled for AVX2.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn kernel_avx2<T: Copy + Into<f64>>(src: &[T], lo: f64, scale: f64, out: &mut [u16]) {
    kernel(src, lo, scale, out)
}

/// `src` normalised into `out` (as long as `src`), on the calling thread.
fn slice<T: Copy + Into<f64>>(src: &[T], lo: f64, scale: f64, out: &mut [u16]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above).
        return unsafe { kernel_avx2(src, lo, scale, out) };
    }
    kernel(src, lo, scale, out)
}

/// Voxels per task of [`normalised_par`]: enough to amortise a task, few enough to spread a
/// volume over every core.
const TASK: usize = 1 << 16;

impl VoxelData {
    /// Every voxel normalised by `lo` and `scale` ([`normalise_one`]), on the calling thread
    /// (for work that is already one of many threads', such as a brick loader's).
    pub fn normalised(&self, lo: f64, scale: f64) -> Vec<u16> {
        let mut out = vec![0u16; self.len()];
        match self {
            VoxelData::U8(s) => slice(s, lo, scale, &mut out),
            VoxelData::U16(s) => slice(s, lo, scale, &mut out),
            VoxelData::I16(s) => slice(s, lo, scale, &mut out),
            VoxelData::F32(s) => slice(s, lo, scale, &mut out),
        }
        out
    }

    /// [`VoxelData::normalised`] in parallel on every core, in order.
    pub fn normalised_par(&self, lo: f64, scale: f64) -> Vec<u16> {
        use rayon::prelude::*;
        fn par<T: Copy + Into<f64> + Sync>(s: &[T], lo: f64, scale: f64, out: &mut [u16]) {
            out.par_chunks_mut(TASK)
                .zip(s.par_chunks(TASK))
                .for_each(|(o, s)| slice(s, lo, scale, o));
        }
        let mut out = vec![0u16; self.len()];
        match self {
            VoxelData::U8(s) => par(s, lo, scale, &mut out),
            VoxelData::U16(s) => par(s, lo, scale, &mut out),
            VoxelData::I16(s) => par(s, lo, scale, &mut out),
            VoxelData::F32(s) => par(s, lo, scale, &mut out),
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What the renderer's normalisation has always been: `round` after the clamp, through a
    /// saturating cast.
    fn plain(v: f64, [lo, hi]: [f64; 2]) -> u16 {
        ((v - lo) * scale_of([lo, hi])).round().clamp(0.0, 65535.0) as u16
    }

    #[test]
    fn the_loops_give_what_rounding_each_voxel_gives() {
        let range = [-0.1, 1.3];
        let mut values: Vec<f32> = (0..100_003)
            .map(|i| (i as f32 * 0.000_017_3 - 0.3) * 1.1)
            .collect();
        values.extend([f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.1, 1.3, 0.0]);
        let data = VoxelData::F32(values.clone());
        let (lo, scale) = (range[0], scale_of(range));
        let want: Vec<u16> = values.iter().map(|&v| plain(v as f64, range)).collect();
        assert_eq!(data.normalised(lo, scale), want);
        assert_eq!(data.normalised_par(lo, scale), want);
        let n = values.len();
        assert_eq!(want[n - 6..n - 3], [0, 65535, 0], "NaN, +inf, -inf");
        assert_eq!(want[n - 3..], [0, 65535, 4681]);
    }

    #[test]
    fn every_type_normalises_and_an_empty_range_gives_zero() {
        let i16s = VoxelData::I16(vec![-1000, 0, 1000, 3000]);
        let range = [-1000.0, 3000.0];
        let want: Vec<u16> = [-1000.0, 0.0, 1000.0, 3000.0]
            .iter()
            .map(|&v| plain(v, range))
            .collect();
        assert_eq!(i16s.normalised(range[0], scale_of(range)), want);
        assert_eq!(want, [0, 16384, 32768, 65535]);
        let u8s = VoxelData::U8(vec![0, 7, 255]);
        assert_eq!(
            u8s.normalised(0.0, scale_of([0.0, 255.0])),
            [0, 1799, 65535]
        );
        let u16s = VoxelData::U16(vec![5, 9]);
        assert_eq!(u16s.normalised(5.0, scale_of([5.0, 5.0])), [0, 0]);
    }

    #[test]
    fn adding_a_half_and_truncating_rounds_as_round_does() {
        for range in [
            [0.0, 1.0],
            [-1024.0, 3071.0],
            [0.0, 255.0],
            [0.25, 0.75],
            [7.0, 7.0],
        ] {
            let scale = scale_of(range);
            let span = range[1] - range[0];
            for i in -1000..=1_001_000 {
                let v = range[0] + span * i as f64 / 1e6;
                assert_eq!(
                    normalise_one(v, range[0], scale),
                    plain(v, range),
                    "{v} in {range:?}"
                );
            }
            // Exact halves of a step.
            for k in 0..65535 {
                let v = range[0] + (k as f64 + 0.5) / scale.max(1e-300);
                assert_eq!(normalise_one(v, range[0], scale), plain(v, range), "{v}");
            }
        }
    }
}
