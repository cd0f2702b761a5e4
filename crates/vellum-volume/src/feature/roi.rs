//! FM1, the region of interest (paper §3.1): a mask over the volume's grid, taken from a mask
//! volume or grown from seeds through an intensity window.
//!
//! Seeded growing is a plain breadth-first flood fill. It is the one step here that is not
//! parallel: its frontier is small next to the volume, and it runs once per feature.

use std::collections::VecDeque;

use super::neighbourhood::{Connectivity, Grid};
use crate::Volume;
use vellum_error::{Error, Result};

/// The ROI: one flag per voxel of the data volume, x fastest.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Roi {
    dims: [usize; 3],
    mask: Vec<bool>,
}

impl Roi {
    /// An ROI from per-voxel flags. `mask` must hold one flag per voxel of `dims`.
    pub fn new(dims: [usize; 3], mask: Vec<bool>) -> Result<Self> {
        let n = dims.iter().product::<usize>();
        if mask.len() != n {
            return Err(Error::Invalid(format!(
                "ROI mask has {} voxels but the {}x{}x{} grid has {n}; expected one flag per voxel",
                mask.len(),
                dims[0],
                dims[1],
                dims[2]
            )));
        }
        Ok(Roi { dims, mask })
    }

    /// The ROI of a mask volume: every nonzero voxel. The mask must be aligned voxel for voxel
    /// with `data`: the same dims and, when both know their orientation, the same origin
    /// (within 1e-3 mm), directions (within 1e-4) and spacing (within 1e-4 relative).
    pub fn from_mask(mask: &Volume, data: &Volume) -> Result<Self> {
        let data_dims = data.dims;
        if mask.dims != data_dims {
            let [a, b, c] = mask.dims;
            let [x, y, z] = data_dims;
            return Err(Error::Invalid(format!(
                "the mask is {a}x{b}x{c} but the volume is {x}x{y}x{z}; expected a mask aligned voxel for voxel with the volume"
            )));
        }
        let (gm, gd) = (&mask.geometry, &data.geometry);
        if gm.is_oriented() && gd.is_oriented() {
            let far = |a: &[f64], b: &[f64], tol: f64| {
                a.iter()
                    .zip(b)
                    .any(|(x, y)| (x - y).abs() > tol * y.abs().max(1.0))
            };
            let why = if far(&gm.origin, &gd.origin, 1e-3) {
                Some(format!(
                    "its origin is {:?} mm but the volume's is {:?}",
                    gm.origin, gd.origin
                ))
            } else if far(
                gm.direction.as_flattened(),
                gd.direction.as_flattened(),
                1e-4,
            ) {
                Some(format!(
                    "its directions are {:?} but the volume's are {:?}",
                    gm.direction, gd.direction
                ))
            } else if far(&mask.spacing, &data.spacing, 1e-4) {
                Some(format!(
                    "its spacing is {:?} but the volume's is {:?}",
                    mask.spacing, data.spacing
                ))
            } else {
                None
            };
            if let Some(why) = why {
                return Err(Error::Invalid(format!(
                    "the mask does not lie on the volume's grid: {why}; expected the same geometry"
                )));
            }
        }
        let flags = (0..mask.len())
            .map(|i| mask.data.get_f64(i) != 0.0)
            .collect();
        Roi::new(data_dims, flags)
    }

    /// Seeded region growing: the voxels connected to any of `seeds` through voxels whose value
    /// lies in `window` = [lo, hi] (inclusive, in data units), with 6- or 26-connectivity (18 is
    /// accepted too). Every seed must lie inside the volume and inside the window.
    pub fn grow(
        volume: &Volume,
        seeds: &[[usize; 3]],
        window: [f64; 2],
        connectivity: Connectivity,
    ) -> Result<Self> {
        let [lo, hi] = window;
        if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
            return Err(Error::Invalid(format!(
                "intensity window {lo}:{hi} is invalid; expected two finite numbers LO:HI with LO <= HI"
            )));
        }
        if seeds.is_empty() {
            return Err(Error::Invalid(
                "no seed was given; expected at least one seed voxel X,Y,Z".into(),
            ));
        }
        let grid = Grid::new(volume.dims);
        let inside = |i: usize| (lo..=hi).contains(&volume.data.get_f64(i));
        let mut mask = vec![false; grid.len()];
        let mut queue = VecDeque::new();
        for &s in seeds {
            if (0..3).any(|a| s[a] >= volume.dims[a]) {
                let [x, y, z] = volume.dims;
                return Err(Error::Invalid(format!(
                    "seed {},{},{} lies outside the {x}x{y}x{z} volume; expected 0 <= X < {x}, 0 <= Y < {y}, 0 <= Z < {z}",
                    s[0], s[1], s[2]
                )));
            }
            let i = grid.index(s);
            if !inside(i) {
                return Err(Error::Invalid(format!(
                    "seed {},{},{} has value {} outside the window {lo}:{hi}; expected every seed's value inside the window",
                    s[0],
                    s[1],
                    s[2],
                    volume.data.get_f64(i)
                )));
            }
            if !mask[i] {
                mask[i] = true;
                queue.push_back(s);
            }
        }
        let offsets = connectivity.offsets();
        while let Some(p) = queue.pop_front() {
            for &d in &offsets {
                if let Some(q) = grid.offset(p, d) {
                    if !mask[q] && inside(q) {
                        mask[q] = true;
                        queue.push_back(grid.coords(q));
                    }
                }
            }
        }
        Roi::new(volume.dims, mask)
    }

    /// Voxels along x, y, z.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// The per-voxel flags, x fastest.
    pub fn mask(&self) -> &[bool] {
        &self.mask
    }

    /// True when voxel `i` (linear index) is in the ROI.
    #[inline]
    pub fn contains(&self, i: usize) -> bool {
        self.mask[i]
    }

    /// Number of ROI voxels.
    pub fn count(&self) -> usize {
        self.mask.iter().filter(|&&m| m).count()
    }

    /// The ROI as a u8 volume (1 = ROI) with `spacing`, e.g. to save a grown region as a mask.
    #[cfg(test)]
    pub(crate) fn to_volume(&self, spacing: [f64; 3]) -> Result<Volume> {
        let data = self.mask.iter().map(|&m| m as u8).collect();
        Volume::new(self.dims, spacing, crate::VoxelData::U8(data))
    }
}

