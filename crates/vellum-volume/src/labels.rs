//! Label volumes (issue 42): a segmentation read as segments, not intensities. Each voxel holds
//! an id (0 is background by convention); the ids present are numbered densely (`index`), so a
//! renderer samples a voxel's index nearest, never interpolated, and looks its segment's colour,
//! visibility and level up in a table of one entry per id present.
//!
//! Colours come from the store's NGFF `image-label` metadata when it has them, else from a hash
//! of the id ([`colour_of`]): the same id has the same colour in every picture and every run.

use crate::io::ome_zarr;
use crate::Volume;
use std::path::{Path, PathBuf};
use vellum_error::{Error, Result};

/// The most distinct ids a label volume may hold (its indices are 16-bit on the GPU).
pub const MAX_LABELS: usize = 65_535;

/// A label volume: the distinct ids it holds and each voxel's index among them.
#[derive(Clone, Debug)]
pub struct Labels {
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// The ids present, ascending; a voxel's index points into this.
    pub ids: Vec<u32>,
    /// Per voxel (x fastest), the index of its id in `ids`.
    pub index: Vec<u16>,
    /// Per index, the voxels that hold it.
    pub counts: Vec<u64>,
    /// Colours the file gives (NGFF `image-label` colours: id, RGBA), if any.
    pub file_colours: Vec<(u32, [u8; 4])>,
}

impl Labels {
    /// The segments of `v`, whose voxels must be whole numbers from 0 to 2^32 − 1 (`what`
    /// names it in a refusal), with at most [`MAX_LABELS`] distinct values.
    pub fn of_volume(v: &Volume, what: &str) -> Result<Labels> {
        let n = v.len();
        let mut ids: Vec<u32> = Vec::new();
        let mut seen = std::collections::HashSet::new();
        // A segmentation runs along x: the last value is the next one's most of the time, and
        // is not hashed again (hashing every voxel was most of the read).
        let mut last = None;
        for i in 0..n {
            let x = v.data.get_f64(i);
            if last == Some(x) {
                continue;
            }
            last = Some(x);
            if x < 0.0 || x.fract() != 0.0 || x > u32::MAX as f64 {
                return Err(Error::Invalid(format!(
                    "{what} holds {x} at voxel {i}; a label volume holds whole numbers from 0 (ids), expected a segmentation"
                )));
            }
            if seen.insert(x as u32) {
                ids.push(x as u32);
                if ids.len() > MAX_LABELS {
                    return Err(Error::Invalid(format!(
                        "{what} holds more than {MAX_LABELS} distinct ids; expected a segmentation with fewer labels"
                    )));
                }
            }
        }
        ids.sort_unstable();
        let lookup: std::collections::HashMap<u32, u16> = ids
            .iter()
            .enumerate()
            .map(|(i, &id)| (id, i as u16))
            .collect();
        let mut counts = vec![0u64; ids.len()];
        let mut last = (u32::MAX as u64 + 1, 0u16);
        let index: Vec<u16> = (0..n)
            .map(|i| {
                let id = v.data.get_f64(i) as u32;
                if last.0 != id as u64 {
                    last = (id as u64, lookup[&id]);
                }
                counts[last.1 as usize] += 1;
                last.1
            })
            .collect();
        Ok(Labels {
            dims: v.dims,
            ids,
            index,
            counts,
            file_colours: Vec::new(),
        })
    }

    /// The label volume at `path`: a file, a store (with its NGFF `image-label` colours), or
    /// the name of a label image in the `labels` group of the store `image` (`--labels NAME`).
    pub fn open(path: &Path, image: Option<&Path>) -> Result<Labels> {
        let (path, in_group) = resolve(path, image);
        let what = format!("the label volume {}", path.display());
        if in_group || ome_zarr::is_store(&path) {
            let ms = ome_zarr::Multiscale::open(&path)?;
            let mut labels = Labels::of_volume(&ms.read_level(0)?, &what)?;
            labels.file_colours = ms.label_colours.clone();
            return Ok(labels);
        }
        Labels::of_volume(&crate::io::load(&path, None)?, &what)
    }

    /// Refuses a label volume that does not lie on a grid of `dims` voxels, in one sentence
    /// that names it (`what`).
    pub fn check_grid(&self, dims: [usize; 3], what: &str) -> Result<()> {
        if self.dims == dims {
            return Ok(());
        }
        let [a, b, c] = self.dims;
        let [x, y, z] = dims;
        Err(Error::Invalid(format!(
            "{what} is {a} x {b} x {c} voxels and the input {x} x {y} x {z}; expected a label volume on the input's grid"
        )))
    }

    /// The index of `id`, if the volume holds it.
    pub fn index_of(&self, id: u32) -> Option<usize> {
        self.ids.binary_search(&id).ok()
    }

