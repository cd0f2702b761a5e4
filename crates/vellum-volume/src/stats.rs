//! Summary statistics of a volume: range, mean and histogram, for `vellum info` and for choosing
//! transfer-function domains. Non-finite float voxels are counted and otherwise ignored, so one
//! NaN cannot poison the range.

use rayon::prelude::*;
use serde::Serialize;

use super::{Volume, VoxelData};

/// Voxels per parallel task.
const CHUNK: usize = 1 << 16;

/// Range, mean and histogram of the finite voxels.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Stats {
    /// Smallest finite voxel (0 when there is none).
    pub min: f64,
    /// Largest finite voxel (0 when there is none).
    pub max: f64,
    /// Mean of the finite voxels (0 when there is none).
    pub mean: f64,
    /// Counts in equal-width bins over `[min, max]`; the last bin includes `max`.
    pub histogram: Vec<u64>,
    /// NaN and infinite voxels, left out of everything above.
    pub(crate) non_finite: usize,
}

/// The smallest and largest finite value of `v` ([+∞, −∞] when it has none).
///
/// Each voxel type is read as itself, not through a per-voxel conversion: the store writers
/// range every chunk they write, every channel and level, and the loop by `get_f64` with
/// `f64::min` was a tenth of a chunked pass's CPU time.
pub fn value_range(v: &Volume) -> [f64; 2] {
    match &v.data {
        VoxelData::U8(s) => whole_range(s),
        VoxelData::U16(s) => whole_range(s),
        VoxelData::I16(s) => whole_range(s),
        VoxelData::F32(s) => finite_range(s),
    }
}

/// The range of integer voxels (all finite).
fn whole_range<T: Copy + Ord + Into<f64>>(s: &[T]) -> [f64; 2] {
    let Some(&first) = s.first() else {
        return [f64::INFINITY, f64::NEG_INFINITY];
    };
    let (lo, hi) = s
        .iter()
        .fold((first, first), |(lo, hi), &x| (lo.min(x), hi.max(x)));
    [lo.into(), hi.into()]
}

/// Lanes [`finite_range`] keeps apart: each lane's compare and select is independent of the
/// others', which the compiler turns into vector instructions (one chain through a single
/// minimum it may not reorder).
const LANES: usize = 16;

/// The range of the finite values of `s` ([+∞, −∞] when there is none).
fn finite_range(s: &[f32]) -> [f64; 2] {
    let mut lo = [f32::INFINITY; LANES];
    let mut hi = [f32::NEG_INFINITY; LANES];
    let mut blocks = s.chunks_exact(LANES);
    for b in &mut blocks {
        for i in 0..LANES {
            // NaN and ±∞ fail `< ∞` and take no part.
            let (x, finite) = (b[i], b[i].abs() < f32::INFINITY);
            lo[i] = if finite && x < lo[i] { x } else { lo[i] };
            hi[i] = if finite && x > hi[i] { x } else { hi[i] };
        }
    }
    let rest = blocks.remainder().iter().filter(|x| x.is_finite());
    let (lo, hi) = lo
        .into_iter()
        .chain(rest.clone().copied())
        .zip(hi.into_iter().chain(rest.copied()))
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), (a, b)| {
            (l.min(a), h.max(b))
        });
    [lo as f64, hi as f64]
}

/// Computes [`Stats`] with `bins` histogram bins (none when `bins` is 0).
pub fn stats(volume: &Volume, bins: usize) -> Stats {
    match &volume.data {
        VoxelData::U8(v) => stats_of(v, bins),
        VoxelData::U16(v) => stats_of(v, bins),
        VoxelData::I16(v) => stats_of(v, bins),
        VoxelData::F32(v) => stats_of(v, bins),
    }
}

