//! Volumes read a box at a time (issue 26): what `vellum convert` streams into a store, and what
//! the brick cache reads bricks from, without the whole grid in memory. A [`Volume`] in memory, a
//! [`Phantom`] sampled box by box, and one level of an OME-Zarr store (`io::ome_zarr::StoreLevel`)
//! are all sources.

use crate::geometry::Geometry;
use crate::phantom::Phantom;
use crate::{Volume, VoxelData, VoxelType};
use vellum_error::Result;

/// A grid that can be read a box at a time.
pub trait BoxSource: Sync {
    /// Voxels along x, y, z.
    fn dims(&self) -> [usize; 3];
    /// Voxel size along x, y, z.
    fn spacing(&self) -> [f64; 3];
    /// Origin and directions.
    fn geometry(&self) -> Geometry;
    /// The values' type.
    fn voxel(&self) -> VoxelType;
    /// Voxels `lo .. lo + size`, which must lie inside [`BoxSource::dims`], as a volume of that
    /// size (the source's spacing; the geometry is not moved).
    fn read_box(&self, lo: [usize; 3], size: [usize; 3]) -> Result<Volume>;
}

impl<T: BoxSource + ?Sized> BoxSource for &T {
    fn dims(&self) -> [usize; 3] {
        (**self).dims()
    }
    fn spacing(&self) -> [f64; 3] {
        (**self).spacing()
    }
    fn geometry(&self) -> Geometry {
        (**self).geometry()
    }
    fn voxel(&self) -> VoxelType {
        (**self).voxel()
    }
    fn read_box(&self, lo: [usize; 3], size: [usize; 3]) -> Result<Volume> {
        (**self).read_box(lo, size)
    }
}

impl BoxSource for Volume {
    fn dims(&self) -> [usize; 3] {
        self.dims
    }
    fn spacing(&self) -> [f64; 3] {
        self.spacing
    }
    fn geometry(&self) -> Geometry {
        self.geometry
    }
    fn voxel(&self) -> VoxelType {
        self.voxel_type()
    }
    fn read_box(&self, lo: [usize; 3], size: [usize; 3]) -> Result<Volume> {
        let rows = (0..size[2]).flat_map(|z| (0..size[1]).map(move |y| (y, z)));
        let starts: Vec<usize> = rows
            .map(|(y, z)| self.index(lo[0], lo[1] + y, lo[2] + z))
            .collect();
        let w = size[0];
        fn gather<T: Copy>(src: &[T], starts: &[usize], w: usize) -> Vec<T> {
            let mut out = Vec::with_capacity(starts.len() * w);
            for &s in starts {
                out.extend_from_slice(&src[s..s + w]);
            }
            out
        }
        let data = match &self.data {
            VoxelData::U8(d) => VoxelData::U8(gather(d, &starts, w)),
            VoxelData::U16(d) => VoxelData::U16(gather(d, &starts, w)),
            VoxelData::I16(d) => VoxelData::I16(gather(d, &starts, w)),
            VoxelData::F32(d) => VoxelData::F32(gather(d, &starts, w)),
        };
        Volume::new(size, self.spacing, data)
    }
}

impl BoxSource for Phantom {
    fn dims(&self) -> [usize; 3] {
        [self.n; 3]
    }
    fn spacing(&self) -> [f64; 3] {
        [1.0; 3]
    }
    fn geometry(&self) -> Geometry {
        Geometry::default()
    }
    fn voxel(&self) -> VoxelType {
        VoxelType::F32
    }
    fn read_box(&self, lo: [usize; 3], size: [usize; 3]) -> Result<Volume> {
        Ok(self.sample_box(lo, size))
    }
}

/// A float grid computed box by box from `src`: a box is read with `halo` more voxels on every
/// side (as far as the grid goes), and `f(box, offset, size)` returns its part `offset ..
/// offset + size`, the box asked for. What the chunked passes (importance, occlusion) write: a
/// filter whose reach is at most `halo` gives every kept voxel exactly as on the whole grid.
pub struct Halo<'a> {
    /// The grid.
    pub src: &'a dyn BoxSource,
    /// Voxels read beyond each box on every side.
    pub halo: usize,
    #[allow(clippy::type_complexity)]
    /// The filter: given the box read with its halo, the offset and size of the part to keep.
    pub f: &'a (dyn Fn(&Volume, [usize; 3], [usize; 3]) -> Result<Volume> + Sync),
}

