//! OME-Zarr multiscale images (issue 26): NGFF 0.4 on Zarr v2 and NGFF 0.5 on Zarr v3, read and
//! written through `zarrs`. The NGFF layer here is small: the `multiscales` metadata (axes, the
//! datasets' paths and their scale and translation) in the root group's attributes, under `ome`
//! for 0.5. The arrays hold (z, y, x), or (t, c, z, y, x) with one time point and one channel; C
//! order with x fastest is our voxel order, so a level's bytes are a `Volume`'s as they come.
//!
//! NGFF has no rotation: a volume written with a direction matrix keeps its origin and spacing
//! and loses its directions (`write` says so once), and a store read back has no anatomical
//! orientation.
//!
//! Missing chunks read as the array's fill value, as the Zarr spec says.

use crate::error::{Error, Result};
use crate::volume::geometry::Geometry;
use crate::volume::source::BoxSource;
use crate::volume::{Volume, VoxelData, VoxelType};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use zarrs::array::{data_type, Array, ArrayBuilder, ArraySubset};
use zarrs::filesystem::FilesystemStore;

/// One level of a multiscale image.
#[derive(Clone, Debug, PartialEq)]
pub struct Level {
    /// The array's path in the store ("0", "1", …).
    pub path: String,
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// Chunk edge along x, y, z.
    pub chunk: [usize; 3],
    /// Physical voxel size along x, y, z (the dataset's scale).
    pub spacing: [f64; 3],
    /// Physical position of voxel (0, 0, 0) along x, y, z (the dataset's translation).
    pub origin: [f64; 3],
}

/// An opened OME-Zarr multiscale image: its levels, finest first.
pub struct Multiscale {
    pub root: PathBuf,
    /// The NGFF version, "0.4" or "0.5".
    pub version: String,
    pub voxel: VoxelType,
    pub levels: Vec<Level>,
    /// Level 0's value range when the writer recorded it (`vellum.range`, written by vellum).
    pub range: Option<[f64; 2]>,
    /// Leading axes of size 1 (t and c) before z, y, x.
    leading: usize,
    /// The levels' arrays, opened once.
    arrays: Vec<Array<FilesystemStore>>,
}

/// Whether `path` names an OME-Zarr store: a folder whose name ends in `.zarr`.
pub fn is_store(path: &Path) -> bool {
    path.is_dir()
        && path
            .file_name()
            .is_some_and(|n| n.to_string_lossy().to_lowercase().ends_with(".zarr"))
}

fn invalid(path: &Path, what: impl std::fmt::Display) -> Error {
    Error::format(path, what.to_string())
}

impl Multiscale {
    /// Opens the store at `path` and reads its multiscale metadata (no voxels yet).
    pub fn open(path: &Path) -> Result<Self> {
        let store =
            Arc::new(FilesystemStore::new(path).map_err(|e| {
                invalid(path, format!("could not be opened as a Zarr store ({e})"))
            })?);
        let group = zarrs::group::Group::open(store.clone(), "/").map_err(|e| {
            invalid(
                path,
                format!("has no readable Zarr group at its root ({e}); expected an OME-Zarr image"),
            )
        })?;
        let attrs = Value::Object(group.attributes().clone());
        let (version, ms) = multiscales(path, &attrs)?;
        let axes = axis_names(path, ms)?;
        let leading = axes.len() - 3;
        let datasets = ms["datasets"]
            .as_array()
            .filter(|d| !d.is_empty())
            .ok_or_else(|| {
                invalid(
                    path,
                    "multiscales[0] lists no datasets; expected at least one level",
                )
            })?;
        let mut levels = Vec::new();
        let mut arrays = Vec::new();
        let mut voxel = None;
        for (i, d) in datasets.iter().enumerate() {
            let name = d["path"]
                .as_str()
                .ok_or_else(|| invalid(path, format!("dataset {i} has no path")))?;
            let array = Array::open(store.clone(), &format!("/{name}"))
                .map_err(|e| invalid(path, format!("level {name} could not be opened ({e})")))?;
            let t = voxel_type(path, name, &array)?;
            if voxel.is_some_and(|v| v != t) {
                return Err(invalid(
                    path,
                    format!("level {name} holds another data type than level 0; expected one type for every level"),
                ));
            }
            voxel = Some(t);
            levels.push(level(path, name, &array, d, leading)?);
            arrays.push(array);
        }
        check_levels(path, &levels)?;
        let range = attrs["vellum"]["range"]
            .as_array()
            .and_then(|r| Some([r.first()?.as_f64()?, r.get(1)?.as_f64()?]))
            .filter(|r| r[0] <= r[1]);
        Ok(Multiscale {
            range,
            root: path.to_path_buf(),
            version,
            voxel: voxel.expect("at least one level"),
            levels,
            leading,
            arrays,
        })
    }

