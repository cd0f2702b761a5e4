//! FM2, the voxel categories of the paper's §3.2.
//!
//! Neighbourhoods, where the paper leaves them open:
//! - **ROI boundary** (§3.1, "one of its neighboring voxels is not part of the ROI"): the 6 face
//!   neighbours. This makes the boundary the thinnest closed layer of the ROI, one voxel thick, as
//!   in Fig. 4c; together with the one-voxel grow on either side it gives the fuzzy boundary the
//!   3 voxels of width the paper assumes. A 26-neighbour test would thicken the boundary at
//!   edges and corners only.
//! - **Type 1** ("adjacent to at least one non-boundary ROI voxel"): adjacency is tested over all
//!   26 neighbours, so that a convex corner of a thick ROI, whose nearest interior voxel is a
//!   diagonal neighbour, is not mistaken for a thin ROI. Type 2 then means: no interior ROI voxel
//!   in the 3×3×3 block, which is the paper's "so thin that all ROI voxels are also boundary
//!   voxels".
//! - **Fuzzy boundary**: the paper's grow, once, with the 18-neighbourhood, from every boundary
//!   voxel (both types: around a thin ROI "the voxels that surround them are" part of the fuzzy
//!   boundary) in all directions, so it adds one layer outside the ROI and one inside it.
//!
//! Category 1 is then the type-1 boundary plus the grown voxels, category 2 the type-2 boundary
//! (the grow never relabels them), category 3 the other ROI voxels and category 4 the rest. A
//! consequence of the paper's definitions: an ROI 3 or 4 voxels thick has no category-2 or -3
//! voxels at all (boundary, plus one grown layer on each side, covers it), while 1 or 2 voxels thick
//! is all category 2.
//!
//! Neighbours outside the volume do not exist (see [`super::neighbourhood`]).

use rayon::prelude::*;
use serde::Serialize;

use super::neighbourhood::{Connectivity, Grid};
use super::roi::Roi;

/// The category of one voxel (paper §3.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[repr(u8)]
pub enum Category {
    /// 1: the fuzzy boundary between the ROI and its surroundings.
    FuzzyBoundary = 1,
    /// 2: a thin ROI (type-2 boundary voxels).
    ThinRoi = 2,
    /// 3: the remaining ROI voxels.
    RoiInterior = 3,
    /// 4: everything else.
    Outside = 4,
}

impl Category {
    /// True for categories 2 and 3, the voxels that eq. 5 shifts by Δ.
    #[inline]
    pub fn is_roi_body(self) -> bool {
        matches!(self, Category::ThinRoi | Category::RoiInterior)
    }
}

/// Number of voxels in each category.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct CategoryCounts {
    /// Category 1, the fuzzy boundary.
    pub fuzzy_boundary: usize,
    /// Category 2, thin ROI.
    pub thin_roi: usize,
    /// Category 3, the rest of the ROI.
    pub roi_interior: usize,
    /// Category 4, everything else.
    pub outside: usize,
}

impl CategoryCounts {
    /// The counts as [c1, c2, c3, c4].
    pub fn as_array(&self) -> [usize; 4] {
        [
            self.fuzzy_boundary,
            self.thin_roi,
            self.roi_interior,
            self.outside,
        ]
    }
}

/// The category of every voxel of the ROI's grid, x fastest.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Categories {
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// One category per voxel.
    pub labels: Vec<Category>,
}

impl Categories {
    /// How many voxels fall into each category.
    pub fn counts(&self) -> CategoryCounts {
        self.labels
            .par_chunks(1 << 16)
            .map(|chunk| {
                let mut c = [0usize; 4];
                for &l in chunk {
                    c[l as usize - 1] += 1;
                }
                c
            })
            .reduce(|| [0; 4], |a, b| std::array::from_fn(|k| a[k] + b[k]))
            .into()
    }
}

impl From<[usize; 4]> for CategoryCounts {
    fn from(c: [usize; 4]) -> Self {
        CategoryCounts {
            fuzzy_boundary: c[0],
            thin_roi: c[1],
            roi_interior: c[2],
            outside: c[3],
        }
    }
}

