//! Passes join volumes and the GPU: each module records the dispatches of one technique and has a
//! CPU twin in `volume::reference` that tests compare it with.

pub mod chunked;
pub mod gpu_volume;
pub mod importance;
pub mod lines;
pub mod normals;
pub mod occlusion;
pub mod occlusion_analysis;
pub mod occlusion_fft;
pub mod paging;
pub mod volume_image;

/// The values of the box `lo .. lo + size` of a grid laid out x fastest in `values`, whose rows
/// are `pitch` values apart with `rows` rows (y) to a slab (z): row by row, x fastest. What a
/// chunked pass keeps of a box it read back; the caller checks the box lies in the grid.
pub(crate) fn box_rows<T: Copy>(
    values: &[T],
    (pitch, rows): (usize, usize),
    (lo, size): ([usize; 3], [usize; 3]),
) -> Vec<T> {
    let mut kept = Vec::with_capacity(size.iter().product());
    for z in lo[2]..lo[2] + size[2] {
        for y in lo[1]..lo[1] + size[1] {
            let row = lo[0] + pitch * (y + rows * z);
            kept.extend_from_slice(&values[row..row + size[0]]);
        }
    }
    kept
}
