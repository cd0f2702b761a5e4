//! OME-Zarr multiscale images (issue 26): NGFF 0.4 on Zarr v2 and NGFF 0.5 on Zarr v3, read and
//! written through `zarrs`. The NGFF layer here is small: the `multiscales` metadata (axes, the
//! datasets' paths and their scale and translation) in the root group's attributes, under `ome`
//! for 0.5. The arrays hold (z, y, x), (c, z, y, x), (t, z, y, x) or (t, c, z, y, x); one time
//! point and one channel are read ([`Pick`]: the `time` and `channels` options). C order with x
//! fastest is our voxel order, so a level's bytes are a `Volume`'s as they come.
//!
//! NGFF has no rotation: a volume written with a direction matrix keeps its origin and spacing
//! and loses its directions (`write` says so once), and a store read back has no anatomical
//! orientation.
//!
//! Missing chunks read as the array's fill value, as the Zarr spec says.

use super::guarded_store::GuardedStore;
use super::ngff_checks::{self, Limits};
use crate::geometry::Geometry;
use crate::source::BoxSource;
use crate::team::{Solo, Team};
use crate::{Volume, VoxelData, VoxelType};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use vellum_error::{Error, Result};
use zarrs::array::{data_type, Array, ArrayBuilder, ArraySubset};
use zarrs::filesystem::FilesystemStore;

pub use super::ngff_checks::Level;

/// An opened OME-Zarr multiscale image: its levels, finest first.
pub struct Multiscale {
    /// The store's folder, or its URL.
    pub root: PathBuf,
    /// The NGFF version, "0.4" or "0.5".
    pub version: String,
    /// The voxels' type in every level.
    pub voxel: VoxelType,
    /// The levels, finest first.
    pub levels: Vec<Level>,
    /// Level 0's value range when the writer recorded it (`vellum.range`, written by vellum; of
    /// the channel picked, `vellum.channel_ranges`, in a store of several).
    pub range: Option<[f64; 2]>,
    /// Values per voxel: the c axis's size (1 without one).
    pub channels: usize,
    /// Time points: the t axis's size (1 without one).
    pub times: usize,
    /// A label image's colours (NGFF `image-label` `colors`): id and RGBA.
    pub label_colours: Vec<(u32, [u8; 4])>,
    /// The channels' display settings (NGFF `omero` `channels`), by channel; empty without.
    pub omero: Vec<OmeroChannel>,
    /// Level 0's placement as vellum wrote it (`vellum.geometry`: origin, directions and
    /// space), which NGFF's scale and translation cannot hold; `None` for other writers' stores.
    pub placed: Option<Geometry>,
    /// The index on the leading axes (t, c) that is read: the time point and channel picked.
    lead: Vec<u64>,
    /// The levels' arrays, opened once, read through the store's guards.
    arrays: Vec<Array<GuardedStore>>,
    /// By level, whether a whole chunk decodes with zstd alone into a caller's buffer
    /// ([`zstd_alone`]).
    zstd_alone: Vec<bool>,
}

/// Whether `path` names an OME-Zarr store: a folder whose name ends in `.zarr` or that holds a
/// Zarr group's metadata (as a label image under `labels/` does), or an `http://` or `https://`
/// URL (read as a store whatever its name).
pub fn is_store(path: &Path) -> bool {
    if super::http_store::is_url(path) {
        return true;
    }
    let named = path
        .file_name()
        .is_some_and(|n| n.to_string_lossy().to_lowercase().ends_with(".zarr"));
    path.is_dir()
        && (named
            || ["zarr.json", ".zgroup", ".zattrs"]
                .iter()
                .any(|m| path.join(m).is_file()))
}

/// Level 0's geometry from vellum's attributes (`{origin, direction, space}`), when whole and
/// finite with unit directions.
fn placement(g: &Value) -> Option<Geometry> {
    let triple = |v: &Value| -> Option<[f64; 3]> {
        let a = v.as_array().filter(|a| a.len() == 3)?;
        let t = [a[0].as_f64()?, a[1].as_f64()?, a[2].as_f64()?];
        t.iter().all(|x| x.is_finite()).then_some(t)
    };
    let origin = triple(&g["origin"])?;
    let rows = g["direction"].as_array().filter(|r| r.len() == 3)?;
    let direction = [triple(&rows[0])?, triple(&rows[1])?, triple(&rows[2])?];
    let unit = (0..3).all(|c| {
        let n: f64 = (0..3).map(|r| direction[r][c] * direction[r][c]).sum();
        (n - 1.0).abs() < 1e-3
    });
    let space = match g["space"].as_str()? {
        "lps" => crate::geometry::Space::Lps,
        _ => crate::geometry::Space::Unknown,
    };
    unit.then_some(Geometry {
        origin,
        direction,
        space,
    })
}

/// A channel's display settings from NGFF `omero` metadata.
#[derive(Clone, Debug, PartialEq)]
pub struct OmeroChannel {
    /// Its colour, RGB.
    pub colour: [u8; 3],
    /// The window of values shown, in data units (`window.start`, `window.end`).
    pub window: Option<[f64; 2]>,
    /// Whether it is shown by default.
    pub active: bool,
    /// Its name.
    pub label: Option<String>,
}

/// The `omero` channels (at the attributes' root in 0.4, under `ome` in 0.5); a colour that is
/// not six hex digits reads as white.
fn omero_channels(attrs: &Value) -> Vec<OmeroChannel> {
    let omero = match &attrs["ome"]["omero"] {
        Value::Null => &attrs["omero"],
        o => o,
    };
    let Some(channels) = omero["channels"].as_array() else {
        return Vec::new();
    };
    channels
        .iter()
        .map(|c| {
            let hex = c["color"].as_str().unwrap_or("FFFFFF");
            let byte = |i: usize| {
                hex.get(i..i + 2)
                    .and_then(|h| u8::from_str_radix(h, 16).ok())
            };
            let colour = match (hex.len(), byte(0), byte(2), byte(4)) {
                (6, Some(r), Some(g), Some(b)) => [r, g, b],
                _ => [255; 3],
            };
            let w = &c["window"];
            let window = match (w["start"].as_f64(), w["end"].as_f64()) {
                (Some(a), Some(b)) if a < b => Some([a, b]),
                _ => None,
            };
            OmeroChannel {
                colour,
                window,
                active: c["active"].as_bool().unwrap_or(true),
                label: c["label"].as_str().map(str::to_string),
            }
        })
        .collect()
}

/// Which time point and channel of a store to read; `None` reads the only one and refuses a
/// store of several in one sentence that names the option.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Pick {
    /// The time point, from 0.
    pub time: Option<usize>,
    /// The channel, from 0.
    pub channel: Option<usize>,
}

fn invalid(path: &Path, what: impl std::fmt::Display) -> Error {
    Error::format(path, what.to_string())
}

impl Multiscale {
    /// Opens the store at `path` and reads its multiscale metadata (no voxels yet). A store of
    /// more than one channel or time point is refused in one sentence; see
    /// [`Multiscale::open_picked`].
    pub fn open(path: &Path) -> Result<Self> {
        Self::open_picked(path, Pick::default())
    }

    /// Opens the store at `path` to read channel `channel` of its c axis (0 for a store without
    /// one): a multi-channel store such as the normals' reads as one scalar grid per channel.
    pub fn open_channel(path: &Path, channel: usize) -> Result<Self> {
        Self::open_picked(
            path,
            Pick {
                time: None,
                channel: Some(channel),
            },
        )
    }

