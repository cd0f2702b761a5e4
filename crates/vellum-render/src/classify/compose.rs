//! A feature map composed with an occlusion transfer function, in one classification: the
//! migrated features take their colours on their private intervals (FM6), and the occlusion
//! transfer function classifies the rest, the unmigrated context, by intensity and occlusion
//! (OS4). Both papers' classifications thus meet in one 256 × 256 table over the feature
//! volume's (intensity, occlusion), and nothing in the shaders changes.
//!
//! The occlusion transfer function is written for the original data: its intensity axis is the
//! normalised range of the volume before migration, which is the map's `context_range`. On the
//! feature volume's wider range, an intensity bin at data value v is classified by:
//! - **context** (c0 ≤ v ≤ c1): the occlusion TF at u = (v − c0) / (c1 − c0), linear between its
//!   intensity bins, row by row of occlusion;
//! - **above the context**: the feature transfer function's entry, whatever the occlusion: a
//!   feature's colour across its band, transparent in the gaps (see [`super::features`]).
//!
//! The occlusion volume must be the original data's, so that the context is classified by the
//! occlusion the transfer function was designed on. Migration moved each feature's voxels up by
//! Δ = interval_low − source_low (eq. 4, 5), so [`composed_visibility`] maps a feature volume's
//! value back to the original intensity before the occlusion TF's visibility mapping applies.
//! A feature without a `source_range` (older maps) occludes as the top of the context range.

use crate::classify::features::feature_transfer_function;
use crate::classify::otf::TABLE_SIZE;
use vellum_error::{Error, Result};
use vellum_volume::feature::FeatureMap;
use vellum_volume::reference::occlusion::Visibility;

/// Where a feature volume's value v lies in the original data: `Some(u)`, the original's
/// normalised intensity, for the context and for feature voxels with a known source range; the
/// original value is found by undoing the feature's shift.
struct Origin<'a> {
    map: &'a FeatureMap,
    /// Features by lower edge, with their shifts Δ when known.
    shifts: Vec<(f64, Option<f64>)>,
}

impl<'a> Origin<'a> {
    fn new(map: &'a FeatureMap) -> Self {
        let mut shifts: Vec<(f64, Option<f64>)> = map
            .features()
            .iter()
            .map(|(_, f)| {
                let lo = f.interval[0];
                (lo, f.source_range.map(|s| lo - s[0]))
            })
            .collect();
        shifts.sort_by(|a, b| a.0.total_cmp(&b.0));
        Origin { map, shifts }
    }

    /// The original normalised intensity of a context value, or `None` above the context.
    fn context(&self, v: f64) -> Option<f32> {
        let [c0, c1] = self.map.context_range;
        (v <= c1).then(|| unit((v - c0) / (c1 - c0)))
    }

    /// The original normalised intensity of any value of the feature volume: a context value
    /// itself, a feature's value shifted back down (the top of the context when the shift is not
    /// known, or in the gap below the first feature).
    fn original(&self, v: f64) -> f32 {
        if let Some(u) = self.context(v) {
            return u;
        }
        let [c0, c1] = self.map.context_range;
        match self.shifts.iter().rev().find(|(lo, _)| *lo <= v) {
            Some((_, Some(delta))) => unit((v - delta - c0) / (c1 - c0)),
            _ => 1.0,
        }
    }
}

fn unit(x: f64) -> f32 {
    x.clamp(0.0, 1.0) as f32
}

/// Knot `i` of a 256-entry axis on [0, 1]: the value entry `i` holds (`TransferFunction::table`).
fn knot(i: usize) -> f64 {
    i as f64 / (TABLE_SIZE - 1) as f64
}

/// Checks the map and the feature volume's range before composing.
fn check(map: &FeatureMap, range: [f64; 2]) -> Result<()> {
    crate::classify::features::check(map, range)?;
    let [c0, c1] = map.context_range;
    if c1.partial_cmp(&c0) != Some(std::cmp::Ordering::Greater) {
        return Err(Error::Invalid(format!(
            "the feature map's context range [{c0}, {c1}] is empty; expected the data range before migration, min < max"
        )));
    }
    Ok(())
}

/// The occlusion TF `otf` (a 256 × 256 table over the original data, `otf[o * 256 + s]`) and
/// the feature map `map` as one table over the feature volume whose data range is `range`.
pub(crate) fn composed_table(
    map: &FeatureMap,
    otf: &[[f32; 4]],
    range: [f64; 2],
) -> Result<Vec<[f32; 4]>> {
    check(map, range)?;
    if otf.len() != TABLE_SIZE * TABLE_SIZE {
        return Err(Error::Invalid(format!(
            "an occlusion transfer-function table needs {TABLE_SIZE}×{TABLE_SIZE} entries, not {}",
            otf.len()
        )));
    }
    let features = feature_transfer_function(map, range)?.table(TABLE_SIZE);
    let origin = Origin::new(map);
    let columns: Vec<Column> = (0..TABLE_SIZE)
        .map(|si| {
            let v = range[0] + knot(si) * (range[1] - range[0]);
            match origin.context(v) {
                Some(u) => Column::Context(u),
                None => Column::Feature(features[si]),
            }
        })
        .collect();
    let mut table = Vec::with_capacity(TABLE_SIZE * TABLE_SIZE);
    for row in otf.chunks_exact(TABLE_SIZE) {
        table.extend(columns.iter().map(|c| match *c {
            Column::Context(u) => along_intensity(row, u),
            Column::Feature(rgba) => rgba,
        }));
    }
    Ok(table)
}