    /// The colour of `id`: the file's, or [`colour_of`].
    pub fn colour(&self, id: u32) -> [u8; 4] {
        self.file_colours
            .iter()
            .find(|(i, _)| *i == id)
            .map_or_else(|| colour_of(id), |(_, c)| *c)
    }

    /// Per index, the bounding box of its voxels: the first and the last voxel along x, y, z
    /// (an index no voxel holds gets an empty box, first past last).
    pub fn boxes(&self) -> Vec<[[u32; 3]; 2]> {
        let [nx, ny, _] = self.dims;
        let mut boxes = vec![[[u32::MAX; 3], [0; 3]]; self.ids.len()];
        for (r, row) in self.index.chunks(nx.max(1)).enumerate() {
            let (y, z) = ((r % ny) as u32, (r / ny) as u32);
            // Per run of one index along the row, its first and last x.
            let mut x0 = 0;
            while x0 < row.len() {
                let k = row[x0];
                let x1 = x0 + row[x0..].iter().take_while(|&&i| i == k).count();
                let b = &mut boxes[k as usize];
                let (lo, hi) = ([x0 as u32, y, z], [x1 as u32 - 1, y, z]);
                for a in 0..3 {
                    b[0][a] = b[0][a].min(lo[a]);
                    b[1][a] = b[1][a].max(hi[a]);
                }
                x0 = x1;
            }
        }
        boxes
    }

    /// The indices, two per 32-bit word (the lower half first), as the ray caster reads them.
    pub fn packed(&self) -> Vec<u32> {
        self.index
            .chunks(2)
            .map(|p| p[0] as u32 | (p.get(1).copied().unwrap_or(0) as u32) << 16)
            .collect()
    }
}

/// The segment indices of a coarser level (`dims` voxels, each `ratio` voxels of the finer level
/// `fine`, of `fine_dims`, along each axis), each voxel the index most of its finer voxels hold
/// that is not `background` (id 0's index), or `background` when all of them are: a segment
/// never vanishes from a coarse level while it holds any of the voxel, and no voxel blends two
/// (neuroglancer downsamples segmentations by the mode likewise).
pub fn coarser_index(
    fine: &[u16],
    fine_dims: [usize; 3],
    dims: [usize; 3],
    ratio: [f64; 3],
    background: Option<u16>,
) -> Vec<u16> {
    use rayon::prelude::*;
    // Per axis, the finer voxels each coarse voxel covers (at least one, within the level).
    let spans: [Vec<(usize, usize)>; 3] = std::array::from_fn(|a| {
        (0..dims[a])
            .map(|x| {
                let lo = ((x as f64 * ratio[a] + 1e-9).floor() as usize).min(fine_dims[a] - 1);
                let hi = (((x + 1) as f64 * ratio[a] - 1e-9).ceil() as usize)
                    .clamp(lo + 1, fine_dims[a]);
                (lo, hi)
            })
            .collect()
    });
    let [nx, ny, _] = fine_dims;
    let mut out = vec![0u16; dims[0] * dims[1] * dims[2]];
    out.par_chunks_mut(dims[0] * dims[1])
        .enumerate()
        .for_each(|(z, slice)| {
            let (z0, z1) = spans[2][z];
            let mut counts: Vec<(u16, u32)> = Vec::with_capacity(8);
            for (y, row) in slice.chunks_mut(dims[0]).enumerate() {
                let (y0, y1) = spans[1][y];
                for (x, out) in row.iter_mut().enumerate() {
                    let (x0, x1) = spans[0][x];
                    counts.clear();
                    for fz in z0..z1 {
                        for fy in y0..y1 {
                            for &i in &fine[(fz * ny + fy) * nx..][x0..x1] {
                                if Some(i) == background {
                                    continue;
                                }
                                match counts.iter_mut().find(|c| c.0 == i) {
                                    Some(c) => c.1 += 1,
                                    None => counts.push((i, 1)),
                                }
                            }
                        }
                    }
                    // The most held; of equals, the first met.
                    let best = counts
                        .iter()
                        .fold(None, |b: Option<(u16, u32)>, &c| match b {
                            Some(b) if b.1 >= c.1 => Some(b),
                            _ => Some(c),
                        });
                    *out = best.map_or(background.unwrap_or(0), |b| b.0);
                }
            }
        });
    out
}

/// `path`, or the label image of that name in the `labels` group of the store `image` when
/// `path` is a bare name that names no file; and whether it is the latter.
fn resolve(path: &Path, image: Option<&Path>) -> (PathBuf, bool) {
    let bare = path.components().count() == 1 && !path.exists();
    match image.filter(|i| bare && ome_zarr::is_store(i)) {
        Some(store) => (store.join("labels").join(path), true),
        None => (path.to_path_buf(), false),
    }
}

