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
pub fn value_range(v: &Volume) -> [f64; 2] {
    let mut r = [f64::INFINITY, f64::NEG_INFINITY];
    for i in 0..v.len() {
        let x = v.data.get_f64(i);
        if x.is_finite() {
            r = [r[0].min(x), r[1].max(x)];
        }
    }
    r
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