impl BoxSource for Halo<'_> {
    fn dims(&self) -> [usize; 3] {
        self.src.dims()
    }
    fn spacing(&self) -> [f64; 3] {
        self.src.spacing()
    }
    fn geometry(&self) -> Geometry {
        self.src.geometry()
    }
    fn voxel(&self) -> VoxelType {
        VoxelType::F32
    }
    fn read_box(&self, lo: [usize; 3], size: [usize; 3]) -> Result<Volume> {
        let (v, offset) = read_widened(self.src, self.halo, lo, size)?;
        (self.f)(&v, offset, size)
    }
}

/// The box `lo .. lo + size` of `src` widened by `halo` on every side as far as the grid goes,
/// and where the box asked for starts in it.
pub fn read_widened(
    src: &dyn BoxSource,
    halo: usize,
    lo: [usize; 3],
    size: [usize; 3],
) -> Result<(Volume, [usize; 3])> {
    let dims = src.dims();
    let ext_lo = lo.map(|v| v.saturating_sub(halo));
    let ext_hi: [usize; 3] = std::array::from_fn(|a| (lo[a] + size[a] + halo).min(dims[a]));
    let ext_size: [usize; 3] = std::array::from_fn(|a| ext_hi[a] - ext_lo[a]);
    let v = src.read_box(ext_lo, ext_size)?;
    Ok((v, std::array::from_fn(|a| lo[a] - ext_lo[a])))
}

/// Voxels `lo .. lo + size` of `src` as f32, where the box may reach outside the grid: voxels
/// outside repeat the nearest edge voxel, as a clamp-to-edge sampler reads them. What the brick
/// cache fills a brick and its apron with.
#[cfg(test)]
pub(crate) fn read_box_clamped(
    src: &dyn BoxSource,
    lo: [i64; 3],
    size: [usize; 3],
) -> Result<Vec<f32>> {
    let dims = src.dims();
    let clamp = |v: i64, a: usize| v.clamp(0, dims[a] as i64 - 1) as usize;
    let inner_lo: [usize; 3] = std::array::from_fn(|a| clamp(lo[a], a));
    let inner_hi: [usize; 3] = std::array::from_fn(|a| clamp(lo[a] + size[a] as i64 - 1, a) + 1);
    let inner_size: [usize; 3] = std::array::from_fn(|a| inner_hi[a] - inner_lo[a]);
    let inner = src.read_box(inner_lo, inner_size)?;
    let mut out = vec![0f32; size[0] * size[1] * size[2]];
    let local = |v: i64, a: usize| clamp(v, a) - inner_lo[a];
    let xs: Vec<usize> = (0..size[0]).map(|i| local(lo[0] + i as i64, 0)).collect();
    for z in 0..size[2] {
        let lz = local(lo[2] + z as i64, 2);
        for y in 0..size[1] {
            let ly = local(lo[1] + y as i64, 1);
            let row = inner_size[0] * (ly + inner_size[1] * lz);
            let o = size[0] * (y + size[1] * z);
            for (x, &lx) in xs.iter().enumerate() {
                out[o + x] = inner.data.get_f64(row + lx) as f32;
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::phantom::Kind;

    #[test]
    fn a_phantom_box_is_the_box_of_the_whole_phantom() {
        for kind in [Kind::SheppLogan, Kind::Nested, Kind::Torus] {
            let p = Phantom { kind, n: 37 };
            let whole = p.volume();
            let lo = [5, 11, 20];
            let size = [19, 8, 17];
            let part = p.read_box(lo, size).unwrap();
            assert_eq!(part, whole.read_box(lo, size).unwrap(), "{kind:?}");
        }
    }

    #[test]
    fn clamped_boxes_repeat_the_edges() {
        let v = Volume::new([3, 2, 1], [1.0; 3], VoxelData::U8(vec![1, 2, 3, 4, 5, 6])).unwrap();
        let b = read_box_clamped(&v, [-1, 0, 0], [5, 1, 2]).unwrap();
        assert_eq!(b, vec![1.0, 1.0, 2.0, 3.0, 3.0, 1.0, 1.0, 2.0, 3.0, 3.0]);
        let b = read_box_clamped(&v, [1, 1, -2], [1, 2, 1]).unwrap();
        assert_eq!(b, vec![5.0, 5.0]);
    }
}
