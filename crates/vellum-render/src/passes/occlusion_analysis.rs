//! Analyses built on the occlusion pass: adaptive mapping selection (SPEC OS6) and radius
//! sensitivity (SPEC OS7).
//!
//! **Selection.** For an intensity interval of interest, every candidate truncated ramp
//! (t0, t1) is scored without recomputing occlusion.
//!
//! - The local histogram of each voxel's ball neighbourhood (K intensity bins) comes from K
//!   occlusion passes, one per bin, with the bin's indicator as the visibility mapping.
//! - For any mapping M, O(x) = Σ_k h_k(x) · M(c_k), where c_k is the bin centre, as the paper's
//!   eq. 4 puts it (occlusion is the centroid of the weighted local histogram).
//! - The occlusion values of the interval's voxels are clustered by 1D k-means, k = 2..4.
//! - A candidate's score is its largest variance of cluster means, weighted by cluster size.
//! - The candidate with the largest score wins.

use crate::passes::occlusion::{
    normalised_f32, Method, Neighbourhood, Occlusion, OcclusionInput, OcclusionParams,
};
use rayon::prelude::*;
use serde::Serialize;
use vellum_error::{Error, Result};
use vellum_volume::reference::occlusion::Visibility;
use vellum_volume::{Volume, VoxelData};

/// One scored candidate mapping.
#[derive(Clone, Debug, Serialize)]
pub struct Candidate {
    /// Cut-offs as fractions of the data range.
    pub t0: f64,
    /// Upper cut-off as a fraction of the data range, above `t0`: the ramp reaches 1 there.
    pub t1: f64,
    /// The same in data units.
    pub t0_value: f64,
    /// `t1` in data units.
    pub t1_value: f64,
    /// Largest variance of cluster means over k = 2..4, and the k that gave it.
    pub score: f64,
    /// The number of clusters, 2..=4, that gave `score`.
    pub k: usize,
    /// Cluster means (occlusion) for that k, ascending.
    pub means: Vec<f64>,
}

/// The result of `occlusion-select`.
#[derive(Clone, Debug, Serialize)]
pub struct Selection {
    /// The intensity interval of interest [lo, hi], in data units.
    pub interval: [f64; 2],
    /// Occlusion radius in voxels.
    pub radius: u32,
    /// Output stride of the occlusion passes: only every `stride`-th voxel per axis is scored.
    pub stride: u32,
    /// K, the number of intensity bins of the local histograms (one occlusion pass each).
    pub(crate) histogram_bins: usize,
    /// How many voxels of the output grid lie in `interval`: the values that were clustered.
    pub voxels_in_interval: usize,
    /// The highest-scoring candidate.
    pub best: Candidate,
    /// Every candidate ramp (cut-offs on a 1/8 grid of the range), highest score first.
    pub candidates: Vec<Candidate>,
}

/// For output voxel `o` of a grid coarser by `stride`: its (x, y, z) and the linear index of the
/// input voxel it samples.
fn sampled_voxel(o: usize, out_dims: [usize; 3], dims: [usize; 3], stride: usize) -> usize {
    let (x, y, z) = (
        o % out_dims[0],
        (o / out_dims[0]) % out_dims[1],
        o / (out_dims[0] * out_dims[1]),
    );
    (x * stride).min(dims[0] - 1)
        + dims[0] * ((y * stride).min(dims[1] - 1) + dims[1] * (z * stride).min(dims[2] - 1))
}

/// Ball occlusion of the uploaded volume with `visibility`, at the output grid of `stride`, as
/// plain values.
fn ball_occlusion(
    occ: &mut Occlusion,
    input: &OcclusionInput,
    radius: u32,
    visibility: Visibility,
    stride: u32,
    method: Method,
    pad: Option<[usize; 3]>,
) -> Result<Vec<f32>> {
    let p = OcclusionParams {
        radius,
        visibility,
        neighbourhood: Neighbourhood::Ball,
        stride,
        spectrum_bins: None,
        method,
        pad,
    };
    match occ.compute_on(input, &p)?.occlusion.data {
        VoxelData::F32(o) => Ok(o),
        _ => unreachable!("occlusion is float"),
    }
}