    /// Opens the store at `path` to read the time point and channel of `pick`.
    pub fn open_picked(path: &Path, pick: Pick) -> Result<Self> {
        let store =
            Arc::new(GuardedStore::new(path).map_err(|e| {
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
        let c_axis = axes.iter().position(|a| a == "c");
        let datasets = ms["datasets"]
            .as_array()
            .filter(|d| !d.is_empty())
            .ok_or_else(|| {
                invalid(
                    path,
                    "multiscales[0] lists no datasets; expected at least one level",
                )
            })?;
        ngff_checks::datasets(path, datasets)?;
        let mut levels = Vec::new();
        let mut arrays = Vec::new();
        let mut direct = Vec::new();
        let mut voxel = None;
        let names = datasets
            .iter()
            .enumerate()
            .map(|(i, d)| {
                d["path"]
                    .as_str()
                    .ok_or_else(|| invalid(path, format!("dataset {i} has no path")))
            })
            .collect::<Result<Vec<&str>>>()?;
        let mut opened = open_arrays(&store, &names, super::http_store::is_url(path)).into_iter();
        for (d, name) in datasets.iter().zip(names) {
            let array = opened
                .next()
                .ok_or_else(|| invalid(path, format!("level {name} could not be opened")))?
                .map_err(|e| invalid(path, format!("level {name} could not be opened ({e})")))?;
            let (limits, chunk_bytes) = Limits::of_array(path, name, &array)?;
            limits.check(path, name, leading)?;
            store.bound_array(name, chunk_bytes);
            let t = voxel_type(path, name, &array)?;
            if voxel.is_some_and(|v| v != t) {
                return Err(invalid(
                    path,
                    format!("level {name} holds another data type than level 0; expected one type for every level"),
                ));
            }
            voxel = Some(t);
            levels.push(level(path, name, &array, d, leading)?);
            direct.push(zstd_alone(&array, leading));
            arrays.push(array);
        }
        ngff_checks::multiscale_transforms(path, ms, leading, &mut levels)?;
        check_levels(path, &levels)?;
        ngff_checks::consistent_levels(path, &levels)?;
        let channels = c_axis.map_or(1, |c| arrays[0].shape()[c] as usize);
        if arrays
            .iter()
            .any(|a| c_axis.is_some_and(|c| a.shape()[c] as usize != channels))
        {
            return Err(invalid(
                path,
                "levels hold different numbers of channels; expected the same in every level",
            ));
        }
        let t_axis = axes.iter().position(|a| a == "t");
        let times = t_axis.map_or(1, |t| arrays[0].shape()[t] as usize);
        let mut lead = vec![0u64; leading];
        if let Some(c) = c_axis {
            lead[c] = pick_one(path, "channel", "channels", pick.channel, channels)? as u64;
        }
        if let Some(t) = t_axis {
            lead[t] = pick_one(path, "time point", "time", pick.time, times)? as u64;
        }
        // A store of several channels records each one's range: `range` spans them all.
        let recorded = match c_axis {
            Some(c) => &attrs["vellum"]["channel_ranges"][lead[c] as usize],
            None => &attrs["vellum"]["range"],
        };
        let range = recorded
            .as_array()
            .and_then(|r| Some([r.first()?.as_f64()?, r.get(1)?.as_f64()?]))
            .filter(|r| r[0] <= r[1]);
        Ok(Multiscale {
            placed: placement(&attrs["vellum"]["geometry"]),
            label_colours: label_colours(&attrs),
            omero: omero_channels(&attrs),
            range,
            root: path.to_path_buf(),
            version,
            voxel: voxel.expect("at least one level"),
            levels,
            channels,
            times,
            lead,
            arrays,
            zstd_alone: direct,
        })
    }

    /// Reads level `level` whole, as a volume with the level's spacing and origin.
    pub fn read_level(&self, level: usize) -> Result<Volume> {
        let l = self.level_info(level)?;
        let v = self.read_box(level, [0; 3], l.dims)?;
        v.with_geometry(self.geometry_of(level))
    }

    /// Level `level`'s origin, directions and space: as vellum recorded level 0's, with the
    /// level's offset from level 0 (its translation's) turned by the directions; else the
    /// translation as the origin, axis-aligned in no known space.
    pub fn geometry_of(&self, level: usize) -> Geometry {
        let at = self.levels.get(level).map_or([0.0; 3], |l| l.origin);
        let Some(g) = self.placed else {
            return Geometry {
                origin: at,
                ..Geometry::default()
            };
        };
        let shift: [f64; 3] = std::array::from_fn(|a| at[a] - self.levels[0].origin[a]);
        Geometry {
            origin: std::array::from_fn(|r| {
                g.origin[r] + (0..3).map(|c| g.direction[r][c] * shift[c]).sum::<f64>()
            }),
            ..g
        }
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
        let boxes = chunk_boxes(l.chunk, lo, size);
        if boxes.len() > 1 && super::http_store::is_url(&self.root) {
            return self.read_box_by_chunks(level, (lo, size), &boxes);
        }
        let data = retrieve(&self.arrays[level], &self.lead, self.voxel, lo, size)
            .map_err(|e| self.read_error(level, lo, size, e))?;
        Volume::new(size, l.spacing, data)
    }

    /// [`Multiscale::read_box`] into `out` (`size`'s voxels of the store's type), whose memory is
    /// reused: a type the store holds as it is decodes there in place, with no buffer of its
    /// own; one converted on the way (`int8`, the wide types) is read and then moved in.
    pub fn read_box_into(
        &self,
        level: usize,
        lo: [usize; 3],
        size: [usize; 3],
        out: &mut VoxelData,
    ) -> Result<()> {
        let l = self.level_info(level)?;
        let n: usize = size.iter().product();
        let array = &self.arrays[level];
        let plain = Some(self.voxel) == stored_as(array.data_type());
        let remote =
            chunk_boxes(l.chunk, lo, size).len() > 1 && super::http_store::is_url(&self.root);
        if !plain || remote || out.voxel_type() != self.voxel || out.len() != n {
            *out = self.read_box(level, lo, size)?.data;
            return Ok(());
        }
        if self.zstd_alone[level]
            && lo.iter().zip(l.chunk).all(|(o, c)| o % c == 0)
            && size == l.chunk
        {
            let mut at = self.lead.clone();
            at.extend([2, 1, 0].map(|a| (lo[a] / l.chunk[a]) as u64));
            match decode_zstd_into(array, &at, out) {
                Ok(true) => return Ok(()),
                // Absent: the fill value, as zarrs reads it.
                Ok(false) => {}
                Err(e) => return Err(self.read_error(level, lo, size, e)),
            }
        }
        retrieve_into(array, &box_subset(&self.lead, lo, size), out)
            .map_err(|e| self.read_error(level, lo, size, e))
    }

    /// [`Multiscale::read_box`] of a store on a server, chunk by chunk on
    /// [`REMOTE_READERS`] threads: each chunk is a request, and zarrs' own parallel read, on
    /// the decoders' pool of one thread a core, keeps only as many in flight as there are cores
    /// (two here, so a level of 64 chunks took 32 round trips).
    fn read_box_by_chunks(
        &self,
        level: usize,
        (lo, size): ([usize; 3], [usize; 3]),
        boxes: &[([usize; 3], [usize; 3])],
    ) -> Result<Volume> {
        use std::sync::atomic::{AtomicUsize, Ordering};
        let data = VoxelData::zeros(self.voxel, size.iter().product());
        let out = std::sync::Mutex::new(Volume::new(size, self.levels[level].spacing, data)?);
        let next = AtomicUsize::new(0);
        let read = || -> Result<()> {
            while let Some(&(blo, bsize)) = boxes.get(next.fetch_add(1, Ordering::Relaxed)) {
                let part = self.read_box(level, blo, bsize)?;
                out.lock()
                    .map_err(|_| Error::Invalid("a reader of the store stopped".into()))?
                    .paste(&part, blo, lo);
            }
            Ok(())
        };
        std::thread::scope(|s| {
            let readers: Vec<_> = (0..REMOTE_READERS.min(boxes.len()))
                .map(|_| s.spawn(read))
                .collect();
            readers.into_iter().try_for_each(|r| {
                r.join()
                    .unwrap_or_else(|_| Err(Error::Invalid("a reader of the store stopped".into())))
            })
        })?;
        out.into_inner()
            .map_err(|_| Error::Invalid("a reader of the store stopped".into()))
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
                    let index = self.chunk_index([x, y, z]);
                    let chunk = array.retrieve_chunk::<zarrs::array::ArrayBytes<'static>>(&index);
                    if let Err(e) = chunk {
                        let key = self.chunk_name(level, [x, y, z]);
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

    /// The key of chunk `c` (its place in level `level`'s chunk grid, x y z) in the store, from
    /// its root: `0/c/3/1/2`.
    fn chunk_name(&self, level: usize, c: [usize; 3]) -> String {
        let (l, array) = (&self.levels[level], &self.arrays[level]);
        let key = array.chunk_key(&self.chunk_index(c));
        let key = key.as_str().trim_start_matches('/');
        match key.starts_with(&format!("{}/", l.path)) {
            true => key.to_string(),
            false => format!("{}/{key}", l.path),
        }
    }

    /// Whether the store holds chunk `c` of level `level` now, when that can be told without
    /// reading it (in a folder; `None` on a server).
    pub fn holds_chunk(&self, level: usize, c: [usize; 3]) -> Option<bool> {
        let array = self.arrays.get(level)?;
        array
            .storage()
            .holds_locally(&array.chunk_key(&self.chunk_index(c)))
    }

    /// The zarrs index of chunk `c` (its place in a level's chunk grid, x y z): the leading
    /// axes' picked indices, then z, y, x.
    fn chunk_index(&self, c: [usize; 3]) -> Vec<u64> {
        let mut index = self.lead.clone();
        index.extend([c[2], c[1], c[0]].map(|i| i as u64));
        index
    }

    /// The sentence for chunk `c` of level `level`, which the store held when it was opened and
    /// no longer holds.
    pub fn vanished(&self, level: usize, c: [usize; 3]) -> Error {
        invalid(
            &self.root,
            format!(
                "chunk {} of level {} was in the store when it was opened and is gone now; the store changed while it was read",
                self.chunk_name(level, c),
                self.levels[level].path
            ),
        )
    }

    /// The finest level of at most `voxels` voxels (level 0 when it is that small), read whole
    /// for statistics and ranges; `None` when even the coarsest is larger.
    pub fn finest_within(&self, voxels: usize) -> Option<usize> {
        self.levels
            .iter()
            .position(|l| l.dims.iter().product::<usize>() <= voxels)
    }

    /// Bytes of level `level` in memory (0 for a level the store does not have).
    pub(crate) fn level_bytes(&self, level: usize) -> u64 {
        self.levels.get(level).map_or(0, |l| {
            l.dims.iter().map(|&n| n as u64).product::<u64>() * self.voxel.size() as u64
        })
    }

    /// The chunks of level `level` the store does not hold, which read as its fill value
    /// (Zarr writers, vellum's and zarr-python's by default, leave out chunks of the fill value
    /// alone): `None` on a server, where each chunk would be a request, and for levels of more
    /// than [`MAX_LISTED_CHUNKS`] chunks.
    pub fn absent_chunks(&self, level: usize) -> Result<Option<AbsentChunks>> {
        let l = self.level_info(level)?;
        let grid: [usize; 3] = std::array::from_fn(|a| l.dims[a].div_ceil(l.chunk[a].max(1)));
        let n = grid.iter().product::<usize>();
        let array = &self.arrays[level];
        let store = array.storage();
        // Chunk i's place in the grid (x fastest).
        let place = |i: usize| {
            [
                i % grid[0],
                (i / grid[0]) % grid[1],
                i / (grid[0] * grid[1]),
            ]
        };
        let held = |i: usize| store.holds_locally(&array.chunk_key(&self.chunk_index(place(i))));
        if n > MAX_LISTED_CHUNKS || held(0).is_none() {
            return Ok(None);
        }
        let absent: Vec<bool> = (0..n).map(|i| held(i) == Some(false)).collect();
        // The fill value as the readers see it: an absent chunk read.
        let Some(i) = absent.iter().position(|&a| a) else {
            return Ok(Some(AbsentChunks {
                grid,
                absent,
                value: 0.0,
            }));
        };
        let c = place(i);
        let lo: [usize; 3] = std::array::from_fn(|a| c[a] * l.chunk[a]);
        let one: [usize; 3] = std::array::from_fn(|a| l.chunk[a].min(1));
        let voxel = self.read_box(level, lo, one)?;
        let value = crate::chunks::Chunk::new(voxel).value();
        Ok(value.map(|value| AbsentChunks {
            grid,
            absent,
            value,
        }))
    }

    /// Level `level` as a [`BoxSource`].
    pub fn level(&self, level: usize) -> Result<StoreLevel<'_>> {
        self.level_info(level)?;
        Ok(StoreLevel { ms: self, level })
    }
}

/// Chunks per level at most that [`Multiscale::absent_chunks`] looks for: a file's presence
/// each (a 4096³ level of 64³ chunks has this many).
pub const MAX_LISTED_CHUNKS: usize = 1 << 18;

/// The chunks of a level that a store does not hold ([`Multiscale::absent_chunks`]).
#[derive(Clone, Debug, PartialEq)]
pub struct AbsentChunks {
    /// Chunks along x, y, z.
    pub grid: [usize; 3],
    /// Per chunk (x fastest), whether the store leaves it out.
    absent: Vec<bool>,
    /// The value every voxel of an absent chunk reads as.
    pub value: f64,
}

impl AbsentChunks {
    /// Whether chunk `c` (its place in the grid) is left out.
    pub fn is_absent(&self, c: [usize; 3]) -> bool {
        (0..3).all(|a| c[a] < self.grid[a])
            && self.absent[c[0] + self.grid[0] * (c[1] + self.grid[1] * c[2])]
    }

    /// Chunks left out.
    pub fn count(&self) -> usize {
        self.absent.iter().filter(|&&a| a).count()
    }
}

/// Voxels `lo .. lo + size` of `array` at index `lead` on its leading axes (t, c).
fn retrieve<S: zarrs::storage::ReadableStorageTraits + ?Sized + 'static>(
    array: &Array<S>,
    lead: &[u64],
    voxel: VoxelType,
    lo: [usize; 3],
    size: [usize; 3],
) -> std::result::Result<VoxelData, Box<dyn std::error::Error>> {
    let subset = box_subset(lead, lo, size);
    // A box of several chunks is decoded in place. A chunk alone is not: zarrs' owned read of
    // one chunk was the faster into a new buffer (the brick loaders' decoding took 124-130
    // against 132-142 ms of CPU on lavapipe's 16 MiB frame, four runs of each interleaved,
    // before they decoded into buffers they reuse through `Multiscale::read_box_into`).
    let several = || -> std::result::Result<bool, zarrs::array::ArrayError> {
        let chunks = array.chunks_in_array_subset(&subset)?;
        Ok(chunks.is_some_and(|c| c.num_elements() > 1))
    };
    if Some(voxel) == stored_as(array.data_type()) && several()? {
        let mut data = VoxelData::zeros(voxel, size.iter().product());
        retrieve_into(array, &subset, &mut data)?;
        return Ok(data);
    }
    Ok(match voxel {
        VoxelType::U8 => VoxelData::U8(array.retrieve_array_subset(&subset)?),
        VoxelType::U16 => VoxelData::U16(array.retrieve_array_subset(&subset)?),
        VoxelType::I16 if *array.data_type() == data_type::int8() => VoxelData::I16(
            array
                .retrieve_array_subset::<Vec<i8>>(&subset)?
                .into_iter()
                .map(i16::from)
                .collect(),
        ),
        VoxelType::I16 => VoxelData::I16(array.retrieve_array_subset(&subset)?),
        VoxelType::F32 => match wide(array.data_type()) {
            Some(w) => VoxelData::F32(widened(array, w, &subset)?),
            None => VoxelData::F32(array.retrieve_array_subset(&subset)?),
        },
    })
}

/// The subset of an array of `lead` leading indices (channel, time) and the box `lo .. lo +
/// size` (x, y, z; the array's last three axes are z, y, x).
fn box_subset(lead: &[u64], lo: [usize; 3], size: [usize; 3]) -> ArraySubset {
    let mut ranges: Vec<std::ops::Range<u64>> = lead.iter().map(|&i| i..i + 1).collect();
    ranges.extend([2, 1, 0].map(|a| lo[a] as u64..(lo[a] + size[a]) as u64));
    ArraySubset::new_with_ranges(&ranges)
}

/// The voxel type an array's values are held in as they are, with no converting.
fn stored_as(t: &zarrs::array::DataType) -> Option<VoxelType> {
    let table = [
        (data_type::uint8(), VoxelType::U8),
        (data_type::uint16(), VoxelType::U16),
        (data_type::int16(), VoxelType::I16),
        (data_type::float32(), VoxelType::F32),
    ];
    look_up(t, table)
}

/// What `table` pairs with data type `t`, if anything.
fn look_up<T, const N: usize>(
    t: &zarrs::array::DataType,
    table: [(zarrs::array::DataType, T); N],
) -> Option<T> {
    table.into_iter().find(|(d, _)| d == t).map(|(_, v)| v)
}

/// [`retrieve`] of `subset` decoded straight into `out`, voxels in the array's own type
/// ([`stored_as`]). zarrs' owned read filled a buffer with the fill value, decoded each chunk
/// into it and then copied it all into the vector it returns: two passes over the box more,
/// in memory the process touches for the first time, on every read of a store.
fn retrieve_into<S: zarrs::storage::ReadableStorageTraits + ?Sized + 'static>(
    array: &Array<S>,
    subset: &ArraySubset,
    out: &mut VoxelData,
) -> std::result::Result<(), Box<dyn std::error::Error>> {
    use zarrs::array::ArrayBytesFixedDisjointView;
    let shape = subset.shape().to_vec();
    let voxel = out.voxel_type().size();
    let bytes = unsafe_cell_slice::UnsafeCellSlice::new(out.as_bytes_mut());
    let whole = ArraySubset::new_with_shape(shape.clone());
    // SAFETY: the one view of `out`, over all of it: no other view overlaps it.
    let mut view = unsafe { ArrayBytesFixedDisjointView::new(bytes, voxel, &shape, whole) }?;
    array.retrieve_array_subset_into(subset, (&mut view).into())?;
    Ok(())
}

/// Whether `array`'s chunks are its voxels as they lie in memory (the `bytes` codec,
/// little-endian on a little-endian machine) compressed by zstd alone, through no storage
/// transformer, each chunk one index deep on the `leading` axes (time, channel): a whole chunk
/// then decodes with zstd straight into a reader's buffer ([`decode_zstd_into`]). vellum writes
/// its stores so.
fn zstd_alone(array: &Array<GuardedStore>, leading: usize) -> bool {
    let zarrs::array::ArrayMetadata::V3(m) = array.metadata() else {
        return false;
    };
    let little = |c: &zarrs::metadata::v3::MetadataV3| {
        c.configuration()
            .and_then(|c| c.get("endian"))
            .is_none_or(|e| e == "little")
    };
    let codecs = matches!(m.codecs.as_slice(),
        [b, z] if b.name() == "bytes" && little(b) && z.name() == "zstd");
    let one_deep = array
        .chunk_shape(&vec![0; leading + 3])
        .is_ok_and(|s| s[..leading].iter().all(|n| n.get() == 1));
    cfg!(target_endian = "little") && codecs && m.storage_transformers.is_empty() && one_deep
}

thread_local! {
    /// A zstd decoder for each thread that reads chunks, made once and kept.
    static ZSTD: std::cell::RefCell<Option<zstd::bulk::Decompressor<'static>>> =
        const { std::cell::RefCell::new(None) };
}

/// Decodes chunk `at` (its index on every axis) of `array`, whose chunks are [`zstd_alone`],
/// straight into `out`, which it must fill: `Ok(false)` when the store holds no such chunk.
/// zarrs' own read decodes into a buffer of its own, in memory touched for the first time
/// whenever a cache holds what was read before, and copies it out; this writes each voxel once,
/// into memory the reader reuses.
fn decode_zstd_into(
    array: &Array<GuardedStore>,
    at: &[u64],
    out: &mut VoxelData,
) -> std::result::Result<bool, Box<dyn std::error::Error>> {
    let Some(encoded) = array.retrieve_encoded_chunk(at)? else {
        return Ok(false);
    };
    let dst = out.as_bytes_mut();
    let n = ZSTD.with(|z| -> std::io::Result<usize> {
        let mut z = z.borrow_mut();
        let d = match z.as_mut() {
            Some(d) => d,
            None => z.insert(zstd::bulk::Decompressor::new()?),
        };
        d.decompress_to_buffer(&encoded[..], dst)
    })?;
    if n != dst.len() {
        return Err(format!(
            "it decodes to {n} bytes, where its chunk holds {}",
            dst.len()
        )
        .into());
    }
    Ok(true)
}

/// The levels' arrays `names` of `store`, in order: on a server, each level's metadata asked for
/// at once on a thread of its own (one round trip for all, not one a level).
fn open_arrays(
    store: &Arc<GuardedStore>,
    names: &[&str],
    remote: bool,
) -> Vec<std::result::Result<Array<GuardedStore>, String>> {
    let open =
        |name: &str| Array::open(store.clone(), &format!("/{name}")).map_err(|e| e.to_string());
    if !remote || names.len() < 2 {
        return names.iter().map(|n| open(n)).collect();
    }
    std::thread::scope(|s| {
        let handles: Vec<_> = names.iter().map(|n| s.spawn(move || open(n))).collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .unwrap_or_else(|_| Err("the thread that opened it stopped".to_string()))
            })
            .collect()
    })
}