    /// Reads level `level` whole, as a volume with the level's spacing and origin.
    pub fn read_level(&self, level: usize) -> Result<Volume> {
        let l = self.level_info(level)?;
        let v = self.read_box(level, [0; 3], l.dims)?;
        let geometry = Geometry {
            origin: l.origin,
            ..Geometry::default()
        };
        v.with_geometry(geometry)
    }

    fn level_info(&self, level: usize) -> Result<&Level> {
        self.levels.get(level).ok_or_else(|| {
            invalid(
                &self.root,
                format!("has no level {level}; it has {}", self.levels.len()),
            )
        })
    }

    /// Voxels `lo .. lo + size` of level `level` (inside its dims), with the level's spacing.
    /// Missing chunks read as the fill value; a corrupt one is named by its key.
    pub fn read_box(&self, level: usize, lo: [usize; 3], size: [usize; 3]) -> Result<Volume> {
        let l = self.level_info(level)?;
        let data = retrieve(&self.arrays[level], self.leading, self.voxel, lo, size)
            .map_err(|e| self.read_error(level, lo, size, e))?;
        Volume::new(size, l.spacing, data)
    }

    /// The error of a box that could not be read, naming the first chunk of the box that fails
    /// to decode (by its key in the store) when one does.
    fn read_error(
        &self,
        level: usize,
        lo: [usize; 3],
        size: [usize; 3],
        cause: Box<dyn std::error::Error>,
    ) -> Error {
        let (l, array) = (&self.levels[level], &self.arrays[level]);
        let range = |a: usize| lo[a] / l.chunk[a]..=(lo[a] + size[a] - 1) / l.chunk[a];
        for z in range(2) {
            for y in range(1) {
                for x in range(0) {
                    let mut index = vec![0u64; self.leading];
                    index.extend([z, y, x].map(|i| i as u64));
                    let chunk = array.retrieve_chunk::<zarrs::array::ArrayBytes<'static>>(&index);
                    if let Err(e) = chunk {
                        // The key in the store, from its root.
                        let key = array.chunk_key(&index);
                        let key = key.as_str().trim_start_matches('/');
                        let key = match key.starts_with(&format!("{}/", l.path)) {
                            true => key.to_string(),
                            false => format!("{}/{key}", l.path),
                        };
                        return invalid(
                            &self.root,
                            format!("chunk {key} of level {} could not be read ({e})", l.path),
                        );
                    }
                }
            }
        }
        invalid(
            &self.root,
            format!("level {} could not be read ({cause})", l.path),
        )
    }

    /// Bytes of level `level` in memory (0 for a level the store does not have).
    pub fn level_bytes(&self, level: usize) -> u64 {
        self.levels.get(level).map_or(0, |l| {
            l.dims.iter().map(|&n| n as u64).product::<u64>() * self.voxel.size() as u64
        })
    }

    /// Level `level` as a [`BoxSource`].
    pub fn level(&self, level: usize) -> Result<StoreLevel<'_>> {
        self.level_info(level)?;
        Ok(StoreLevel { ms: self, level })
    }
}

