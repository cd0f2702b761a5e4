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
        Ok(Multiscale {
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
        let l = self.levels.get(level).ok_or_else(|| {
            invalid(
                &self.root,
                format!("has no level {level}; it has {}", self.levels.len()),
            )
        })?;
        let array = &self.arrays[level];
        let mut ranges: Vec<std::ops::Range<u64>> = vec![0..1; self.leading];
        ranges.extend([l.dims[2], l.dims[1], l.dims[0]].map(|n| 0..n as u64));
        let subset = ArraySubset::new_with_ranges(&ranges);
        let read_error = |e: zarrs::array::ArrayError| {
            invalid(
                &self.root,
                format!("level {} could not be read ({e})", l.path),
            )
        };
        let data = match self.voxel {
            VoxelType::U8 => {
                VoxelData::U8(array.retrieve_array_subset(&subset).map_err(read_error)?)
            }
            VoxelType::U16 => {
                VoxelData::U16(array.retrieve_array_subset(&subset).map_err(read_error)?)
            }
            VoxelType::I16 => {
                VoxelData::I16(array.retrieve_array_subset(&subset).map_err(read_error)?)
            }
            VoxelType::F32 => {
                VoxelData::F32(array.retrieve_array_subset(&subset).map_err(read_error)?)
            }
        };
        let geometry = Geometry {
            origin: l.origin,
            ..Geometry::default()
        };
        Volume::new(l.dims, l.spacing, data)?.with_geometry(geometry)
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

/// Writes `v` as an NGFF 0.5 (Zarr v3) multiscale image at `path` (a folder that must not exist
/// yet), zstd-compressed, each level the 2×2×2 mean of the one before it. The store is written
/// under a temporary name and renamed into place once complete, so no partial store is left.
pub fn write(path: &Path, v: &Volume, opts: &WriteOptions) -> Result<()> {
    if opts.chunk == 0 {
        return Err(Error::Invalid(
            "`chunk` is 0; expected a chunk edge of 1 voxel or more".into(),
        ));
    }
    let levels = opts.levels.unwrap_or_else(|| auto_levels(v.dims));
    if levels == 0 {
        return Err(Error::Invalid("`levels` is 0; expected 1 or more".into()));
    }
    if v.geometry.direction != crate::volume::geometry::IDENTITY {
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
    crate::output::write_folder_atomic(path, |tmp| write_levels(tmp, &name, v, opts.chunk, levels))
}

fn write_levels(path: &Path, name: &str, v: &Volume, chunk: usize, levels: usize) -> Result<()> {
    let store = Arc::new(FilesystemStore::new(path).map_err(|e| invalid(path, e))?);
    let mut datasets = Vec::new();
    // Level 0 is written from `v` itself; each coarser level is made from the one before.
    let mut coarser: Option<Volume> = None;
    for i in 0..levels {
        if i > 0 {
            coarser = Some(halve(coarser.as_ref().unwrap_or(v))?);
        }
        let current = coarser.as_ref().unwrap_or(v);
        write_array(&store, path, &i.to_string(), current, chunk)?;
        let s = current.spacing;
        let o = current.geometry.origin;
        datasets.push(json!({
            "path": i.to_string(),
            "coordinateTransformations": [
                {"type": "scale", "scale": [s[2], s[1], s[0]]},
                {"type": "translation", "translation": [o[2], o[1], o[0]]},
            ],
        }));
    }
    let mut group = zarrs::group::GroupBuilder::new()
        .build(store, "/")
        .map_err(|e| invalid(path, e))?;
    group.attributes_mut().insert(
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
    group.store_metadata().map_err(|e| invalid(path, e))
}

fn write_array(
    store: &Arc<FilesystemStore>,
    path: &Path,
    name: &str,
    v: &Volume,
    chunk: usize,
) -> Result<()> {
    let shape: Vec<u64> = [v.dims[2], v.dims[1], v.dims[0]]
        .iter()
        .map(|&n| n as u64)
        .collect();
    let chunks: Vec<u64> = shape
        .iter()
        .map(|&n| (chunk as u64).min(n).max(1))
        .collect();
    let (dtype, fill): (zarrs::array::DataType, zarrs::array::FillValue) = match &v.data {
        VoxelData::U8(_) => (data_type::uint8(), 0u8.into()),
        VoxelData::U16(_) => (data_type::uint16(), 0u16.into()),
        VoxelData::I16(_) => (data_type::int16(), 0i16.into()),
        VoxelData::F32(_) => (data_type::float32(), 0f32.into()),
    };
    let array = ArrayBuilder::new(shape.clone(), chunks, dtype, fill)
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
    let ranges: Vec<std::ops::Range<u64>> = shape.iter().map(|&n| 0..n).collect();
    let subset = ArraySubset::new_with_ranges(&ranges);
    let stored = match &v.data {
        VoxelData::U8(d) => array.store_array_subset(&subset, d.as_slice()),
        VoxelData::U16(d) => array.store_array_subset(&subset, d.as_slice()),
        VoxelData::I16(d) => array.store_array_subset(&subset, d.as_slice()),
        VoxelData::F32(d) => array.store_array_subset(&subset, d.as_slice()),
    };
    stored.map_err(|e| invalid(path, format!("level {name} could not be written ({e})")))
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