/// Threads that read a box of a store on a server, a chunk each at a time
/// (`Multiscale::read_box_by_chunks`): requests mostly wait on their answers.
const REMOTE_READERS: usize = 16;

/// The chunks of edge `chunk` that the box `lo .. lo + size` meets, by their place in the chunk
/// grid (x fastest); none for an empty box.
pub(crate) fn chunks_meeting(
    chunk: [usize; 3],
    lo: [usize; 3],
    size: [usize; 3],
) -> impl Iterator<Item = [usize; 3]> {
    let empty = size.contains(&0) || chunk.contains(&0);
    let first: [usize; 3] = std::array::from_fn(|a| lo[a] / chunk[a].max(1));
    let last: [usize; 3] =
        std::array::from_fn(|a| (lo[a] + size[a]).saturating_sub(1) / chunk[a].max(1));
    let span = move |a: usize| first[a]..if empty { first[a] } else { last[a] + 1 };
    span(2).flat_map(move |z| span(1).flat_map(move |y| span(0).map(move |x| [x, y, z])))
}

/// The parts of the box `lo .. lo + size` in each chunk of edge `chunk` it meets (x fastest):
/// each part's first voxel and size.
fn chunk_boxes(
    chunk: [usize; 3],
    lo: [usize; 3],
    size: [usize; 3],
) -> Vec<([usize; 3], [usize; 3])> {
    chunks_meeting(chunk, lo, size)
        .map(|c| {
            let blo: [usize; 3] = std::array::from_fn(|a| (c[a] * chunk[a]).max(lo[a]));
            let bhi: [usize; 3] =
                std::array::from_fn(|a| ((c[a] + 1) * chunk[a]).min(lo[a] + size[a]));
            (blo, std::array::from_fn(|a| bhi[a] - blo[a]))
        })
        .collect()
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
        self.ms.geometry_of(self.level)
    }
    fn voxel(&self) -> VoxelType {
        self.ms.voxel
    }
    fn read_box(&self, lo: [usize; 3], size: [usize; 3]) -> Result<Volume> {
        self.ms.read_box(self.level, lo, size)
    }
}