/// Voxels `lo .. lo + size` of `array`, whose first `leading` axes have size 1.
fn retrieve(
    array: &Array<FilesystemStore>,
    leading: usize,
    voxel: VoxelType,
    lo: [usize; 3],
    size: [usize; 3],
) -> std::result::Result<VoxelData, Box<dyn std::error::Error>> {
    let mut ranges: Vec<std::ops::Range<u64>> = vec![0..1; leading];
    ranges.extend([2, 1, 0].map(|a| lo[a] as u64..(lo[a] + size[a]) as u64));
    let subset = ArraySubset::new_with_ranges(&ranges);
    Ok(match voxel {
        VoxelType::U8 => VoxelData::U8(array.retrieve_array_subset(&subset)?),
        VoxelType::U16 => VoxelData::U16(array.retrieve_array_subset(&subset)?),
        VoxelType::I16 => VoxelData::I16(array.retrieve_array_subset(&subset)?),
        VoxelType::F32 => VoxelData::F32(array.retrieve_array_subset(&subset)?),
    })
}

/// One level of a store, read a box at a time.
pub struct StoreLevel<'a> {
    ms: &'a Multiscale,
    level: usize,
}

impl BoxSource for StoreLevel<'_> {
    fn dims(&self) -> [usize; 3] {
        self.ms.levels[self.level].dims
    }
    fn spacing(&self) -> [f64; 3] {
        self.ms.levels[self.level].spacing
    }
    fn geometry(&self) -> Geometry {
        Geometry {
            origin: self.ms.levels[self.level].origin,
            ..Geometry::default()
        }
    }
    fn voxel(&self) -> VoxelType {
        self.ms.voxel
    }
    fn read_box(&self, lo: [usize; 3], size: [usize; 3]) -> Result<Volume> {
        self.ms.read_box(self.level, lo, size)
    }
}

/// The NGFF version and the first multiscale of the root attributes: under `ome` for 0.5, at the
/// top for 0.4.
fn multiscales<'a>(path: &Path, attrs: &'a Value) -> Result<(String, &'a Value)> {
    let (version, list) = match attrs.get("ome") {
        Some(ome) => (
            ome["version"].as_str().map(str::to_string),
            &ome["multiscales"],
        ),
        None => (None, &attrs["multiscales"]),
    };
    let ms = list.as_array().and_then(|l| l.first()).ok_or_else(|| {
        invalid(
            path,
            "has no OME-NGFF multiscales metadata; expected an OME-Zarr image",
        )
    })?;
    let version = version
        .or_else(|| ms["version"].as_str().map(str::to_string))
        .unwrap_or_default();
    if version != "0.4" && version != "0.5" {
        return Err(invalid(
            path,
            format!("is OME-NGFF version {version:?}; expected 0.4 or 0.5"),
        ));
    }
    Ok((version, ms))
}

/// The axes' names: (z, y, x), or (t, c, z, y, x).
fn axis_names(path: &Path, ms: &Value) -> Result<Vec<String>> {
    let names: Vec<String> = ms["axes"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|x| {
                    x["name"]
                        .as_str()
                        .or(x.as_str())
                        .unwrap_or("")
                        .to_lowercase()
                })
                .collect()
        })
        .unwrap_or_default();
    let ok = names == ["z", "y", "x"] || names == ["t", "c", "z", "y", "x"];
    if !ok {
        return Err(invalid(
            path,
            format!("has axes {names:?}; expected (z, y, x) or (t, c, z, y, x)"),
        ));
    }
    Ok(names)
}

fn voxel_type(path: &Path, name: &str, array: &Array<FilesystemStore>) -> Result<VoxelType> {
    let t = array.data_type();
    Ok(if *t == data_type::uint8() {
        VoxelType::U8
    } else if *t == data_type::uint16() {
        VoxelType::U16
    } else if *t == data_type::int16() {
        VoxelType::I16
    } else if *t == data_type::float32() {
        VoxelType::F32
    } else {
        return Err(invalid(
            path,
            format!("level {name} holds an unsupported data type; expected uint8, uint16, int16 or float32"),
        ));
    })
}