fn stats_of<T: Copy + Into<f64> + Sync>(values: &[T], bins: usize) -> Stats {
    #[derive(Clone, Copy)]
    struct Acc {
        min: f64,
        max: f64,
        sum: f64,
        finite: usize,
    }
    let empty = Acc {
        min: f64::INFINITY,
        max: f64::NEG_INFINITY,
        sum: 0.0,
        finite: 0,
    };
    // Chunks keep the per-task accumulators (one histogram each) few.
    let acc = values
        .par_chunks(CHUNK)
        .map(|chunk| {
            chunk.iter().fold(empty, |a, &x| {
                let x: f64 = x.into();
                if !x.is_finite() {
                    return a;
                }
                Acc {
                    min: a.min.min(x),
                    max: a.max.max(x),
                    sum: a.sum + x,
                    finite: a.finite + 1,
                }
            })
        })
        .reduce(
            || empty,
            |a, b| Acc {
                min: a.min.min(b.min),
                max: a.max.max(b.max),
                sum: a.sum + b.sum,
                finite: a.finite + b.finite,
            },
        );
    let non_finite = values.len() - acc.finite;
    if acc.finite == 0 {
        return Stats {
            min: 0.0,
            max: 0.0,
            mean: 0.0,
            histogram: vec![0; bins],
            non_finite,
        };
    }
    let (min, max) = (acc.min, acc.max);
    let scale = if max > min {
        bins as f64 / (max - min)
    } else {
        0.0
    };
    let histogram = if bins == 0 {
        Vec::new()
    } else {
        values
            .par_chunks(CHUNK)
            .map(|chunk| {
                let mut h = vec![0u64; bins];
                for &x in chunk {
                    let x: f64 = x.into();
                    if x.is_finite() {
                        h[(((x - min) * scale) as usize).min(bins - 1)] += 1;
                    }
                }
                h
            })
            .reduce(
                || vec![0u64; bins],
                |mut a, b| {
                    a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                    a
                },
            )
    };
    Stats {
        min,
        max,
        mean: acc.sum / acc.finite as f64,
        histogram,
        non_finite,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The range folds lane by lane, and the remainder on its own: against a plain fold, for
    /// lengths around the lanes, with NaN and infinities that take no part, and for each type.
    #[test]
    fn the_range_is_the_plain_folds() {
        let plain = |v: &Volume| {
            (0..v.len())
                .map(|i| v.data.get_f64(i))
                .filter(|x| x.is_finite())
                .fold([f64::INFINITY, f64::NEG_INFINITY], |r, x| {
                    [r[0].min(x), r[1].max(x)]
                })
        };
        let mut state = 7u32;
        let mut next = move || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            state
        };
        for n in [0, 1, 15, 16, 17, 33, 1000] {
            let f: Vec<f32> = (0..n)
                .map(|i| match next() % 11 {
                    0 if i % 3 == 0 => f32::NAN,
                    1 if i % 5 == 0 => f32::INFINITY,
                    2 if i % 7 == 0 => f32::NEG_INFINITY,
                    r => (next() % 2000) as f32 / 7.0 - 100.0 + r as f32,
                })
                .collect();
            let u16s: Vec<u16> = (0..n).map(|_| next() as u16).collect();
            let i16s: Vec<i16> = (0..n).map(|_| next() as i16).collect();
            let u8s: Vec<u8> = (0..n).map(|_| next() as u8).collect();
            for data in [
                VoxelData::F32(f),
                VoxelData::U16(u16s),
                VoxelData::I16(i16s),
                VoxelData::U8(u8s),
            ] {
                let v = Volume::new([n, 1, 1], [1.0; 3], data).unwrap_or_else(|_| {
                    Volume::new([1, 1, 1], [1.0; 3], VoxelData::U8(vec![3])).unwrap()
                });
                assert_eq!(
                    value_range(&v),
                    plain(&v),
                    "{n} voxels of {:?}",
                    v.voxel_type()
                );
            }
        }
        // Nothing finite: the empty range.
        let nan = Volume::new([20, 1, 1], [1.0; 3], VoxelData::F32(vec![f32::NAN; 20])).unwrap();
        assert_eq!(value_range(&nan), [f64::INFINITY, f64::NEG_INFINITY]);
    }
}