/// The colours of a label image's NGFF `image-label` metadata (0.4 at the attributes' root, 0.5
/// under `ome`); entries without a whole label value or four channels are passed over.
fn label_colours(attrs: &Value) -> Vec<(u32, [u8; 4])> {
    let meta = match &attrs["ome"]["image-label"] {
        Value::Null => &attrs["image-label"],
        m => m,
    };
    let Some(colours) = meta["colors"].as_array() else {
        return Vec::new();
    };
    colours
        .iter()
        .filter_map(|c| {
            let id = u32::try_from(c["label-value"].as_u64()?).ok()?;
            let rgba = c["rgba"].as_array()?;
            let ch = |i: usize| rgba.get(i)?.as_u64().filter(|&v| v <= 255).map(|v| v as u8);
            Some((id, [ch(0)?, ch(1)?, ch(2)?, ch(3)?]))
        })
        .collect()
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
    let ok = names == ["z", "y", "x"]
        || names == ["c", "z", "y", "x"]
        || names == ["t", "z", "y", "x"]
        || names == ["t", "c", "z", "y", "x"];
    if !ok {
        return Err(invalid(
            path,
            format!("has axes {names:?}; expected (z, y, x), (c, z, y, x), (t, z, y, x) or (t, c, z, y, x)"),
        ));
    }
    Ok(names)
}

