//! Segments of a label volume as features (issue 42): data that arrives segmented is migrated
//! one segment at a time, each chosen id's voxels the ROI of one feature (§3.1's mask), moved to
//! a private interval of its own with its fuzzy boundary rebuilt (§3.2–§3.4), the intervals of
//! the segments before it kept private: what `vellum migrate --mask` appending one feature
//! after another does, in one pass over the ids.

use crate::feature::{migrate, MigrateParams, MigrationReport, Roi};
use crate::labels::Labels;
use crate::{Volume, VoxelData};
use vellum_error::{Error, Result};

/// `volume` with the segments `ids` of `labels` (on its grid) migrated in that order, and each
/// one's report. `params.protected` holds the intervals of features already in `volume`.
pub fn migrate_segments(
    volume: &Volume,
    labels: &Labels,
    ids: &[u32],
    params: &MigrateParams,
) -> Result<(Volume, Vec<(u32, MigrationReport)>)> {
    if labels.dims != volume.dims {
        let [a, b, c] = labels.dims;
        let [x, y, z] = volume.dims;
        return Err(Error::Invalid(format!(
            "the label volume is {a}x{b}x{c} voxels and the input {x}x{y}x{z}; expected a label volume on the input's grid"
        )));
    }
    let mut current = volume.clone();
    let mut protected = params.protected.clone();
    let mut reports = Vec::with_capacity(ids.len());
    for &id in ids {
        let Some(k) = labels.index_of(id) else {
            return Err(Error::Invalid(format!(
                "label {id} is not in the label volume; expected one of its ids"
            )));
        };
        let mask: Vec<u8> = labels
            .index
            .iter()
            .map(|&i| u8::from(i as usize == k))
            .collect();
        let mut mask = Volume::new(volume.dims, volume.spacing, VoxelData::U8(mask))?;
        mask.geometry = volume.geometry;
        let roi = Roi::from_mask(&mask, &current)?;
        let p = MigrateParams {
            protected: protected.clone(),
            ..params.clone()
        };
        let m = migrate(&current, &roi, &p)?;
        protected.push(m.report.interval);
        reports.push((id, m.report));
        current = m.volume;
    }
    Ok((current, reports))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two segments of different densities side by side on a ramp of background: each moves
    /// to its own interval, above the data and apart from the other's, and its interior lands
    /// in it.
    #[test]
    fn each_segment_moves_to_an_interval_of_its_own() {
        let n = 16;
        let at = |x: usize, y: usize, z: usize| x + n * (y + n * z);
        let mut ids = vec![0u8; n * n * n];
        let mut values = vec![0f32; n * n * n];
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    let inside = (4..12).contains(&y) && (4..12).contains(&z);
                    let (id, v) = match x {
                        2..7 if inside => (3, 100.0),
                        9..14 if inside => (7, 200.0),
                        _ => (0, 10.0 * (x as f32 / n as f32)),
                    };
                    ids[at(x, y, z)] = id;
                    values[at(x, y, z)] = v;
                }
            }
        }
        let vol = |d| Volume::new([n; 3], [1.0; 3], d).unwrap();
        let labels = Labels::of_volume(&vol(VoxelData::U8(ids)), "l").unwrap();
        let data = vol(VoxelData::F32(values));
        let (out, reports) =
            migrate_segments(&data, &labels, &[3, 7], &MigrateParams::default()).unwrap();
        assert_eq!(reports.iter().map(|r| r.0).collect::<Vec<_>>(), [3, 7]);
        let [a, b] = [reports[0].1.interval, reports[1].1.interval];
        assert!(a[0] > 200.0 && b[0] > a[1], "intervals {a:?} then {b:?}");
        let inside = |v: f64, i: [f64; 2]| v >= i[0] && v <= i[1];
        assert!(inside(out.data.get_f64(at(4, 8, 8)), a));
        assert!(inside(out.data.get_f64(at(11, 8, 8)), b));
        assert!(
            !inside(out.data.get_f64(at(0, 8, 8)), a) && !inside(out.data.get_f64(at(0, 8, 8)), b)
        );
        let e = migrate_segments(&data, &labels, &[5], &MigrateParams::default()).unwrap_err();
        assert!(
            e.to_string().contains("label 5 is not in the label volume"),
            "{e}"
        );
    }
}