/// 1D k-means with deterministic quantile initialisation; returns (means ascending, counts).
pub(crate) fn kmeans_1d(values: &[f64], k: usize) -> (Vec<f64>, Vec<usize>) {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    if n == 0 || k == 0 {
        return (Vec::new(), Vec::new());
    }
    let mut means: Vec<f64> = (0..k)
        .map(|i| sorted[((2 * i + 1) * n / (2 * k)).min(n - 1)])
        .collect();
    let mut counts = vec![0usize; k];
    for _ in 0..100 {
        let mut sums = vec![0.0; k];
        counts.iter_mut().for_each(|c| *c = 0);
        for &v in &sorted {
            let j = (0..k)
                .min_by(|&a, &b| (v - means[a]).abs().total_cmp(&(v - means[b]).abs()))
                .unwrap_or(0);
            sums[j] += v;
            counts[j] += 1;
        }
        let next: Vec<f64> = (0..k)
            .map(|j| {
                if counts[j] > 0 {
                    sums[j] / counts[j] as f64
                } else {
                    means[j]
                }
            })
            .collect();
        let moved = next.iter().zip(&means).any(|(a, b)| (a - b).abs() > 1e-12);
        means = next;
        if !moved {
            break;
        }
    }
    let mut order: Vec<usize> = (0..k).collect();
    order.sort_by(|&a, &b| means[a].total_cmp(&means[b]));
    (
        order.iter().map(|&j| means[j]).collect(),
        order.iter().map(|&j| counts[j]).collect(),
    )
}

/// Variance of cluster means, weighted by cluster size (the between-cluster variance).
pub(crate) fn variance_of_means(means: &[f64], counts: &[usize]) -> f64 {
    let n: usize = counts.iter().sum();
    if n == 0 {
        return 0.0;
    }
    let mean = means
        .iter()
        .zip(counts)
        .map(|(m, &c)| m * c as f64)
        .sum::<f64>()
        / n as f64;
    means
        .iter()
        .zip(counts)
        .map(|(m, &c)| c as f64 * (m - mean).powi(2))
        .sum::<f64>()
        / n as f64
}

/// Adaptive mapping selection for the interval `[lo, hi]` (data units).
pub fn select(
    occ: &mut Occlusion,
    v: &Volume,
    interval: [f64; 2],
    radius: u32,
    stride: u32,
    method: Method,
) -> Result<Selection> {
    const BINS: usize = 16;
    crate::passes::occlusion::check_radius_stride(radius, stride)?;
    let (intensity, range) = normalised_f32(v);
    let span = range[1] - range[0];
    if span <= 0.0 {
        return Err(Error::Invalid(
            "the volume is constant; there is nothing to classify".into(),
        ));
    }
    let norm = |x: f64| (x - range[0]) / span;
    let (lo, hi) = (norm(interval[0]) as f32, norm(interval[1]) as f32);
    if lo.is_nan() || hi.is_nan() || lo > hi || hi < 0.0 || lo > 1.0 {
        return Err(Error::Invalid(format!(
            "interval {}:{} lies outside the data range {}..{}; expected LO <= HI within it",
            interval[0], interval[1], range[0], range[1]
        )));
    }
    // The voxels of interest: in the interval, at the output grid points.
    let s = stride as usize;
    let out_dims: [usize; 3] = v.dims.map(|d| d.div_ceil(s));
    let picks: Vec<(usize, usize)> = (0..out_dims[0] * out_dims[1] * out_dims[2])
        .filter_map(|o| {
            let i = sampled_voxel(o, out_dims, v.dims, s);
            (intensity[i] >= lo && intensity[i] <= hi).then_some((o, i))
        })
        .collect();
    if picks.len() < 4 {
        return Err(Error::Invalid(format!(
            "only {} voxels fall in the interval; expected at least 4 to cluster",
            picks.len()
        )));
    }
    // Local histograms: h[k][voxel] for the picked voxels.
    let mut hist = vec![vec![0f32; picks.len()]; BINS];
    // One upload serves all the passes.
    let input = OcclusionInput::upload(occ.context(), v)?;
    let progress = crate::progress::bar(BINS as u64, "local histograms");
    for (k, h) in hist.iter_mut().enumerate() {
        progress.inc(1);
        let table: Vec<f32> = (0..256)
            .map(|t| if t * BINS / 256 == k { 1.0 } else { 0.0 })
            .collect();
        let o = ball_occlusion(
            occ,
            &input,
            radius,
            Visibility::Table(table),
            stride,
            method,
            None,
        )?;
        for (j, &(oi, _)) in picks.iter().enumerate() {
            h[j] = o[oi];
        }
    }
    let centre = |k: usize| (k as f64 + 0.5) / BINS as f64;
    let steps: Vec<f64> = (0..=8).map(|i| i as f64 / 8.0).collect();
    let pairs: Vec<(f64, f64)> = steps
        .iter()
        .flat_map(|&a| steps.iter().filter(move |&&b| b > a).map(move |&b| (a, b)))
        .collect();
    let mut candidates: Vec<Candidate> = pairs
        .par_iter()
        .map(|&(t0, t1)| {
            let m: Vec<f64> = (0..BINS)
                .map(|k| ((centre(k) - t0) / (t1 - t0)).clamp(0.0, 1.0))
                .collect();
            let values: Vec<f64> = (0..picks.len())
                .map(|j| (0..BINS).map(|k| hist[k][j] as f64 * m[k]).sum())
                .collect();
            let (mut best, mut best_k, mut best_means) = (-1.0, 2, Vec::new());
            for k in 2..=4 {
                let (means, counts) = kmeans_1d(&values, k);
                let score = variance_of_means(&means, &counts);
                if score > best {
                    (best, best_k, best_means) = (score, k, means);
                }
            }
            Candidate {
                t0,
                t1,
                t0_value: range[0] + t0 * span,
                t1_value: range[0] + t1 * span,
                score: best,
                k: best_k,
                means: best_means,
            }
        })
        .collect();
    candidates.sort_by(|a, b| b.score.total_cmp(&a.score));
    let best = candidates[0].clone();
    Ok(Selection {
        interval,
        radius,
        stride,
        histogram_bins: BINS,
        voxels_in_interval: picks.len(),
        best,
        candidates,
    })
}