/// The index `picked` along an axis of `count` (`what`: "channel" or "time point"; `option`: the
/// option that picks it): the only one when none is picked.
fn pick_one(
    path: &Path,
    what: &str,
    option: &str,
    picked: Option<usize>,
    count: usize,
) -> Result<usize> {
    match picked {
        Some(i) if i < count => Ok(i),
        Some(i) => Err(invalid(
            path,
            format!(
                "has {count} {what}(s), 0 to {}; {what} {i} does not exist (`{option}`)",
                count.saturating_sub(1)
            ),
        )),
        None if count == 1 => Ok(0),
        None => Err(invalid(
            path,
            format!(
                "holds {count} {what}s; pick one with `{option}` (0 to {})",
                count - 1
            ),
        )),
    }
}

fn voxel_type(path: &Path, name: &str, array: &Array<GuardedStore>) -> Result<VoxelType> {
    let t = array.data_type();
    Ok(if *t == data_type::uint8() {
        VoxelType::U8
    } else if *t == data_type::uint16() {
        VoxelType::U16
    } else if *t == data_type::int16() || *t == data_type::int8() {
        VoxelType::I16
    } else if *t == data_type::float32() || wide(t).is_some() {
        // Widened as the file readers widen them: exact up to 2^24 (label ids, counts), and a
        // value beyond is refused when read (`widened`).
        VoxelType::F32
    } else {
        return Err(invalid(
            path,
            format!("level {name} holds an unsupported data type; expected uint8, uint16, int16 or float32 (or int8, uint32, int32, uint64, int64 or float64, widened)"),
        ));
    })
}

/// The types read as float32 by [`widened`].
#[derive(Clone, Copy)]
enum Wide {
    U32,
    I32,
    U64,
    I64,
    F64,
}

fn wide(t: &zarrs::array::DataType) -> Option<Wide> {
    let table = [
        (data_type::uint32(), Wide::U32),
        (data_type::int32(), Wide::I32),
        (data_type::uint64(), Wide::U64),
        (data_type::int64(), Wide::I64),
        (data_type::float64(), Wide::F64),
    ];
    look_up(t, table)
}

/// The voxels of `subset` of an array of a type wider than float32, as float32; a value that
/// float32 does not keep exactly (beyond 2^24 in magnitude, or a float64 fraction it rounds) is
/// refused, so two label ids never merge.
fn widened<S: zarrs::storage::ReadableStorageTraits + ?Sized + 'static>(
    array: &Array<S>,
    w: Wide,
    subset: &ArraySubset,
) -> std::result::Result<Vec<f32>, Box<dyn std::error::Error>> {
    let all: Vec<f64> = match w {
        Wide::U32 => array
            .retrieve_array_subset::<Vec<u32>>(subset)?
            .into_iter()
            .map(f64::from)
            .collect(),
        Wide::I32 => array
            .retrieve_array_subset::<Vec<i32>>(subset)?
            .into_iter()
            .map(f64::from)
            .collect(),
        Wide::U64 => array
            .retrieve_array_subset::<Vec<u64>>(subset)?
            .into_iter()
            .map(|v| v as f64)
            .collect(),
        Wide::I64 => array
            .retrieve_array_subset::<Vec<i64>>(subset)?
            .into_iter()
            .map(|v| v as f64)
            .collect(),
        Wide::F64 => array.retrieve_array_subset::<Vec<f64>>(subset)?,
    };
    all.into_iter()
        .map(|v| {
            let f = v as f32;
            match f as f64 == v || (matches!(w, Wide::F64) && v.is_finite() && v.abs() < 1e38) {
                true => Ok(f),
                false => Err(format!("it holds {v}, which float32 does not keep exactly; expected values within 2^24").into()),
            }
        })
        .collect()
}

/// One level from its array and its dataset entry (scale and translation, z y x order);
/// `leading` axes (t, c) come before z, y, x.
fn level(
    path: &Path,
    name: &str,
    array: &Array<GuardedStore>,
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
            "scale" => spacing = xyz,
            _ => origin = xyz,
        }
    }
    ngff_checks::spacing(path, &format!("level {name}'s scale"), spacing)?;
    ngff_checks::origin(path, &format!("level {name}'s translation"), origin)?;
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
    /// Chunks made at once (each on its own thread, with its box in memory); `None`: one per
    /// core.
    pub threads: Option<usize>,
}