/// A label volume of `rois` on `volume`'s grid (its spacing and placement): voxels of the n-th
/// ROI take id n + 1, a voxel in several keeps the first's id, and the rest are 0. Stored as
/// uint8 up to 255 ROIs, else uint16. Also returns how many voxels each id took.
pub fn label_volume(volume: &Volume, rois: &[Roi]) -> Result<(Volume, Vec<usize>)> {
    if rois.len() > u16::MAX as usize {
        return Err(Error::Invalid(format!(
            "{} regions were given; a label volume holds at most {}",
            rois.len(),
            u16::MAX
        )));
    }
    if let Some(r) = rois.iter().find(|r| r.dims != volume.dims) {
        let [a, b, c] = r.dims;
        return Err(Error::Invalid(format!(
            "a region of {a}x{b}x{c} voxels lies on another grid than the volume's; expected the volume's"
        )));
    }
    let mut ids = vec![0u16; volume.len()];
    let mut counts = vec![0usize; rois.len()];
    for (n, roi) in rois.iter().enumerate() {
        for (id, &m) in ids.iter_mut().zip(&roi.mask) {
            if m && *id == 0 {
                *id = n as u16 + 1;
                counts[n] += 1;
            }
        }
    }
    let data = match rois.len() <= u8::MAX as usize {
        true => crate::VoxelData::U8(ids.iter().map(|&i| i as u8).collect()),
        false => crate::VoxelData::U16(ids),
    };
    let labels = Volume::new(volume.dims, volume.spacing, data)?.with_geometry(volume.geometry)?;
    Ok((labels, counts))
}

/// Parses seeds written as `X,Y,Z[;X,Y,Z...]` (whole voxel indices).
pub fn parse_seeds(s: &str) -> Result<Vec<[usize; 3]>> {
    let bad = |part: &str| {
        Error::Invalid(format!(
            "seed '{part}' is invalid; expected X,Y,Z voxel indices (whole numbers), several separated by ';'"
        ))
    };
    let seeds = s
        .split(';')
        .filter(|p| !p.trim().is_empty())
        .map(|part| {
            let v: Vec<usize> = part
                .split(',')
                .map(|c| c.trim().parse::<usize>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| bad(part))?;
            <[usize; 3]>::try_from(v).map_err(|_| bad(part))
        })
        .collect::<Result<Vec<_>>>()?;
    if seeds.is_empty() {
        return Err(bad(s));
    }
    Ok(seeds)
}