/// One point of the sensitivity plot.
#[derive(Clone, Debug, Serialize)]
pub struct SensitivityRow {
    /// Occlusion radius in voxels.
    pub radius: u32,
    /// Index of the intensity band, from 0 at the low end of the data range.
    pub band: usize,
    /// Lower edge of the band, in data units.
    pub(crate) band_lo: f64,
    /// Upper edge of the band, in data units.
    pub(crate) band_hi: f64,
    /// How many voxels of the output grid fall in the band.
    pub voxels: usize,
    /// Sample variance of their occlusion (ramp mapping, ball); 0 with fewer than 2 voxels.
    pub variance: f64,
}

/// Most intensity bands of a sensitivity plot.
pub(crate) const MAX_BANDS: usize = 1024;
/// Most radii of a sensitivity plot.
pub(crate) const MAX_RADII: usize = 64;

/// Variance of occlusion (ramp mapping, ball) within each of `bands` intensity bands, for each
/// radius (SPEC OS7, paper Fig. 6). Band edges are in data units.
pub fn sensitivity(
    occ: &mut Occlusion,
    v: &Volume,
    radii: &[u32],
    bands: usize,
    stride: u32,
    method: Method,
) -> Result<Vec<SensitivityRow>> {
    if bands == 0 || bands > MAX_BANDS {
        return Err(Error::Invalid(format!(
            "{bands} intensity bands are invalid; expected 1..={MAX_BANDS}"
        )));
    }
    if radii.is_empty() || radii.len() > MAX_RADII {
        return Err(Error::Invalid(format!(
            "{} radii are invalid; expected 1..={MAX_RADII}",
            radii.len()
        )));
    }
    // Radii first: an automatic stride follows from them, so it must not take the blame.
    for &r in radii {
        crate::passes::occlusion::check_radius_stride(r, 1)?;
    }
    crate::passes::occlusion::check_radius_stride(1, stride)?;
    let (intensity, range) = normalised_f32(v);
    let s = stride as usize;
    let out_dims: [usize; 3] = v.dims.map(|d| d.div_ceil(s));
    let mut rows = Vec::new();
    let input = OcclusionInput::upload(occ.context(), v)?;
    // One padded size for the whole sweep (the largest radius's), so the FFT methods transform the
    // data once and only the kernel changes.
    let largest = radii.iter().copied().max().unwrap_or(1);
    let pad = Some(crate::passes::occlusion_fft::padded_dims(v.dims, largest));
    let progress = crate::progress::bar(radii.len() as u64, "radii");
    for &radius in radii {
        progress.inc(1);
        let o = ball_occlusion(occ, &input, radius, Visibility::Ramp, stride, method, pad)?;
        let mut acc = vec![(0usize, 0.0f64, 0.0f64); bands];
        for (oi, &occl) in o.iter().enumerate() {
            let i = sampled_voxel(oi, out_dims, v.dims, s);
            let b = ((intensity[i] * bands as f32) as usize).min(bands - 1);
            let a = &mut acc[b];
            a.0 += 1;
            a.1 += occl as f64;
            a.2 += (occl as f64).powi(2);
        }
        let span = range[1] - range[0];
        for (b, (n, sum, sq)) in acc.into_iter().enumerate() {
            let variance = if n > 1 {
                (sq - sum * sum / n as f64) / (n - 1) as f64
            } else {
                0.0
            };
            rows.push(SensitivityRow {
                radius,
                band: b,
                band_lo: range[0] + span * b as f64 / bands as f64,
                band_hi: range[0] + span * (b + 1) as f64 / bands as f64,
                voxels: n,
                variance: variance.max(0.0),
            });
        }
    }
    Ok(rows)
}

