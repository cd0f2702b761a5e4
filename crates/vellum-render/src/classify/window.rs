//! The default transfer function, `auto`: the grey ramp over the window where the data's content
//! lies, found from its histogram. The plain `grey` ramp spans the whole data range, so a CT whose
//! air fills most of the volume and whose bone is a few bright voxels renders dim: nearly every
//! voxel sits low on the ramp. `auto` spans instead the 1st to the 99.5th percentile of the voxels
//! above the background, the way a radiology viewer's first window-level does.
//!
//! **Background** is the bottom `BACKGROUND` of the data range (air in CT, noise outside the head
//! in MRI). The percentiles are taken over the remaining voxels, from a 4096-bin histogram.
//! A volume with no voxel above its background (a constant, or a mask of zeros) gets the whole
//! range.
//!
//! **Few distinct values.** A mask or a label volume takes a handful of values, and the
//! percentile window fails on it: a 0/1 mask's content is one level, so the window collapses onto
//! it and the surface, where the gradient is, stays transparent (a ball of radius 20 rendered
//! black, or as a dim blob lit by ambient light alone under `--iso 0.5`); a label volume's lowest
//! labels sit at the window's foot, transparent. Such a volume (`levels`: at most
//! `MAX_LEVELS` distinct values, and integer voxels or a single level above the lowest) gets a
//! window between its lowest value v₀ (the background) and the next one v₁: transparent below
//! v₀ + ¼(v₁ − v₀), opaque white from v₀ + ½(v₁ − v₀) on. Every label, and the boundary of the
//! mask where its gradient is, is then opaque and lit, and `--iso` at the midpoint finds white.
//! A float volume with a few levels above its background (the Shepp–Logan phantom's 0.2, 0.3 and
//! 1) keeps the percentile window: its levels are intensities, to be seen as a CT's are.

use crate::classify::transfer::{ControlPoint, TransferFunction};
use rayon::prelude::*;
use vellum_error::Result;
use vellum_volume::Volume;

/// The name of the default transfer function.
pub const AUTO: &str = "auto";
/// The fraction of the data range, from its minimum up, that counts as background.
pub(crate) const BACKGROUND: f64 = 0.02;
/// The percentiles of the content that bound the window.
pub(crate) const PERCENTILES: [f64; 2] = [0.01, 0.995];
const BINS: usize = 4096;

/// The most distinct values a volume may take to be windowed as a mask or labels.
const MAX_LEVELS: usize = 64;

/// The window [lo, hi] on the normalised range of `range` = [min, max]: between the two lowest
/// values of a mask or a label volume ([`levels`]), else the [`PERCENTILES`] of the voxels of `v`
/// above the background.
pub(crate) fn auto_window(v: &Volume, range: [f64; 2]) -> [f32; 2] {
    let width = range[1] - range[0];
    if width.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return [0.0, 1.0];
    }
    if let Some(levels) = levels(v, range) {
        let discrete = v.voxel_type() != vellum_volume::VoxelType::F32 || levels.len() == 2;
        if discrete && levels.len() >= 2 {
            let (v0, gap) = (levels[0], levels[1] - levels[0]);
            return [v0 + 0.25 * gap, v0 + 0.5 * gap];
        }
    }
    let floor = BACKGROUND * BINS as f64;
    let histogram = v.data.par_fold_f64(
        || vec![0u64; BINS],
        |mut h, value| {
            let x = (value - range[0]) / width * BINS as f64;
            if x.is_finite() && x >= floor {
                h[(x as usize).min(BINS - 1)] += 1;
            }
            h
        },
        |mut a, b| {
            a.iter_mut().zip(&b).for_each(|(a, b)| *a += b);
            a
        },
    );
    let total: u64 = histogram.iter().sum();
    if total == 0 {
        return [0.0, 1.0];
    }
    let at = |p: f64| {
        let target = (p * total as f64).ceil().max(1.0) as u64;
        let mut seen = 0;
        for (i, &c) in histogram.iter().enumerate() {
            seen += c;
            if seen >= target {
                return i;
            }
        }
        BINS - 1
    };
    let (lo, hi) = (at(PERCENTILES[0]), at(PERCENTILES[1]) + 1);
    [
        lo as f32 / BINS as f32,
        (hi as f32 / BINS as f32).max(lo as f32 / BINS as f32 + 1e-3),
    ]
}

/// The distinct values of `v`, normalised over `range` and ascending, when there are at most
/// `MAX_LEVELS` of them; `None` for a volume with more (a scan), found without reading it all.
pub(crate) fn levels(v: &Volume, range: [f64; 2]) -> Option<Vec<f32>> {
    let width = range[1] - range[0];
    (0..v.len())
        .into_par_iter()
        .try_fold(Vec::new, |set, i| {
            add_level(set, ((v.data.get_f64(i) - range[0]) / width) as f32)
        })
        .try_reduce(Vec::new, |a, b| b.into_iter().try_fold(a, add_level))
}

/// `set` (ascending) with `x` in it, or `None` once it holds more than `MAX_LEVELS`.
fn add_level(mut set: Vec<f32>, x: f32) -> Option<Vec<f32>> {
    if let Err(at) = set.binary_search_by(|p| p.total_cmp(&x)) {
        set.insert(at, x);
    }
    (set.len() <= MAX_LEVELS).then_some(set)
}

/// Control points of the ramp across the window.
const RAMP_POINTS: usize = 16;

