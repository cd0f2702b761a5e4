//! FM6: the transfer function of a feature volume, built from its feature map. This is all the
//! renderer needs to colour migrated features: no tag volume, no special shader code.
//!
//! The function lives on the feature volume's normalised range, like every transfer function
//! (0 = its minimum, 1 = its maximum). It has one band per private interval and one for the
//! context (the unmigrated data, [`FeatureMap::context_range`]):
//! - the context is a faint grey whose opacity ramps from 0 (the lowest tenth of the context range,
//!   usually background) up to `CONTEXT_OPACITY`;
//! - each feature has its colour at `FEATURE_OPACITY` per voxel across its interval;
//! - bands begin with a step exactly at their lower edge, and end with a step halfway across the gap
//!   to the next band (the last one holds to 1). Fuzzy-boundary voxels that eq. 5 shifted a little
//!   past the top of an interval thus keep their feature's colour, and the gaps stay transparent
//!   where it matters: between the context and a feature's lower edge.
//!
//! A feature narrower than `MIN_FEATURE_WIDTH` (a segmentation of one intensity has an interval
//! of zero width) is widened downwards into its gap, never past the gap's middle, so that the
//! renderer's 256-entry table still has bins of its colour. Transparent points carry the colour of
//! the band next to them, so texture filtering across a step never blends in black.

use crate::classify::transfer::{ControlPoint, TransferFunction};
use vellum_error::{Error, Result};
use vellum_volume::feature::FeatureMap;

/// Opacity per voxel-length sample inside a feature's interval.
pub(crate) const FEATURE_OPACITY: f32 = 0.8;
/// Opacity per voxel-length sample at the top of the context range.
pub(crate) const CONTEXT_OPACITY: f32 = 0.03;
/// Colour of the context.
pub(crate) const CONTEXT_GREY: [f32; 3] = [0.8, 0.8, 0.8];
/// Narrowest feature band on the normalised range: two bins of the 256-entry table the renderer
/// samples the function into.
pub(crate) const MIN_FEATURE_WIDTH: f32 = 2.0 / 256.0;

/// A band of the function on the normalised range.
struct Band {
    lo: f32,
    hi: f32,
    rgb: [f32; 3],
    context: bool,
}

/// Checks `map` and the feature volume's data range: finite, with min < max.
pub(crate) fn check(map: &FeatureMap, [r0, r1]: [f64; 2]) -> Result<()> {
    map.validate()?;
    if !(r0.is_finite() && r1.is_finite() && r0 < r1) {
        return Err(Error::Invalid(format!(
            "data range [{r0}, {r1}] is invalid; expected the feature volume's finite [min, max] with min < max"
        )));
    }
    Ok(())
}

/// The transfer function that gives every feature of `map` its colour, on the normalised range of
/// a feature volume whose data range is `data_range` = [min, max].
pub fn feature_transfer_function(
    map: &FeatureMap,
    data_range: [f64; 2],
) -> Result<TransferFunction> {
    check(map, data_range)?;
    let [r0, r1] = data_range;
    let width = r1 - r0;
    let norm = |v: f64| (((v - r0) / width).clamp(0.0, 1.0)) as f32;
    let tolerance = 1e-6 * width;

    let mut features = map.features();
    features.sort_by(|a, b| a.1.interval[0].total_cmp(&b.1.interval[0]));
    let mut bands = Vec::with_capacity(features.len() + 1);
    let [c0, c1] = map.context_range;
    if c1 > c0 && c1 > r0 {
        bands.push(Band {
            lo: norm(c0),
            hi: norm(c1),
            rgb: CONTEXT_GREY,
            context: true,
        });
    }
    for (_, f) in &features {
        let [lo, hi] = f.interval;
        if lo < r0 - tolerance || hi > r1 + tolerance {
            return Err(Error::Invalid(format!(
                "feature '{}' has interval [{lo}, {hi}] outside the volume's range [{r0}, {r1}]; expected the feature volume this map was saved with",
                f.label
            )));
        }
        bands.push(Band {
            lo: norm(lo),
            hi: norm(hi),
            rgb: f.color,
            context: false,
        });
    }

    let point = |x: f32, rgb: [f32; 3], a: f32| ControlPoint {
        x,
        rgba: [rgb[0], rgb[1], rgb[2], a],
    };
    let mut points = Vec::with_capacity(4 * bands.len() + 1);
    let mut floor = 0.0f32;
    for (k, b) in bands.iter().enumerate() {
        let end = bands.get(k + 1).map_or(1.0, |n| 0.5 * (b.hi + n.lo));
        let top = if b.context {
            points.push(point(b.lo, b.rgb, 0.0));
            points.push(point(b.lo + 0.1 * (b.hi - b.lo), b.rgb, 0.0));
            points.push(point(b.hi, b.rgb, CONTEXT_OPACITY));
            CONTEXT_OPACITY
        } else {
            let lo = b.lo.min(end - MIN_FEATURE_WIDTH).max(floor);
            points.push(point(lo, b.rgb, 0.0));
            points.push(point(lo, b.rgb, FEATURE_OPACITY));
            FEATURE_OPACITY
        };
        floor = end;
        points.push(point(end, b.rgb, top));
        if end < 1.0 {
            points.push(point(end, b.rgb, 0.0));
        }
    }
    if points.is_empty() {
        points.push(point(0.0, CONTEXT_GREY, 0.0));
    }
    TransferFunction::new("features", points)
}