impl Default for WriteOptions {
    fn default() -> Self {
        WriteOptions {
            chunk: 64,
            levels: None,
            threads: None,
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
    /// Levels written.
    pub levels: usize,
    /// Chunks written, over all levels (chunks that hold only the fill value are not stored).
    pub chunks: usize,
    /// Uncompressed bytes of every level.
    pub bytes: u64,
    /// Smallest and largest value of level 0.
    pub range: [f64; 2],
    /// Smallest and largest value of level 0, per channel.
    pub channel_ranges: Vec<[f64; 2]>,
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
    write_source_in(&Solo, path, src, opts, on_chunk)
}

/// [`write_source`] by the ranks of `team` together (see [`write_channels_in`]).
pub fn write_source_in(
    team: &dyn Team,
    path: &Path,
    src: &dyn BoxSource,
    opts: &WriteOptions,
    on_chunk: &(dyn Fn() + Sync),
) -> Result<WriteReport> {
    let read = |lo, size| Ok(vec![src.read_box(lo, size)?]);
    let channels = Channels::over(src, (1, src.voxel()), &read);
    write_channels_in(team, path, &channels, opts, on_chunk)
}

/// A grid of `count` values per voxel, read a box at a time as one volume per channel.
pub struct Channels<'a> {
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// Voxel size along x, y, z.
    pub spacing: [f64; 3],
    /// Origin and directions.
    pub geometry: Geometry,
    /// The values' type.
    pub voxel: VoxelType,
    /// Values per voxel.
    pub count: usize,
    #[allow(clippy::type_complexity)]
    /// Reads voxels `lo .. lo + size` of every channel.
    pub read: &'a (dyn Fn([usize; 3], [usize; 3]) -> Result<Vec<Volume>> + Sync),
}

impl<'a> Channels<'a> {
    /// `count` channels of `voxel` over the grid of `src` (its dims, spacing and placement),
    /// read by `read`.
    #[allow(clippy::type_complexity)]
    pub fn over(
        src: &dyn BoxSource,
        (count, voxel): (usize, VoxelType),
        read: &'a (dyn Fn([usize; 3], [usize; 3]) -> Result<Vec<Volume>> + Sync),
    ) -> Self {
        Channels {
            dims: src.dims(),
            spacing: src.spacing(),
            geometry: src.geometry(),
            voxel,
            count,
            read,
        }
    }
}

/// [`write_source`] for a grid of several channels, by the ranks of `team` together (`Solo`
/// for a process alone): the arrays get a leading c axis (`channel` in the axes) when
/// `src.count` is above 1, each channel's pyramid is made as a scalar one's, and the recorded
/// range spans every channel. Rank 0 makes the temporary folder and writes the metadata, every
/// rank writes the chunks of its own boxes of each level (a k-d split of the chunk grid; chunks
/// are separate objects, so no two ranks write one), the ranks agree after each level (one
/// failed rank ends every rank with its sentence, and rank 0 removes the folder), and level 0's
/// range is reduced over the ranks. The store is the one a process alone writes, byte for byte.
pub fn write_channels_in(
    team: &dyn Team,
    path: &Path,
    src: &Channels,
    opts: &WriteOptions,
    on_chunk: &(dyn Fn() + Sync),
) -> Result<WriteReport> {
    if opts.chunk == 0 {
        return Err(Error::Invalid(
            "`chunk` is 0; expected a chunk edge of 1 voxel or more".into(),
        ));
    }
    let levels = opts.levels.unwrap_or_else(|| auto_levels(src.dims));
    check_write_shape(src.dims, opts.chunk, levels)?;
    if src.geometry.direction != crate::geometry::IDENTITY && team.is_root() {
        log::warn!(
            "OME-NGFF has no rotation: other readers see {} without its direction matrix (vellum reads it back from the store's `vellum` attributes)",
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
    // Rank 0 makes the temporary folder; every rank learns its name, or rank 0's sentence.
    let folder = team.is_root().then(|| crate::output::begin_folder(path));
    let made = match &folder {
        Some(Err(e)) => Err(Error::Invalid(e.to_string())),
        _ => Ok(()),
    };
    team.agree(made)?;
    let folder = folder.transpose()?;
    let tmp = folder
        .as_ref()
        .map(|f| f.tmp.to_string_lossy().into_owned());
    let tmp = PathBuf::from(
        String::from_utf8_lossy(&team.broadcast(tmp.unwrap_or_default().into_bytes())).into_owned(),
    );
    let threads = opts.threads.unwrap_or(usize::MAX).max(1);
    let report = write_levels(
        team,
        &tmp,
        &name,
        src,
        (opts.chunk, levels, threads),
        on_chunk,
    );
    match (folder, report) {
        (None, report) => report,
        (Some(f), Ok(r)) => f.finish(Ok(())).map(|()| r),
        (Some(f), Err(e)) => Err(f
            .finish(Err(e))
            .err()
            .unwrap_or_else(|| Error::Invalid("the store failed and was removed".into()))),
    }
}

/// Levels, chunks and chunk counts a writer accepts: from 1 level to the number that halves the
/// longest axis down to one voxel (each further level would be that voxel again), chunks of at
/// most `guarded_store::MAX_CHUNK_BYTES` at 32 bits, and at most `ngff_checks::MAX_CHUNKS`
/// of them in level 0 (what a reader accepts).
pub(crate) fn check_write_shape(dims: [usize; 3], chunk: usize, levels: usize) -> Result<()> {
    let longest = dims.into_iter().max().unwrap_or(1).max(1);
    let most = (usize::BITS - (longest - 1).leading_zeros()) as usize + 1;
    if levels == 0 || levels > most {
        return Err(Error::Invalid(format!(
            "`levels` {levels} is invalid for a {}x{}x{} volume; expected 1 to {most} (halving its longest axis down to one voxel)",
            dims[0], dims[1], dims[2]
        )));
    }
    if chunk < 8 && chunk < longest {
        return Err(Error::Invalid(format!(
            "`chunk` {chunk} is too small: a file for every {} voxels; expected 8 or more",
            chunk.pow(3)
        )));
    }
    let chunk_bytes = (chunk as u128).pow(3) * 4;
    if chunk_bytes > super::guarded_store::MAX_CHUNK_BYTES as u128 {
        return Err(Error::Invalid(format!(
            "`chunk` {chunk} is too large: {chunk_bytes} bytes a chunk at 32 bits; expected at most {}",
            super::guarded_store::MAX_CHUNK_BYTES
        )));
    }
    let chunks: u128 = dims
        .iter()
        .map(|&n| n.div_ceil(chunk.max(1)) as u128)
        .product();
    if chunks > ngff_checks::MAX_CHUNKS {
        return Err(Error::Invalid(format!(
            "`chunk` {chunk} cuts a {}x{}x{} volume into {chunks} chunks; expected at most {} (a larger chunk)",
            dims[0],
            dims[1],
            dims[2],
            ngff_checks::MAX_CHUNKS
        )));
    }
    Ok(())
}

fn write_levels(
    team: &dyn Team,
    path: &Path,
    name: &str,
    src: &Channels,
    (chunk, levels, threads): (usize, usize, usize),
    on_chunk: &(dyn Fn() + Sync),
) -> Result<WriteReport> {
    let store = Arc::new(FilesystemStore::new(path).map_err(|e| invalid(path, e))?);
    let mut datasets = Vec::new();
    let (voxel, dims0, base) = (src.voxel, src.dims, src.spacing);
    let channels = src.count;
    let mut report = WriteReport {
        levels,
        chunks: 0,
        bytes: 0,
        range: [f64::INFINITY, f64::NEG_INFINITY],
        channel_ranges: Vec::new(),
    };
    // A c axis only for more than one channel: (c, z, y, x); its scale is 1 and translation 0.
    let with_c = |zyx: [f64; 3], c: f64| -> Vec<f64> {
        let mut v = if channels > 1 { vec![c] } else { vec![] };
        v.extend([zyx[2], zyx[1], zyx[0]]);
        v
    };
    let mut previous: Option<Array<FilesystemStore>> = None;
    for i in 0..levels {
        let dims = level_dims(dims0, i);
        let spacing = base.map(|s| s * (1u64 << i) as f64);
        let origin: [f64; 3] =
            std::array::from_fn(|a| src.geometry.origin[a] + 0.5 * (spacing[a] - base[a]));
        let meta = team.is_root();
        let made = make_array(
            &store,
            path,
            &i.to_string(),
            (dims, channels, meta),
            chunk,
            voxel,
        );
        team.agree(
            made.as_ref()
                .map(|_| ())
                .map_err(|e| Error::Invalid(e.to_string())),
        )?;
        let array = made?;
        let grid = dims.map(|n| n.div_ceil(chunk));
        let owners = crate::team::kd_owners(grid, &[], team.size());
        let mine: Vec<usize> = (0..owners.len())
            .filter(|&c| owners[c] == team.rank())
            .collect();
        let written = match &previous {
            None => store_chunks(
                &array,
                path,
                (dims, chunk, &mine, threads),
                src.read,
                on_chunk,
            ),
            Some(prev) => {
                let read = |lo, size| {
                    halved_box(prev, channels, voxel, level_dims(dims0, i - 1), (lo, size))
                };
                let read = |lo, size| {
                    read(lo, size).map_err(|e| {
                        invalid(
                            path,
                            format!("level {} could not be read back ({e})", i - 1),
                        )
                    })
                };
                store_chunks(&array, path, (dims, chunk, &mine, threads), &read, on_chunk)
            }
        };
        // Every rank's chunks of this level are written before any rank reads them for the next.
        let local = match written {
            Ok(r) => {
                team.agree(Ok(()))?;
                r
            }
            Err(e) => {
                return Err(team
                    .agree(Err(e))
                    .err()
                    .unwrap_or_else(|| Error::Invalid("a chunk failed".into())))
            }
        };
        if i == 0 {
            // Every rank reduces every channel's range, those with no chunk of their own too.
            let mut local = local;
            local.resize(channels, [f64::INFINITY, f64::NEG_INFINITY]);
            report.channel_ranges = local.iter().map(|&r| team.min_max(r)).collect();
            report.range = report
                .channel_ranges
                .iter()
                .fold([f64::INFINITY, f64::NEG_INFINITY], |a, r| {
                    [a[0].min(r[0]), a[1].max(r[1])]
                });
        }
        let count = (0..3).map(|a| dims[a].div_ceil(chunk)).product::<usize>();
        report.chunks += count * channels;
        report.bytes += (dims[0] * dims[1] * dims[2] * voxel.size() * channels) as u64;
        previous = Some(array);
        datasets.push(json!({
            "path": i.to_string(),
            "coordinateTransformations": [
                {"type": "scale", "scale": with_c(spacing, 1.0)},
                {"type": "translation", "translation": with_c(origin, 0.0)},
            ],
        }));
    }
    let mut axes = vec![];
    if channels > 1 {
        axes.push(json!({"name": "c", "type": "channel"}));
    }
    axes.extend(["z", "y", "x"].map(|n| json!({"name": n, "type": "space"})));
    if !team.is_root() {
        return Ok(report);
    }
    let mut group = zarrs::group::GroupBuilder::new()
        .build(store, "/")
        .map_err(|e| invalid(path, e))?;
    let attrs = group.attributes_mut();
    attrs.insert(
        "ome".into(),
        json!({
            "version": "0.5",
            "multiscales": [{ "name": name, "axes": axes, "datasets": datasets }],
        }),
    );
    let g = src.geometry;
    let space = match g.space {
        crate::geometry::Space::Lps => "lps",
        crate::geometry::Space::Unknown => "unknown",
    };
    let mut ours = json!({
        "range": report.range,
        "geometry": { "origin": g.origin, "direction": g.direction, "space": space },
    });
    if channels > 1 {
        // What a reader of one channel normalises it over (`range` spans them all).
        ours["channel_ranges"] = json!(report.channel_ranges);
    }
    attrs.insert("vellum".into(), ours);
    group.store_metadata().map_err(|e| invalid(path, e))?;
    Ok(report)
}

/// The box `lo .. lo + size` of the level after `prev` (a level of `prev_dims`): the 2×2×2 mean
/// of `prev`'s box under it, channel by channel.
fn halved_box(
    prev: &Array<FilesystemStore>,
    channels: usize,
    voxel: VoxelType,
    prev_dims: [usize; 3],
    (lo, size): ([usize; 3], [usize; 3]),
) -> std::result::Result<Vec<Volume>, Box<dyn std::error::Error>> {
    let plo = lo.map(|v| 2 * v);
    let psize: [usize; 3] = std::array::from_fn(|a| (2 * size[a]).min(prev_dims[a] - plo[a]));
    (0..channels)
        .map(|c| {
            let lead = lead_of(channels, c);
            let data = retrieve(prev, &lead, voxel, plo, psize)?;
            Ok(halve(&Volume::new(psize, [1.0; 3], data)?)?)
        })
        .collect()
}

/// The leading index of channel `c` in a written store: none for one channel, (c) otherwise.
fn lead_of(channels: usize, c: usize) -> Vec<u64> {
    if channels > 1 {
        vec![c as u64]
    } else {
        vec![]
    }
}

/// An empty level of `dims` and `channels` in `voxel`, chunked by `chunk` (one channel a chunk),
/// zstd-compressed, its metadata stored when `meta` (rank 0's part in a team).
fn make_array(
    store: &Arc<FilesystemStore>,
    path: &Path,
    name: &str,
    (dims, channels, meta): ([usize; 3], usize, bool),
    chunk: usize,
    voxel: VoxelType,
) -> Result<Array<FilesystemStore>> {
    // (c, z, y, x) for several channels, (z, y, x) for one.
    let mut shape: Vec<u64> = if channels > 1 {
        vec![channels as u64]
    } else {
        vec![]
    };
    shape.extend([dims[2], dims[1], dims[0]].map(|n| n as u64));
    let chunks: Vec<u64> = shape
        .iter()
        .enumerate()
        .map(|(k, &n)| match k + 3 < shape.len() {
            true => 1,
            false => (chunk as u64).min(n).max(1),
        })
        .collect();
    let (dtype, fill): (zarrs::array::DataType, zarrs::array::FillValue) = match voxel {
        VoxelType::U8 => (data_type::uint8(), 0u8.into()),
        VoxelType::U16 => (data_type::uint16(), 0u16.into()),
        VoxelType::I16 => (data_type::int16(), 0i16.into()),
        VoxelType::F32 => (data_type::float32(), 0f32.into()),
    };
    let names: &[&str] = if channels > 1 {
        &["c", "z", "y", "x"]
    } else {
        &["z", "y", "x"]
    };
    let array = ArrayBuilder::new(shape, chunks, dtype, fill)
        .bytes_to_bytes_codecs(vec![Arc::new(zarrs::array::codec::ZstdCodec::new(
            3, false,
        ))])
        .dimension_names(Some(names.to_vec()))
        .build(store.clone(), &format!("/{name}"))
        .map_err(|e| invalid(path, format!("level {name} could not be made ({e})")))?;
    if meta {
        array.store_metadata().map_err(|e| {
            invalid(
                path,
                format!("level {name}'s metadata could not be written ({e})"),
            )
        })?;
    }
    Ok(array)
}

/// Fills chunks `mine` (indices, x fastest) of `array` (a level of `dims`) from `read(lo, size)`
/// (one volume per channel), chunks in parallel; returns the smallest and largest value written.
///
/// The chunks run on plain threads, one per core, not as rayon tasks: `read` may hold a lock
/// while it calls into rayon (the chunked passes share one GPU pipeline behind a mutex, and its
/// packing is parallel), and a rayon worker waiting for that inner work steals other tasks,
/// which can be another chunk that waits for the lock its own thread holds. That deadlocked a
/// 512³ chunked importance map on a 16-core machine.
#[allow(clippy::type_complexity)]
/// Widens each range of `acc` by the matching one of `by` (an empty `acc` takes `by`).
fn widen_each(acc: &mut Vec<[f64; 2]>, by: &[[f64; 2]]) {
    if acc.is_empty() {
        acc.extend_from_slice(by);
    }
    for (a, r) in acc.iter_mut().zip(by) {
        *a = [a[0].min(r[0]), a[1].max(r[1])];
    }
}

fn store_chunks(
    array: &Array<FilesystemStore>,
    path: &Path,
    (dims, chunk, mine, most): ([usize; 3], usize, &[usize], usize),
    read: &(dyn Fn([usize; 3], [usize; 3]) -> Result<Vec<Volume>> + Sync),
    on_chunk: &(dyn Fn() + Sync),
) -> Result<Vec<[f64; 2]>> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let counts = dims.map(|n| n.div_ceil(chunk));
    let total = mine.len();
    let one = |k: usize| -> Result<Vec<[f64; 2]>> {
        // Ctrl-C: stop before the next chunk, so that nothing writes into the folder once it
        // is removed.
        vellum_error::check_interrupt()?;
        let c = mine[k];
        let index = [
            c % counts[0],
            (c / counts[0]) % counts[1],
            c / (counts[0] * counts[1]),
        ];
        let lo = index.map(|i| i * chunk);
        let size: [usize; 3] = std::array::from_fn(|a| chunk.min(dims[a] - lo[a]));
        let channels = read(lo, size)?;
        let mut ranges = Vec::with_capacity(channels.len());
        for (k, v) in channels.iter().enumerate() {
            ranges.push(crate::stats::value_range(v));
            let mut ranges: Vec<std::ops::Range<u64>> = lead_of(channels.len(), k)
                .into_iter()
                .map(|i| i..i + 1)
                .collect();
            ranges.extend([2, 1, 0].map(|a| lo[a] as u64..(lo[a] + size[a]) as u64));
            let subset = ArraySubset::new_with_ranges(&ranges);
            let stored = match &v.data {
                VoxelData::U8(d) => array.store_array_subset(&subset, d.as_slice()),
                VoxelData::U16(d) => array.store_array_subset(&subset, d.as_slice()),
                VoxelData::I16(d) => array.store_array_subset(&subset, d.as_slice()),
                VoxelData::F32(d) => array.store_array_subset(&subset, d.as_slice()),
            };
            stored.map_err(|e| {
                invalid(path, format!("chunk {index:?} could not be written ({e})"))
            })?;
        }
        on_chunk();
        Ok(ranges)
    };
    let next = AtomicUsize::new(0);
    // Each thread takes the next chunk until none is left or one has failed (then every thread
    // stops at its next chunk).
    let worker = || -> Result<Vec<[f64; 2]>> {
        let mut acc = Vec::new();
        loop {
            let c = next.fetch_add(1, Ordering::Relaxed);
            if c >= total {
                return Ok(acc);
            }
            match one(c) {
                Ok(r) => widen_each(&mut acc, &r),
                Err(e) => {
                    next.store(total, Ordering::Relaxed);
                    return Err(e);
                }
            }
        }
    };
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(most)
        .min(total.max(1));
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads).map(|_| s.spawn(worker)).collect();
        let mut acc = Vec::new();
        for h in handles {
            let r = h
                .join()
                .map_err(|_| invalid(path, "a chunk's thread failed".to_string()))??;
            widen_each(&mut acc, &r);
        }
        Ok(acc)
    })
}