/// The grey ramp over [lo, hi] of the normalised range: transparent below `lo`; across the
/// window the opacity rises linearly, t = (x − lo) / (hi − lo), and the grey as √t, so that the
/// soft tissue low in the window is lit rather than dark (on three real volumes the content's
/// mean luminance is 2.2–3.6 times that of the plain `grey` ramp, BENCHMARKS.md); opaque white
/// above `hi`.
pub(crate) fn grey_window([lo, hi]: [f32; 2]) -> Result<TransferFunction> {
    let hi = hi.min(1.0);
    // No point twice at one x (the viewer's editor drags one point at a time): the ends of the
    // range get points of their own only outside the window.
    let mut points = Vec::with_capacity(RAMP_POINTS + 3);
    if lo > 0.0 {
        points.push(ControlPoint {
            x: 0.0,
            rgba: [0.0; 4],
        });
    }
    points.extend((0..=RAMP_POINTS).map(|i| {
        let t = i as f32 / RAMP_POINTS as f32;
        let g = t.sqrt();
        ControlPoint {
            x: lo + t * (hi - lo),
            rgba: [g, g, g, t],
        }
    }));
    if hi < 1.0 {
        points.push(ControlPoint {
            x: 1.0,
            rgba: [1.0; 4],
        });
    }
    TransferFunction::new(AUTO, points)
}

/// `auto` for `v`, whose intensities are normalised over `range`.
pub fn auto(v: &Volume, range: [f64; 2]) -> Result<TransferFunction> {
    grey_window(auto_window(v, range))
}

#[cfg(test)]
mod tests {
    use super::*;
    use vellum_volume::VoxelData;

    fn volume(values: Vec<u8>) -> Volume {
        Volume::new([values.len(), 1, 1], [1.0; 3], VoxelData::U8(values)).unwrap()
    }

    #[test]
    fn window_skips_the_background_and_the_outliers() {
        // 90 % air at 0, content spread over 50..150, 0.1 % bright outliers at 255.
        let mut v = vec![0u8; 9000];
        v.extend((0..999).map(|i| 50 + (i % 101) as u8));
        v.push(255);
        let [lo, hi] = auto_window(&volume(v), [0.0, 255.0]);
        assert!((lo * 255.0 - 50.0).abs() < 1.0, "{}", lo * 255.0);
        assert!((hi * 255.0 - 150.0).abs() < 1.0, "{}", hi * 255.0);
        let tf = grey_window([lo, hi]).unwrap();
        let whole = grey_window([0.0, 1.0]).unwrap();
        let xs: Vec<f32> = whole.points.iter().map(|p| p.x).collect();
        assert!(
            xs.windows(2).all(|w| w[0] < w[1]),
            "one point per x: {xs:?}"
        );
        assert_eq!(tf.sample(0.1)[3], 0.0);
        assert!((tf.sample(hi)[3] - 1.0).abs() < 1e-6);
        let mid = tf.sample(0.5 * (lo + hi));
        assert!(
            (mid[3] - 0.5).abs() < 1e-3 && (mid[0] - 0.5f32.sqrt()).abs() < 0.01,
            "{mid:?}"
        );
    }

    #[test]
    fn masks_and_labels_get_a_window_below_their_first_level() {
        // A 0/1 mask, as bytes and as floats: transparent below ¼, opaque white from ½.
        let mask: Vec<u8> = (0..1000).map(|i| u8::from(i % 7 == 0)).collect();
        assert_eq!(auto_window(&volume(mask.clone()), [0.0, 1.0]), [0.25, 0.5]);
        let floats: Vec<f32> = mask.iter().map(|&m| m as f32).collect();
        let f = Volume::new([1000, 1, 1], [1.0; 3], VoxelData::F32(floats)).unwrap();
        assert_eq!(auto_window(&f, [0.0, 1.0]), [0.25, 0.5]);
        let tf = auto(&f, [0.0, 1.0]).unwrap();
        assert_eq!(tf.sample(0.2)[3], 0.0);
        assert_eq!(
            tf.sample(0.5),
            [1.0; 4],
            "the midpoint, where --iso 0.5 is, is white"
        );
        // Labels 0..29: every label above the ramp, label 1 included.
        let labels: Vec<u8> = (0..3000).map(|i| (i % 30) as u8).collect();
        let [lo, hi] = auto_window(&volume(labels), [0.0, 29.0]);
        assert!((lo * 29.0 - 0.25).abs() < 1e-4 && (hi * 29.0 - 0.5).abs() < 1e-4);
        // A float volume with three levels above its background keeps the percentiles.
        let shepp: Vec<f32> = (0..1000).map(|i| [0.0, 0.2, 0.3, 1.0][i % 4]).collect();
        let s = Volume::new([1000, 1, 1], [1.0; 3], VoxelData::F32(shepp)).unwrap();
        assert!((auto_window(&s, [0.0, 1.0])[0] - 0.2).abs() < 1e-3);
        // More than MAX_LEVELS values: a scan, no levels.
        let scan: Vec<u8> = (0..=255).collect();
        assert_eq!(levels(&volume(scan), [0.0, 255.0]), None);
    }

    #[test]
    fn constant_and_empty_volumes_get_the_whole_range() {
        assert_eq!(auto_window(&volume(vec![7; 10]), [7.0, 7.0]), [0.0, 1.0]);
        assert_eq!(auto_window(&volume(vec![0; 10]), [0.0, 255.0]), [0.0, 1.0]);
        assert!(auto(&volume(vec![0; 10]), [0.0, 255.0]).is_ok());
    }
}