/// A colour for `id` that neighbouring ids do not share: hues a golden angle apart, with the
/// saturation and value varied too, so that ids far apart differ as well. Id 0 is black.
pub fn colour_of(id: u32) -> [u8; 4] {
    if id == 0 {
        return [0, 0, 0, 255];
    }
    let h = (id as f64 * 0.618_033_988_749_895).fract();
    let s = [0.75, 0.55, 0.9][(id % 3) as usize];
    let v = [0.95, 0.8, 0.7][(id / 3 % 3) as usize];
    let rgb = hsv(h, s, v);
    [rgb[0], rgb[1], rgb[2], 255]
}

fn hsv(h: f64, s: f64, v: f64) -> [u8; 3] {
    let i = (h * 6.0).floor();
    let f = h * 6.0 - i;
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - f * s), v * (1.0 - (1.0 - f) * s));
    let (r, g, b) = match i as i32 % 6 {
        0 => (v, t, p),
        1 => (q, v, p),
        2 => (p, v, t),
        3 => (p, q, v),
        4 => (t, p, v),
        _ => (v, p, q),
    };
    [r, g, b].map(|c| (c * 255.0).round() as u8)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::VoxelData;

    #[test]
    fn each_segment_has_the_box_of_its_voxels() {
        // 3 x 2 x 2: id 7 at (1, 0, 0) and (2, 1, 1), id 0 everywhere else.
        let mut v = vec![0u8; 12];
        v[1] = 7;
        v[2 + 3 * (1 + 2)] = 7;
        let l = Labels::of_volume(
            &crate::Volume::new([3, 2, 2], [1.0; 3], VoxelData::U8(v)).unwrap(),
            "l",
        )
        .unwrap();
        let b = l.boxes();
        assert_eq!(b[l.index_of(7).unwrap() as usize], [[1, 0, 0], [2, 1, 1]]);
        assert_eq!(b[l.index_of(0).unwrap() as usize], [[0, 0, 0], [2, 1, 1]]);
    }

    #[test]
    fn ids_are_numbered_densely_and_counted() {
        let v = Volume::new([4, 1, 1], [1.0; 3], VoxelData::U16(vec![0, 70, 3, 70])).unwrap();
        let l = Labels::of_volume(&v, "x").unwrap();
        assert_eq!(l.ids, vec![0, 3, 70]);
        assert_eq!(l.index, vec![0, 2, 1, 2]);
        assert_eq!(l.counts, vec![1, 1, 2]);
        assert_eq!(l.packed(), vec![2 << 16, 1 | 2 << 16]);
        assert_eq!(l.index_of(70), Some(2));
        assert_eq!(l.index_of(5), None);
    }

    #[test]
    fn a_coarse_voxel_takes_the_segment_most_of_it_holds_over_background() {
        // 4 x 2 x 1 to 2 x 1 x 1: (0, 1, 3, 0 | 1, 1, 0, 0) over x-pairs and y; background 0.
        let fine = [0, 1, 3, 0, 1, 1, 0, 0];
        let got = coarser_index(&fine, [4, 2, 1], [2, 1, 1], [2.0, 2.0, 1.0], Some(0));
        assert_eq!(
            got,
            vec![1, 3],
            "1 holds two of the first voxel, 3 the only segment of the second"
        );
        // Without a background every index counts: the second voxel is mostly 0.
        let got = coarser_index(&fine, [4, 2, 1], [2, 1, 1], [2.0, 2.0, 1.0], None);
        assert_eq!(got, vec![1, 0]);
        // An odd edge: 3 voxels to 2, the last coarse voxel covering the last fine one alone.
        let got = coarser_index(&[2, 2, 5], [3, 1, 1], [2, 1, 1], [2.0, 1.0, 1.0], Some(0));
        assert_eq!(got, vec![2, 5]);
    }

    #[test]
    fn fractions_and_negatives_are_refused() {
        for bad in [vec![0.0, 1.5], vec![-1.0, 2.0]] {
            let v = Volume::new([2, 1, 1], [1.0; 3], VoxelData::F32(bad)).unwrap();
            let e = Labels::of_volume(&v, "the label volume m.nrrd").unwrap_err();
            assert!(e.to_string().contains("whole numbers"), "{e}");
        }
    }

    #[test]
    fn neighbouring_ids_get_distinct_colours() {
        for id in 1..200u32 {
            let (a, b) = (colour_of(id), colour_of(id + 1));
            let d: i32 = (0..3).map(|c| (a[c] as i32 - b[c] as i32).abs()).sum();
            assert!(d > 60, "{id}: {a:?} {b:?}");
        }
        assert_eq!(colour_of(0), [0, 0, 0, 255]);
    }
}