/// One level from its array and its dataset entry (scale and translation, z y x order).
fn level(
    path: &Path,
    name: &str,
    array: &Array<FilesystemStore>,
    d: &Value,
    leading: usize,
) -> Result<Level> {
    let shape = array.shape();
    if shape.len() != leading + 3 {
        return Err(invalid(
            path,
            format!(
                "level {name} has {} dimensions; the axes name {}",
                shape.len(),
                leading + 3
            ),
        ));
    }
    if shape[..leading].iter().any(|&n| n != 1) {
        return Err(invalid(
            path,
            format!(
                "level {name} holds {} time points and {} channels; expected one of each",
                shape[0], shape[1]
            ),
        ));
    }
    let chunk = array.chunk_shape(&vec![0; shape.len()]).map_err(|e| {
        invalid(
            path,
            format!("level {name} has no regular chunk grid ({e})"),
        )
    })?;
    let zyx = |v: &[u64]| -> [usize; 3] {
        [
            v[leading + 2] as usize,
            v[leading + 1] as usize,
            v[leading] as usize,
        ]
    };
    let chunk: Vec<u64> = chunk.iter().map(|c| c.get()).collect();
    let mut spacing = [1.0; 3];
    let mut origin = [0.0; 3];
    for t in d["coordinateTransformations"]
        .as_array()
        .into_iter()
        .flatten()
    {
        let key = match t["type"].as_str() {
            Some("scale") => "scale",
            Some("translation") => "translation",
            _ => continue,
        };
        let v: Vec<f64> = t[key]
            .as_array()
            .map(|a| a.iter().filter_map(Value::as_f64).collect())
            .unwrap_or_default();
        if v.len() != leading + 3 || v.iter().any(|x| !x.is_finite()) {
            return Err(invalid(
                path,
                format!(
                    "level {name}'s {key} is {:?}; expected {} finite numbers",
                    t[key],
                    leading + 3
                ),
            ));
        }
        let xyz = [v[leading + 2], v[leading + 1], v[leading]];
        match key {
            "scale" => spacing = xyz.map(f64::abs),
            _ => origin = xyz,
        }
    }
    if spacing.contains(&0.0) {
        return Err(invalid(
            path,
            format!("level {name} has a zero scale; expected positive voxel sizes"),
        ));
    }
    Ok(Level {
        path: name.to_string(),
        dims: zyx(shape),
        chunk: zyx(&chunk),
        spacing,
        origin,
    })
}

/// Each level no larger than the one before it, and level 0 not empty.
fn check_levels(path: &Path, levels: &[Level]) -> Result<()> {
    for w in levels.windows(2) {
        if (0..3).any(|a| w[1].dims[a] > w[0].dims[a]) {
            return Err(invalid(
                path,
                format!(
                    "level {} ({:?}) is larger than level {} ({:?}); expected levels from finest to coarsest",
                    w[1].path, w[1].dims, w[0].path, w[0].dims
                ),
            ));
        }
    }
    Ok(())
}

/// How to write a store.
#[derive(Clone, Debug)]
pub struct WriteOptions {
    /// Chunk edge in voxels.
    pub chunk: usize,
    /// Levels to write; `None`: halve until the longest axis is at most 64 voxels.
    pub levels: Option<usize>,
}

impl Default for WriteOptions {
    fn default() -> Self {
        WriteOptions {
            chunk: 64,
            levels: None,
        }
    }
}

/// The number of levels `auto` gives for `dims`: halve until the longest axis is ≤ 64.
pub fn auto_levels(dims: [usize; 3]) -> usize {
    let mut longest = dims.into_iter().max().unwrap_or(1);
    let mut n = 1;
    while longest > 64 {
        longest = longest.div_ceil(2);
        n += 1;
    }
    n
}

/// Writes `v` as an NGFF 0.5 (Zarr v3) multiscale image at `path`; see [`write_source`].
pub fn write(path: &Path, v: &Volume, opts: &WriteOptions) -> Result<WriteReport> {
    write_source(path, v, opts, &|| {})
}

/// What writing a store did.
#[derive(Clone, Debug, PartialEq)]
pub struct WriteReport {
    pub levels: usize,
    /// Chunks written, over all levels (chunks that hold only the fill value are not stored).
    pub chunks: usize,
    /// Uncompressed bytes of every level.
    pub bytes: u64,
    /// Smallest and largest value of level 0.
    pub range: [f64; 2],
}