/// The 2×2×2 mean of `v` (odd edges average what they have), in the same voxel type, with
/// doubled spacing and the origin moved to the first output voxel's centre.
pub fn halve(v: &Volume) -> Result<Volume> {
    let (d, out) = (v.dims, v.dims.map(|n| n.div_ceil(2)));
    let data = match &v.data {
        VoxelData::U8(s) => VoxelData::U8(halved(s, d, |m| m.round() as u8)),
        VoxelData::U16(s) => VoxelData::U16(halved(s, d, |m| m.round() as u16)),
        VoxelData::I16(s) => VoxelData::I16(halved(s, d, |m| m.round() as i16)),
        VoxelData::F32(s) => VoxelData::F32(halved(s, d, |m| m as f32)),
    };
    let spacing = v.spacing.map(|s| 2.0 * s);
    let geometry = Geometry {
        origin: std::array::from_fn(|a| v.geometry.origin[a] + 0.5 * v.spacing[a]),
        ..v.geometry
    };
    Volume::new(out, spacing, data)?.with_geometry(geometry)
}

/// The 2×2×2 means of `s` (of `dims`), each block's voxels summed in f64 in memory order and
/// turned back by `back`; one output slab of z per task. Each voxel is read as its own type,
/// where a loop through `get_f64` matched the type at every voxel: the store writers halve
/// every chunk of every channel, and that loop was a tenth of a chunked pass's CPU time.
fn halved<T: Copy + Into<f64> + Sync, U: Copy + Default + Send>(
    s: &[T],
    d: [usize; 3],
    back: impl Fn(f64) -> U + Sync,
) -> Vec<U> {
    use rayon::prelude::*;
    let out = d.map(|n| n.div_ceil(2));
    let pair = |o: usize, a: usize| 2 * o..(2 * o + 2).min(d[a]);
    let mut res = vec![U::default(); out.iter().product()];
    res.par_chunks_mut((out[0] * out[1]).max(1))
        .enumerate()
        .for_each(|(oz, slab)| {
            for (oy, row) in slab.chunks_mut(out[0].max(1)).enumerate() {
                for (ox, r) in row.iter_mut().enumerate() {
                    let (mut sum, mut count) = (0f64, 0u32);
                    for z in pair(oz, 2) {
                        for y in pair(oy, 1) {
                            let at = d[0] * (y + d[1] * z);
                            for x in pair(ox, 0) {
                                sum += s[at + x].into();
                                count += 1;
                            }
                        }
                    }
                    *r = back(sum / count as f64);
                }
            }
        });
    res
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `halve` against the plain sum per output voxel in f64 (in voxel order, through
    /// `get_f64`), for each type and odd sizes, a NaN included: equal value for value.
    #[test]
    fn halving_is_the_plain_mean_of_each_block() {
        fn plain(v: &Volume) -> Vec<f64> {
            let (d, out) = (v.dims, v.dims.map(|n| n.div_ceil(2)));
            let mut sums = vec![0f64; out.iter().product()];
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
            sums.iter()
                .zip(&counts)
                .map(|(s, &c)| s / c as f64)
                .collect()
        }
        let dims = [7, 4, 5];
        let n: usize = dims.iter().product();
        let mut f: Vec<f32> = (0..n).map(|i| (i * 37 % 101) as f32 / 3.0 - 9.0).collect();
        f[11] = f32::NAN;
        for data in [
            VoxelData::F32(f),
            VoxelData::U16((0..n).map(|i| (i * 7919 % 65536) as u16).collect()),
            VoxelData::I16((0..n).map(|i| (i * 7919 % 65536) as u16 as i16).collect()),
            VoxelData::U8((0..n).map(|i| (i * 13 % 256) as u8).collect()),
        ] {
            let v = Volume::new(dims, [1.0; 3], data).unwrap();
            let (got, want) = (halve(&v).unwrap(), plain(&v));
            assert_eq!(got.dims, [4, 2, 3]);
            for (i, w) in want.iter().enumerate() {
                let expected = match v.voxel_type() {
                    VoxelType::F32 => *w as f32 as f64,
                    _ => w.round(),
                };
                let g = got.data.get_f64(i);
                assert!(
                    g == expected || (g.is_nan() && expected.is_nan()),
                    "{:?} voxel {i}: {g} against {expected}",
                    v.voxel_type()
                );
            }
        }
    }
}