/// Parses an intensity window written as `LO:HI` in data units.
pub fn parse_window(s: &str) -> Result<[f64; 2]> {
    let parsed = s.split_once(':').and_then(|(a, b)| {
        let (lo, hi) = (a.trim().parse::<f64>().ok()?, b.trim().parse::<f64>().ok()?);
        (lo.is_finite() && hi.is_finite() && lo <= hi).then_some([lo, hi])
    });
    parsed.ok_or_else(|| {
        Error::Invalid(format!(
            "window '{s}' is invalid; expected LO:HI in data units with LO <= HI"
        ))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::VoxelData;

    fn volume(dims: [usize; 3], f: impl Fn([usize; 3]) -> u8) -> Volume {
        let g = Grid::new(dims);
        let data = (0..g.len()).map(|i| f(g.coords(i))).collect();
        Volume::new(dims, [1.0; 3], VoxelData::U8(data)).unwrap()
    }

    #[test]
    fn regions_become_labels_numbered_in_order_and_the_first_keeps_a_shared_voxel() {
        // A bright slab x < 4 and a dimmer one x >= 4, grown separately, then again as one
        // window that covers both: the third region's voxels are all taken already.
        let v = volume([8, 3, 2], |[x, _, _]| if x < 4 { 200 } else { 100 });
        let bright = Roi::grow(&v, &[[0, 0, 0]], [150.0, 255.0], Connectivity::Six).unwrap();
        let dim = Roi::grow(&v, &[[7, 2, 1]], [50.0, 120.0], Connectivity::Six).unwrap();
        let both = Roi::grow(&v, &[[0, 0, 0]], [50.0, 255.0], Connectivity::Six).unwrap();
        let (labels, counts) = label_volume(&v, &[bright, dim, both]).unwrap();
        assert_eq!(counts, vec![24, 24, 0]);
        assert_eq!(labels.voxel_type(), crate::VoxelType::U8);
        assert_eq!(labels.data.get_f64(v.index(3, 1, 1)), 1.0);
        assert_eq!(labels.data.get_f64(v.index(4, 0, 0)), 2.0);
        let other = volume([2, 2, 2], |_| 1);
        let small = Roi::grow(&other, &[[0, 0, 0]], [0.0, 2.0], Connectivity::Six).unwrap();
        let err = label_volume(&v, &[small]).unwrap_err().to_string();
        assert!(err.contains("another grid"), "{err}");
    }

    #[test]
    fn growing_respects_window_and_connectivity() {
        // Two bright voxels touching only at a corner: one region with 26-connectivity, two with 6.
        let v = volume([4, 4, 4], |p| match p {
            [1, 1, 1] | [2, 2, 2] => 200,
            _ => 10,
        });
        let six = Roi::grow(&v, &[[1, 1, 1]], [100.0, 255.0], Connectivity::Six).unwrap();
        assert_eq!(six.count(), 1);
        let all = Roi::grow(&v, &[[1, 1, 1]], [100.0, 255.0], Connectivity::TwentySix).unwrap();
        assert_eq!(all.count(), 2);
        assert!(all.contains(v.index(2, 2, 2)));
        let dark = Roi::grow(&v, &[[0, 0, 0]], [0.0, 50.0], Connectivity::Six).unwrap();
        assert_eq!(dark.count(), 62);
    }

    #[test]
    fn bad_seeds_say_what_was_expected() {
        let v = volume([4, 4, 4], |_| 10);
        let e = Roi::grow(&v, &[[4, 0, 0]], [0.0, 255.0], Connectivity::Six)
            .unwrap_err()
            .to_string();
        assert!(e.contains("outside the 4x4x4 volume"), "{e}");
        let e = Roi::grow(&v, &[[1, 1, 1]], [100.0, 255.0], Connectivity::Six)
            .unwrap_err()
            .to_string();
        assert!(e.contains("value 10 outside the window 100:255"), "{e}");
        let e = Roi::grow(&v, &[], [0.0, 1.0], Connectivity::Six).unwrap_err();
        assert!(e.to_string().contains("at least one seed"), "{e}");
    }

    #[test]
    fn masks_must_match_the_data() {
        let data = volume([4, 4, 4], |_| 0);
        let mask = volume([4, 4, 3], |p| (p[0] == 1) as u8);
        let e = Roi::from_mask(&mask, &data).unwrap_err().to_string();
        assert!(e.contains("mask is 4x4x3 but the volume is 4x4x4"), "{e}");
        let mask = volume([4, 4, 4], |p| 7 * (p[0] == 1) as u8);
        let roi = Roi::from_mask(&mask, &data).unwrap();
        assert_eq!(roi.count(), 16);
        assert_eq!(roi.to_volume([1.0; 3]).unwrap().data.get_f64(1), 1.0);
        // Oriented volumes must also agree in origin.
        use crate::geometry::{Geometry, IDENTITY};
        let placed = |o: [f64; 3]| Geometry::lps(o, IDENTITY).unwrap();
        let data = data.with_geometry(placed([0.0; 3])).unwrap();
        let shifted = mask.clone().with_geometry(placed([5.0, 0.0, 0.0])).unwrap();
        let e = Roi::from_mask(&shifted, &data).unwrap_err().to_string();
        assert!(e.contains("origin is [5.0, 0.0, 0.0]"), "{e}");
        let same = mask.with_geometry(placed([0.0; 3])).unwrap();
        assert!(Roi::from_mask(&same, &data).is_ok());
    }

    #[test]
    fn parses_seeds_and_windows() {
        assert_eq!(
            parse_seeds("1,2,3; 4,5,6").unwrap(),
            vec![[1, 2, 3], [4, 5, 6]]
        );
        for bad in ["", "1,2", "1,2,3,4", "a,b,c", "-1,0,0"] {
            let e = parse_seeds(bad).unwrap_err().to_string();
            assert!(e.contains("expected X,Y,Z"), "{bad}: {e}");
        }
        assert_eq!(parse_window("170:255").unwrap(), [170.0, 255.0]);
        assert_eq!(parse_window("-5.5:2").unwrap(), [-5.5, 2.0]);
        for bad in ["5", "9:1", "a:b", "nan:1"] {
            assert!(parse_window(bad).is_err(), "{bad}");
        }
    }
}