/// The number of chunks `write_source` makes for a grid of `dims`: `on_chunk`'s count.
pub fn chunk_count(dims: [usize; 3], opts: &WriteOptions) -> usize {
    let levels = opts.levels.unwrap_or_else(|| auto_levels(dims));
    (0..levels)
        .map(|i| {
            let d = level_dims(dims, i);
            (0..3)
                .map(|a| d[a].div_ceil(opts.chunk.max(1)))
                .product::<usize>()
        })
        .sum()
}

/// Dims of pyramid level `i` of a grid of `dims`.
fn level_dims(dims: [usize; 3], i: usize) -> [usize; 3] {
    dims.map(|n| (0..i).fold(n, |n, _| n.div_ceil(2)))
}

/// Writes `src` as an NGFF 0.5 (Zarr v3) multiscale image at `path` (a folder that must not exist
/// yet), zstd-compressed, each level the 2×2×2 mean of the one before it, one chunk at a time:
/// level 0 from boxes of `src`, each coarser level from boxes of the level just written, so memory
/// holds a few chunks whatever the grid's size. `on_chunk` is called after each chunk (a progress
/// bar). The store is written under a temporary name and renamed into place once complete, so no
/// partial store is left. Level 0's value range goes in the root attributes (`vellum.range`), so
/// that a reader can normalise intensities without reading every voxel.
pub fn write_source(
    path: &Path,
    src: &dyn BoxSource,
    opts: &WriteOptions,
    on_chunk: &(dyn Fn() + Sync),
) -> Result<WriteReport> {
    if opts.chunk == 0 {
        return Err(Error::Invalid(
            "`chunk` is 0; expected a chunk edge of 1 voxel or more".into(),
        ));
    }
    let levels = opts.levels.unwrap_or_else(|| auto_levels(src.dims()));
    if levels == 0 {
        return Err(Error::Invalid("`levels` is 0; expected 1 or more".into()));
    }
    if src.geometry().direction != crate::volume::geometry::IDENTITY {
        log::warn!(
            "OME-NGFF has no rotation: {} keeps the origin and spacing and drops the direction matrix",
            path.display()
        );
    }
    let name = path
        .file_name()
        .map(|n| {
            n.to_string_lossy()
                .trim_end_matches(".zarr")
                .trim_end_matches(".ome")
                .to_string()
        })
        .unwrap_or_default();
    let mut report = None;
    crate::output::write_folder_atomic(path, |tmp| {
        report = Some(write_levels(tmp, &name, src, opts.chunk, levels, on_chunk)?);
        Ok(())
    })?;
    report.ok_or_else(|| Error::Invalid("the store was not written".into()))
}