/// What one intensity bin of the composed table shows.
enum Column {
    /// The occlusion TF at this original normalised intensity.
    Context(f32),
    /// This feature-TF entry, at every occlusion.
    Feature([f32; 4]),
}

/// One row of an occlusion TF at normalised intensity `u`, linear between knots and clamped at
/// the ends, as the shaders read it.
fn along_intensity(row: &[[f32; 4]], u: f32) -> [f32; 4] {
    let x = (u * (TABLE_SIZE - 1) as f32).clamp(0.0, (TABLE_SIZE - 1) as f32);
    let (i, t) = (x.floor() as usize, x.fract());
    let j = (i + 1).min(TABLE_SIZE - 1);
    std::array::from_fn(|k| row[i][k] + t * (row[j][k] - row[i][k]))
}

/// The visibility mapping of the occlusion pass on the feature volume whose data range is
/// `range`: `original` (the occlusion TF's mapping on the data before migration) at each value's
/// original intensity, so the occlusion volume is the original data's.
pub(crate) fn composed_visibility(
    map: &FeatureMap,
    original: &Visibility,
    range: [f64; 2],
) -> Result<Visibility> {
    check(map, range)?;
    let origin = Origin::new(map);
    Ok(Visibility::Table(
        (0..TABLE_SIZE)
            .map(|i| original.apply(origin.original(range[0] + knot(i) * (range[1] - range[0]))))
            .collect(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use vellum_volume::feature::Feature;

    /// Context 0..255; one feature moved from [100, 150] to [268, 318] (Δ = 168).
    fn map() -> FeatureMap {
        let mut m = FeatureMap::new([0.0, 255.0]);
        m.append(
            Feature {
                label: "vessel".into(),
                description: String::new(),
                interval: [268.0, 318.0],
                color: [0.9, 0.2, 0.2],
                source_range: Some([100.0, 150.0]),
            },
            None,
        )
        .unwrap();
        m
    }

    /// An occlusion TF table whose colour encodes (s, o): rgba = (s, o, 0.5, s·o).
    fn otf() -> Vec<[f32; 4]> {
        let c = |i: usize| knot(i) as f32;
        (0..TABLE_SIZE * TABLE_SIZE)
            .map(|k| {
                let (o, s) = (c(k / TABLE_SIZE), c(k % TABLE_SIZE));
                [s, o, 0.5, s * o]
            })
            .collect()
    }

    #[test]
    fn context_bins_read_the_otf_at_their_original_intensity() {
        let range = [0.0, 318.0];
        let table = composed_table(&map(), &otf(), range).unwrap();
        for si in [0usize, 40, 100, 203] {
            let v = range[0] + knot(si) * 318.0;
            assert!(v <= 255.0);
            for oi in [0usize, 128, 255] {
                let got = table[oi * TABLE_SIZE + si];
                let u = (v / 255.0) as f32;
                let o = knot(oi) as f32;
                // Linear between knots: exact for this table, which is linear in s.
                let want = [u, o, 0.5];
                for k in 0..3 {
                    assert!(
                        (got[k] - want[k]).abs() < 1e-5,
                        "{si} {oi} {got:?} {want:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn feature_bins_take_the_feature_colour_at_every_occlusion() {
        let range = [0.0, 318.0];
        let table = composed_table(&map(), &otf(), range).unwrap();
        let tf = feature_transfer_function(&map(), range)
            .unwrap()
            .table(TABLE_SIZE);
        let bin = |v: f64| ((v / 318.0) * 255.0).round() as usize;
        for v in [270.0, 290.0, 317.0] {
            for oi in [0usize, 77, 255] {
                let got = table[oi * TABLE_SIZE + bin(v)];
                assert_eq!(got, tf[bin(v)]);
                assert_eq!(&got[..3], &[0.9, 0.2, 0.2]);
                assert!(got[3] > 0.5);
            }
        }
        // The gap between the context and the feature is transparent at every occlusion.
        for oi in [0usize, 255] {
            assert_eq!(table[oi * TABLE_SIZE + bin(264.0)][3], 0.0);
        }
    }

    #[test]
    fn visibility_is_the_original_datas() {
        let range = [0.0, 318.0];
        let vis = composed_visibility(&map(), &Visibility::Ramp, range).unwrap();
        let at = |v: f64| vis.apply((v / 318.0) as f32);
        // The context keeps its ramp; the feature's voxels occlude as they did before migration.
        assert!((at(127.0) - 127.0 / 255.0).abs() < 0.01);
        assert!((at(293.0) - 125.0 / 255.0).abs() < 0.01, "{}", at(293.0));
        // In the gap below the feature: the top of the context.
        assert!((at(262.0) - 1.0).abs() < 1e-6);
    }

    #[test]
    fn bad_inputs_are_refused() {
        assert!(composed_table(&map(), &otf()[..10], [0.0, 318.0]).is_err());
        assert!(composed_table(&map(), &otf(), [5.0, 5.0]).is_err());
        let empty = FeatureMap::new([3.0, 3.0]);
        let e = composed_visibility(&empty, &Visibility::Ramp, [0.0, 1.0]).unwrap_err();
        assert!(e.to_string().contains("context range"), "{e}");
    }
}