const ROI: u8 = 1;
const BOUNDARY: u8 = 2;

/// One value per voxel, filled in parallel over x-rows by `fill(row, [y, z], values_of_the_row)`.
fn per_row<T: Send + Sync + Copy>(
    grid: Grid,
    init: T,
    fill: impl Fn(usize, [usize; 2], &mut [T]) + Sync,
) -> Vec<T> {
    let [nx, ny, _] = grid.dims;
    let mut out = vec![init; grid.len()];
    out.par_chunks_mut(nx)
        .enumerate()
        .for_each(|(row, values)| fill(row, [row % ny, row / ny], values));
    out
}

/// Categorises every voxel (see the module doc for the neighbourhoods).
pub fn categorise(roi: &Roi) -> Categories {
    let grid = Grid::new(roi.dims());
    let [nx, ny, nz] = grid.dims;
    let six = grid.stencil(Connectivity::Six.offsets());
    let eighteen = grid.stencil(Connectivity::Eighteen.offsets());
    let twenty_six = grid.stencil(Connectivity::TwentySix.offsets());
    let mask = roi.mask();

    // Pass 1: ROI and boundary flags (a boundary voxel has a face neighbour outside the ROI).
    let flags: Vec<u8> = per_row(grid, 0, |row, [y, z], out| {
        let in_row = &mask[row * nx..][..nx];
        if !in_row.contains(&true) {
            return;
        }
        for (x, o) in out.iter_mut().enumerate().filter(|(x, _)| in_row[*x]) {
            let outside_neighbour = grid.any([x, y, z], row * nx + x, &six, |q| !mask[q]);
            *o = if outside_neighbour {
                ROI | BOUNDARY
            } else {
                ROI
            };
        }
    });
    // Rows holding boundary voxels: a row with none among its 3×3 neighbouring rows cannot
    // touch the boundary, which skips the neighbourhood tests for most of the volume.
    let boundary_rows: Vec<bool> = flags
        .par_chunks(nx)
        .map(|r| r.iter().any(|f| f & BOUNDARY != 0))
        .collect();
    let near_boundary = |y: usize, z: usize| {
        (z.saturating_sub(1)..=(z + 1).min(nz - 1)).any(|zz| {
            (y.saturating_sub(1)..=(y + 1).min(ny - 1)).any(|yy| boundary_rows[yy + ny * zz])
        })
    };

    // Pass 2: types and the 18-neighbour grow of the boundary.
    let labels = per_row(grid, Category::Outside, |row, [y, z], out| {
        let near = near_boundary(y, z);
        for (x, o) in out.iter_mut().enumerate() {
            let (i, p) = (row * nx + x, [x, y, z]);
            let f = flags[i];
            *o = if f & BOUNDARY != 0 {
                if grid.any(p, i, &twenty_six, |q| flags[q] == ROI) {
                    Category::FuzzyBoundary
                } else {
                    Category::ThinRoi
                }
            } else if near && grid.any(p, i, &eighteen, |q| flags[q] & BOUNDARY != 0) {
                Category::FuzzyBoundary
            } else if f & ROI != 0 {
                Category::RoiInterior
            } else {
                Category::Outside
            };
        }
    });
    Categories {
        dims: roi.dims(),
        labels,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn roi(dims: [usize; 3], f: impl Fn([usize; 3]) -> bool) -> Roi {
        let g = Grid::new(dims);
        Roi::new(dims, (0..g.len()).map(|i| f(g.coords(i))).collect()).unwrap()
    }

    // Counts on cubes and sheets, derived by hand, are in tests/features.rs.

    #[test]
    fn edge_of_the_volume_is_not_a_boundary() {
        // The half space x >= 3 of a 6×4×4 grid: boundary only on x = 3.
        let cats = categorise(&roi([6, 4, 4], |p| p[0] >= 3));
        let g = Grid::new([6, 4, 4]);
        for i in 0..g.len() {
            let x = g.coords(i)[0];
            let want = match x {
                2..=4 => Category::FuzzyBoundary,
                5 => Category::RoiInterior,
                _ => Category::Outside,
            };
            assert_eq!(cats.labels[i], want, "x = {x}");
        }
    }
}