fn write_levels(
    path: &Path,
    name: &str,
    src: &dyn BoxSource,
    chunk: usize,
    levels: usize,
    on_chunk: &(dyn Fn() + Sync),
) -> Result<WriteReport> {
    let store = Arc::new(FilesystemStore::new(path).map_err(|e| invalid(path, e))?);
    let mut datasets = Vec::new();
    let (voxel, dims0) = (src.voxel(), src.dims());
    let mut report = WriteReport {
        levels,
        chunks: 0,
        bytes: 0,
        range: [f64::INFINITY, f64::NEG_INFINITY],
    };
    let mut previous: Option<Array<FilesystemStore>> = None;
    for i in 0..levels {
        let dims = level_dims(dims0, i);
        let spacing = src.spacing().map(|s| s * (1u64 << i) as f64);
        let origin: [f64; 3] = std::array::from_fn(|a| {
            src.geometry().origin[a] + 0.5 * (spacing[a] - src.spacing()[a])
        });
        let array = make_array(&store, path, &i.to_string(), dims, chunk, voxel)?;
        let range = match &previous {
            None => store_chunks(
                &array,
                path,
                dims,
                chunk,
                &|lo, size| src.read_box(lo, size),
                on_chunk,
            )?,
            Some(prev) => {
                let prev_dims = level_dims(dims0, i - 1);
                let read = |lo: [usize; 3], size: [usize; 3]| -> Result<Volume> {
                    let plo = lo.map(|v| 2 * v);
                    let psize: [usize; 3] =
                        std::array::from_fn(|a| (2 * size[a]).min(prev_dims[a] - plo[a]));
                    let data = retrieve(prev, 0, voxel, plo, psize).map_err(|e| {
                        invalid(
                            path,
                            format!("level {} could not be read back ({e})", i - 1),
                        )
                    })?;
                    halve(&Volume::new(psize, [1.0; 3], data)?)
                };
                store_chunks(&array, path, dims, chunk, &read, on_chunk)?
            }
        };
        if i == 0 {
            report.range = range;
        }
        report.chunks += (0..3).map(|a| dims[a].div_ceil(chunk)).product::<usize>();
        report.bytes += (dims[0] * dims[1] * dims[2] * voxel.size()) as u64;
        previous = Some(array);
        datasets.push(json!({
            "path": i.to_string(),
            "coordinateTransformations": [
                {"type": "scale", "scale": [spacing[2], spacing[1], spacing[0]]},
                {"type": "translation", "translation": [origin[2], origin[1], origin[0]]},
            ],
        }));
    }
    let mut group = zarrs::group::GroupBuilder::new()
        .build(store, "/")
        .map_err(|e| invalid(path, e))?;
    let attrs = group.attributes_mut();
    attrs.insert(
        "ome".into(),
        json!({
            "version": "0.5",
            "multiscales": [{
                "name": name,
                "axes": [
                    {"name": "z", "type": "space"},
                    {"name": "y", "type": "space"},
                    {"name": "x", "type": "space"},
                ],
                "datasets": datasets,
            }],
        }),
    );
    attrs.insert("vellum".into(), json!({ "range": report.range }));
    group.store_metadata().map_err(|e| invalid(path, e))?;
    Ok(report)
}

/// An empty level of `dims` in `voxel`, chunked by `chunk`, zstd-compressed, metadata stored.
fn make_array(
    store: &Arc<FilesystemStore>,
    path: &Path,
    name: &str,
    dims: [usize; 3],
    chunk: usize,
    voxel: VoxelType,
) -> Result<Array<FilesystemStore>> {
    let shape: Vec<u64> = [dims[2], dims[1], dims[0]]
        .iter()
        .map(|&n| n as u64)
        .collect();
    let chunks: Vec<u64> = shape
        .iter()
        .map(|&n| (chunk as u64).min(n).max(1))
        .collect();
    let (dtype, fill): (zarrs::array::DataType, zarrs::array::FillValue) = match voxel {
        VoxelType::U8 => (data_type::uint8(), 0u8.into()),
        VoxelType::U16 => (data_type::uint16(), 0u16.into()),
        VoxelType::I16 => (data_type::int16(), 0i16.into()),
        VoxelType::F32 => (data_type::float32(), 0f32.into()),
    };
    let array = ArrayBuilder::new(shape, chunks, dtype, fill)
        .bytes_to_bytes_codecs(vec![Arc::new(zarrs::array::codec::ZstdCodec::new(
            3, false,
        ))])
        .dimension_names(Some(["z", "y", "x"]))
        .build(store.clone(), &format!("/{name}"))
        .map_err(|e| invalid(path, format!("level {name} could not be made ({e})")))?;
    array.store_metadata().map_err(|e| {
        invalid(
            path,
            format!("level {name}'s metadata could not be written ({e})"),
        )
    })?;
    Ok(array)
}