/// Writes the sensitivity rows as CSV, atomically.
pub fn write_sensitivity_csv(rows: &[SensitivityRow], path: &std::path::Path) -> Result<()> {
    use std::io::Write;
    vellum_volume::output::write_atomic(path, |w| {
        writeln!(w, "radius,band,band_lo,band_hi,voxels,variance")?;
        for r in rows {
            writeln!(
                w,
                "{},{},{},{},{},{}",
                r.radius, r.band, r.band_lo, r.band_hi, r.voxels, r.variance
            )?;
        }
        Ok(())
    })
}

/// The sensitivity rows as a line plot: variance against radius, one line per band.
pub fn sensitivity_plot(rows: &[SensitivityRow]) -> crate::plot::Canvas {
    use crate::plot::{axes, Canvas, PALETTE};
    let radii: Vec<u32> = {
        let mut r: Vec<u32> = rows.iter().map(|r| r.radius).collect();
        r.dedup();
        r
    };
    let bands = rows.iter().map(|r| r.band).max().map_or(0, |b| b + 1);
    let (w, h, left, top) = (560usize, 360usize, 56usize, 14usize);
    let mut c = Canvas::new(w + left + 16 + 110, h + top + 44, [255, 255, 255]);
    let vmax = rows
        .iter()
        .map(|r| r.variance)
        .fold(0.0, f64::max)
        .max(1e-12);
    let (rmin, rmax) = (
        *radii.first().unwrap_or(&0) as f64,
        *radii.last().unwrap_or(&1) as f64,
    );
    let px = |r: f64| {
        left as i64
            + if rmax > rmin {
                ((r - rmin) / (rmax - rmin) * (w - 1) as f64) as i64
            } else {
                0
            }
    };
    let py = |v: f64| (top + h - 1) as i64 - (v / vmax * (h - 1) as f64) as i64;
    for b in 0..bands {
        let col = PALETTE[b % PALETTE.len()];
        let pts: Vec<(i64, i64)> = rows
            .iter()
            .filter(|r| r.band == b)
            .map(|r| (px(r.radius as f64), py(r.variance)))
            .collect();
        for seg in pts.windows(2) {
            c.line(seg[0], seg[1], col);
        }
        for &(x, y) in &pts {
            c.rect(x - 2, y - 2, 5, 5, col);
        }
        if let Some(r) = rows.iter().find(|r| r.band == b) {
            let ly = (top + 10 + b * 12) as i64;
            c.rect((left + w + 20) as i64, ly, 10, 5, col);
            c.text(
                (left + w + 34) as i64,
                ly,
                &format!("{:.0}-{:.0}", r.band_lo, r.band_hi),
                1,
                [30, 30, 30],
            );
        }
    }
    axes(
        &mut c,
        (left, top, w, h),
        "RADIUS",
        [rmin, rmax],
        "VARIANCE",
        [0.0, vmax],
    );
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kmeans_finds_two_groups() {
        let v: Vec<f64> = (0..50)
            .map(|i| 0.1 + (i % 5) as f64 * 0.001)
            .chain((0..30).map(|i| 0.7 + (i % 3) as f64 * 0.001))
            .collect();
        let (means, counts) = kmeans_1d(&v, 2);
        assert!((means[0] - 0.102).abs() < 1e-3 && (means[1] - 0.701).abs() < 1e-3);
        assert_eq!(counts, vec![50, 30]);
        assert!(variance_of_means(&means, &counts) > 0.08);
        assert_eq!(variance_of_means(&[0.5], &[10]), 0.0);
    }
}