#[cfg(test)]
mod tests {
    use super::*;
    use vellum_volume::feature::Feature;

    fn map() -> FeatureMap {
        let mut m = FeatureMap::new([0.0, 255.0]);
        let f = |label: &str, interval, color| Feature {
            label: label.into(),
            description: String::new(),
            interval,
            color,
            source_range: None,
        };
        m.append(f("skull", [300.0, 500.0], [1.0, 0.9, 0.6]), Some("bones"))
            .unwrap();
        m.append(f("valve", [600.0, 900.0], [0.2, 0.5, 1.0]), None)
            .unwrap();
        m
    }

    #[test]
    fn features_get_their_colours_with_sharp_steps() {
        let tf = feature_transfer_function(&map(), [0.0, 1000.0]).unwrap();
        let at = |v: f32| tf.sample(v / 1000.0);
        // Each interval, edges included, has its colour at full feature opacity.
        for v in [300.0, 400.0, 500.0] {
            assert_eq!(at(v), [1.0, 0.9, 0.6, FEATURE_OPACITY], "{v}");
        }
        for v in [600.0, 750.0, 900.0, 1000.0] {
            assert_eq!(at(v), [0.2, 0.5, 1.0, FEATURE_OPACITY], "{v}");
        }
        // Steps: transparent just below each lower edge, and in the gaps past the halfway point.
        assert_eq!(at(299.99)[3], 0.0);
        assert_eq!(at(599.99)[3], 0.0);
        assert_eq!(at(560.0)[3], 0.0);
        assert_eq!(at(540.0)[3], FEATURE_OPACITY);
        // Context: a faint grey ramp, transparent at the bottom, transparent again above it.
        assert_eq!(at(10.0)[3], 0.0);
        let mid = at(150.0);
        assert!(mid[3] > 0.0 && mid[3] < CONTEXT_OPACITY, "{mid:?}");
        assert_eq!(&mid[..3], &CONTEXT_GREY);
        assert!((at(255.0)[3] - CONTEXT_OPACITY).abs() < 1e-6);
        assert_eq!(at(290.0)[3], 0.0);
        // The 256-entry table the renderer uploads resolves the steps to one bin.
        let table = tf.table(256);
        let bin = |v: f32| table[(v / 1000.0 * 255.0).round() as usize];
        assert_eq!(bin(400.0), [1.0, 0.9, 0.6, FEATURE_OPACITY]);
        assert_eq!(bin(280.0)[3], 0.0);
    }

    #[test]
    fn steps_are_pairs_of_points_with_equal_x() {
        let tf = feature_transfer_function(&map(), [0.0, 1000.0]).unwrap();
        let xs: Vec<f32> = tf.points.iter().map(|p| p.x).collect();
        assert!(xs.windows(2).all(|w| w[0] <= w[1]), "{xs:?}");
        let at_lo: Vec<_> = tf.points.iter().filter(|p| p.x == 0.3).collect();
        assert_eq!(at_lo.len(), 2);
        assert_eq!((at_lo[0].rgba[3], at_lo[1].rgba[3]), (0.0, FEATURE_OPACITY));
        assert_eq!(at_lo[0].rgba[..3], at_lo[1].rgba[..3], "no dark fringe");
    }

    #[test]
    fn edge_cases() {
        let e = feature_transfer_function(&map(), [0.0, 255.0])
            .unwrap_err()
            .to_string();
        assert!(e.contains("expected the feature volume"), "{e}");
        let e = feature_transfer_function(&map(), [5.0, 5.0])
            .unwrap_err()
            .to_string();
        assert!(e.contains("min < max"), "{e}");
        // A zero-width interval at the very top (a one-intensity segmentation) keeps table bins.
        let mut one = FeatureMap::new([0.0, 0.75]);
        one.append(
            Feature {
                label: "core".into(),
                description: String::new(),
                interval: [0.7875, 0.7875],
                color: [1.0, 0.0, 0.0],
                source_range: None,
            },
            None,
        )
        .unwrap();
        let table = feature_transfer_function(&one, [0.0, 0.7875])
            .unwrap()
            .table(256);
        assert_eq!(table[255], [1.0, 0.0, 0.0, FEATURE_OPACITY]);
        assert_eq!(table[254], [1.0, 0.0, 0.0, FEATURE_OPACITY]);
        assert_eq!(table[250][3], 0.0);
        // An empty map gives the context alone.
        let tf = feature_transfer_function(&FeatureMap::new([0.0, 255.0]), [0.0, 255.0]).unwrap();
        assert!(tf.sample(1.0)[3] > 0.0);
    }
}