/// Fills `array` (a level of `dims`) chunk by chunk from `read(lo, size)`, chunks in parallel;
/// returns the smallest and largest value written.
///
/// The chunks run on plain threads, one per core, not as rayon tasks: `read` may hold a lock
/// while it calls into rayon (the chunked passes share one GPU pipeline behind a mutex, and its
/// packing is parallel), and a rayon worker waiting for that inner work steals other tasks,
/// which can be another chunk that waits for the lock its own thread holds. That deadlocked a
/// 512³ chunked importance map on a 16-core machine.
fn store_chunks(
    array: &Array<FilesystemStore>,
    path: &Path,
    dims: [usize; 3],
    chunk: usize,
    read: &(dyn Fn([usize; 3], [usize; 3]) -> Result<Volume> + Sync),
    on_chunk: &(dyn Fn() + Sync),
) -> Result<[f64; 2]> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let counts = dims.map(|n| n.div_ceil(chunk));
    let total = counts[0] * counts[1] * counts[2];
    let one = |c: usize| -> Result<[f64; 2]> {
        let index = [
            c % counts[0],
            (c / counts[0]) % counts[1],
            c / (counts[0] * counts[1]),
        ];
        let lo = index.map(|i| i * chunk);
        let size: [usize; 3] = std::array::from_fn(|a| chunk.min(dims[a] - lo[a]));
        let v = read(lo, size)?;
        let range = crate::volume::stats::value_range(&v);
        let ranges: Vec<std::ops::Range<u64>> = [2, 1, 0]
            .iter()
            .map(|&a| lo[a] as u64..(lo[a] + size[a]) as u64)
            .collect();
        let subset = ArraySubset::new_with_ranges(&ranges);
        let stored = match &v.data {
            VoxelData::U8(d) => array.store_array_subset(&subset, d.as_slice()),
            VoxelData::U16(d) => array.store_array_subset(&subset, d.as_slice()),
            VoxelData::I16(d) => array.store_array_subset(&subset, d.as_slice()),
            VoxelData::F32(d) => array.store_array_subset(&subset, d.as_slice()),
        };
        stored.map_err(|e| invalid(path, format!("chunk {index:?} could not be written ({e})")))?;
        on_chunk();
        Ok(range)
    };
    let next = AtomicUsize::new(0);
    // Each thread takes the next chunk until none is left or one has failed (then every thread
    // stops at its next chunk).
    let worker = || -> Result<[f64; 2]> {
        let mut acc = [f64::INFINITY, f64::NEG_INFINITY];
        loop {
            let c = next.fetch_add(1, Ordering::Relaxed);
            if c >= total {
                return Ok(acc);
            }
            match one(c) {
                Ok(r) => acc = [acc[0].min(r[0]), acc[1].max(r[1])],
                Err(e) => {
                    next.store(total, Ordering::Relaxed);
                    return Err(e);
                }
            }
        }
    };
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(total.max(1));
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads).map(|_| s.spawn(worker)).collect();
        let mut acc = [f64::INFINITY, f64::NEG_INFINITY];
        for h in handles {
            let r = h
                .join()
                .map_err(|_| invalid(path, "a chunk's thread failed".to_string()))??;
            acc = [acc[0].min(r[0]), acc[1].max(r[1])];
        }
        Ok(acc)
    })
}

/// The 2×2×2 mean of `v` (odd edges average what they have), in the same voxel type, with
/// doubled spacing and the origin moved to the first output voxel's centre.
pub fn halve(v: &Volume) -> Result<Volume> {
    let d = v.dims;
    let out = d.map(|n| n.div_ceil(2));
    let mut sums = vec![0f64; out[0] * out[1] * out[2]];
    let mut counts = vec![0u32; sums.len()];
    for z in 0..d[2] {
        for y in 0..d[1] {
            for x in 0..d[0] {
                let o = x / 2 + out[0] * (y / 2 + out[1] * (z / 2));
                sums[o] += v.data.get_f64(x + d[0] * (y + d[1] * z));
                counts[o] += 1;
            }
        }
    }
    let mean = |i: usize| sums[i] / counts[i] as f64;
    let n = sums.len();
    let data = match &v.data {
        VoxelData::U8(_) => VoxelData::U8((0..n).map(|i| mean(i).round() as u8).collect()),
        VoxelData::U16(_) => VoxelData::U16((0..n).map(|i| mean(i).round() as u16).collect()),
        VoxelData::I16(_) => VoxelData::I16((0..n).map(|i| mean(i).round() as i16).collect()),
        VoxelData::F32(_) => VoxelData::F32((0..n).map(|i| mean(i) as f32).collect()),
    };
    let spacing = v.spacing.map(|s| 2.0 * s);
    let geometry = Geometry {
        origin: std::array::from_fn(|a| v.geometry.origin[a] + 0.5 * v.spacing[a]),
        ..v.geometry
    };
    Volume::new(out, spacing, data)?.with_geometry(geometry)
}
