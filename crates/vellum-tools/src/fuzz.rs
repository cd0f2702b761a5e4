//! A stable-Rust fuzz harness for every reader of outside input: volumes (NRRD attached and
//! detached, NIfTI-1 plain and gzipped, MetaImage attached and detached, DICOM), the JSON files
//! (transfer function, occlusion transfer function, feature map, scene), and OME-Zarr stores
//! (issue 40: a small store on Zarr v3 as vellum writes it and one on Zarr v2 as another tool
//! does, with one file mutated per target: the root metadata, an array's metadata, a chunk).
//!
//! Seeds are real files made small: real volumes from `../shared/data` cropped to a few hundred
//! voxels, with their geometry, written by vellum's writers or with the real file's own header
//! text; a real DICOM slice with its pixel data cut to 8×8; the project's example JSON files. Each
//! input is a seed with one to four mutations from a seeded generator (bit flips, interesting
//! bytes, numbers swapped for hostile ones, inserted, deleted or duplicated runs, truncation,
//! splices of two seeds), so a run is reproducible from its seed.
//!
//! Every input runs in-process under `catch_unwind` (a panic is a crash) and under a watchdog (an
//! input running past the time bound is a hang: the watchdog saves it and ends the process).
//! Crashing inputs are saved beside the report. Peak memory is the process's high-water mark.
//!
//! `make fuzz` runs it long (`cargo run --release --example fuzz`); `tests/fuzz.rs` runs it short.

use std::io::Write as _;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::Serialize;

use vellum_error::{Error, Result};
use vellum_volume::{Volume, VoxelData};

/// How a target reads one input file.
#[derive(Clone, Copy, Debug)]
enum Reader {
    /// `volume::io::load` on the file.
    Volume,
    /// `volume::io::load` on the folder holding the file (a DICOM series).
    Folder,
    TransferFunction,
    OcclusionTf,
    FeatureMap,
    Scene,
    /// The store holding the file, opened and read as `info` reads it.
    Store,
}

/// One reader with its seeds.
pub struct Target {
    /// Short name, e.g. "nrrd" or "scene".
    pub name: &'static str,
    /// The file name inputs are written to (its extension picks the reader).
    file: &'static str,
    reader: Reader,
    /// Fixed companion files (a detached header's data file), written once.
    companions: Vec<(String, Vec<u8>)>,
    /// The seed inputs.
    pub seeds: Vec<Vec<u8>>,
}

/// What running one target did.
#[derive(Clone, Debug, Default, Serialize)]
pub struct TargetReport {
    pub target: String,
    pub inputs: u64,
    /// Inputs the reader accepted.
    pub accepted: u64,
    /// Inputs refused with an error (the expected outcome for most).
    pub refused: u64,
    /// Inputs that panicked (saved as crash-TARGET-N).
    pub crashes: u64,
    /// The slowest input, in milliseconds.
    pub max_ms: f64,
    /// Mean time per input, in microseconds.
    pub mean_us: f64,
    /// Refusals whose message, as the command line shows it (`error::one_line`), is empty or not
    /// one line.
    pub unclear: u64,
    /// A few distinct crash messages.
    pub crash_messages: Vec<String>,
    /// A few refusals that were not one line (saved as unclear-TARGET-N).
    pub unclear_messages: Vec<String>,
}

/// Options of a run.
#[derive(Clone, Debug)]
pub struct FuzzOptions {
    /// Inputs per target.
    pub inputs: u64,
    /// Generator seed.
    pub seed: u64,
    /// An input running longer is a hang: the watchdog saves it and exits the process with 3.
    pub time_bound: Duration,
    /// Where inputs are written while they run and crashing inputs are kept.
    pub work_dir: PathBuf,
    /// Only targets whose name contains one of these (all when empty).
    pub only: Vec<String>,
}

/// xorshift64*: small, fast and reproducible; quality far beyond what mutation needs.
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

const BYTES: &[u8] = b"\0\xff\x7f\x80 \n\r\t-+.,:;=()[]{}\"'0123456789eE";
const NUMBERS: &[&str] = &[
    "0",
    "-1",
    "1",
    "-0",
    "65535",
    "65536",
    "2147483647",
    "-2147483648",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "99999999999999999999",
    "1e308",
    "-1e308",
    "1e-320",
    "nan",
    "inf",
    "-inf",
    "3.4e38",
    "1e39",
    "0.0",
    "32767",
    "-32768",
    "1000000000",
];

/// One to four mutations of `input`, with `other` as a splice partner.
fn mutate(rng: &mut Rng, input: &[u8], other: &[u8]) -> Vec<u8> {
    let mut b = input.to_vec();
    for _ in 0..1 + rng.below(4) {
        let len = b.len();
        match rng.below(9) {
            0 if len > 0 => {
                let i = rng.below(len);
                b[i] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let i = rng.below(len);
                b[i] = BYTES[rng.below(BYTES.len())];
            }
            2 | 3 => {
                // Replace a run of digits (or insert at a random place) by a hostile number.
                let start = rng.below(len + 1);
                let digits = |c: &u8| c.is_ascii_digit() || *c == b'.' || *c == b'-' || *c == b'e';
                let from = (start..len).find(|&i| digits(&b[i])).unwrap_or(start);
                let to = (from..len).find(|&i| !digits(&b[i])).unwrap_or(len);
                let n = NUMBERS[rng.below(NUMBERS.len())].as_bytes();
                b.splice(from..to, n.iter().copied());
            }
            4 => {
                let at = rng.below(len + 1);
                let n = 1 + rng.below(16);
                let bytes: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
                b.splice(at..at, bytes);
            }
            5 if len > 0 => {
                let from = rng.below(len);
                let to = (from + 1 + rng.below(64)).min(len);
                b.drain(from..to);
            }
            6 if len > 0 => {
                let from = rng.below(len);
                let to = (from + 1 + rng.below(64)).min(len);
                let run = b[from..to].to_vec();
                let at = rng.below(b.len() + 1);
                b.splice(at..at, run);
            }
            7 if len > 0 => b.truncate(rng.below(len)),
            _ if !other.is_empty() => {
                let cut = rng.below(len + 1);
                let from = rng.below(other.len());
                b.truncate(cut);
                b.extend_from_slice(&other[from..]);
            }
            _ => {}
        }
    }
    b
}

/// A block of `volume` of at most `size` voxels per axis, at `at`, keeping type and geometry
/// (the origin moves to the block's first voxel).
fn crop(volume: &Volume, at: [usize; 3], size: [usize; 3]) -> Result<Volume> {
    let at: [usize; 3] = std::array::from_fn(|a| at[a].min(volume.dims[a] - 1));
    let dims: [usize; 3] = std::array::from_fn(|a| size[a].min(volume.dims[a] - at[a]));
    let indices: Vec<usize> = (0..dims[2])
        .flat_map(|z| (0..dims[1]).flat_map(move |y| (0..dims[0]).map(move |x| [x, y, z])))
        .map(|[x, y, z]| volume.index(at[0] + x, at[1] + y, at[2] + z))
        .collect();
    let data = match &volume.data {
        VoxelData::U8(v) => VoxelData::U8(indices.iter().map(|&i| v[i]).collect()),
        VoxelData::U16(v) => VoxelData::U16(indices.iter().map(|&i| v[i]).collect()),
        VoxelData::I16(v) => VoxelData::I16(indices.iter().map(|&i| v[i]).collect()),
        VoxelData::F32(v) => VoxelData::F32(indices.iter().map(|&i| v[i]).collect()),
    };
    let mut g = volume.geometry;
    for (a, &offset) in at.iter().enumerate() {
        let axis = g.axis(a);
        for (r, o) in g.origin.iter_mut().enumerate() {
            *o += axis[r] * volume.spacing[a] * offset as f64;
        }
    }
    Volume::new(dims, volume.spacing, data)?.with_geometry(g)
}

fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

/// The middle block of a real volume file, cropped to 10×9×7.
fn real_block(path: &Path) -> Result<Volume> {
    let v = vellum_volume::io::load(path, None)?;
    let at = v.dims.map(|d| d / 2);
    crop(&v, at, [10, 9, 7])
}

/// Bytes a writer produces for `volume` at a file called `name` (through a scratch file).
fn written(scratch: &Path, name: &str, volume: &Volume) -> Result<Vec<u8>> {
    let path = scratch.join(name);
    vellum_volume::io::write(&path, volume)?;
    read(&path)
}

/// The real header `text` with its size and data-file lines replaced.
fn retarget(text: &str, size_key: &str, sizes: &str, file_key: &str, file: &str) -> String {
    text.lines()
        .map(|l| {
            if l.starts_with(size_key) {
                format!("{size_key}{sizes}")
            } else if l.starts_with(file_key) {
                format!("{file_key}{file}")
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
        + "\n"
}

/// A real DICOM slice with its image cut to 8×8 (rows, columns and pixel data rewritten).
fn small_dicom(path: &Path, scratch: &Path) -> Result<Vec<u8>> {
    use dicom_core::{DataElement, PrimitiveValue, VR};
    use dicom_dictionary_std::tags;
    let mut obj = dicom_object::open_file(path)
        .map_err(|e| Error::format(path, format!("not readable as DICOM ({e})")))?;
    let bits = obj
        .element(tags::BITS_ALLOCATED)
        .ok()
        .and_then(|e| e.to_int::<u16>().ok())
        .unwrap_or(16);
    let bytes = 64 * (bits as usize / 8).max(1);
    let pixels: Vec<u8> = (0..bytes).map(|i| (i * 37 % 251) as u8).collect();
    obj.put(DataElement::new(
        tags::ROWS,
        VR::US,
        PrimitiveValue::from(8u16),
    ));
    obj.put(DataElement::new(
        tags::COLUMNS,
        VR::US,
        PrimitiveValue::from(8u16),
    ));
    obj.put(DataElement::new(
        tags::PIXEL_DATA,
        VR::OW,
        PrimitiveValue::from(pixels),
    ));
    let out = scratch.join("small.dcm");
    obj.write_to_file(&out)
        .map_err(|e| Error::format(&out, format!("could not be written ({e})")))?;
    read(&out)
}

/// Detached-header seeds: the engine's NRRD header and the MR head's MetaImage header retargeted
/// to the small blocks (`data.raw` beside them), and the MetaImage as one .mha with the block.
fn header_seeds(data: &Path, engine: &Volume, head: &Volume) -> Result<[Vec<u8>; 3]> {
    let (formats, volumes) = (data.join("formats"), data.join("volumes"));
    let sizes = |v: &Volume| format!("{} {} {}", v.dims[0], v.dims[1], v.dims[2]);
    let nhdr_text = std::fs::read_to_string(volumes.join("engine/engine.nhdr"))
        .map_err(|e| Error::io(volumes.join("engine/engine.nhdr"), e))?;
    let nhdr = retarget(
        &nhdr_text,
        "sizes: ",
        &sizes(engine),
        "data file: ",
        "data.raw",
    )
    .replace("encoding: gzip", "encoding: raw");
    let mhd_path = formats.join("metaimage/HeadMRVolume.mhd");
    let mhd_text = std::fs::read_to_string(&mhd_path).map_err(|e| Error::io(&mhd_path, e))?;
    let mhd = retarget(
        &mhd_text,
        "DimSize = ",
        &sizes(head),
        "ElementDataFile = ",
        "data.raw",
    );
    let mut mha = retarget(
        &mhd_text,
        "DimSize = ",
        &sizes(head),
        "ElementDataFile = ",
        "LOCAL",
    )
    .into_bytes();
    mha.extend_from_slice(head.data.as_bytes());

    Ok([nhdr.into_bytes(), mhd.into_bytes(), mha])
}

/// The seed files of one target.
type Seeds = Vec<Vec<u8>>;

/// JSON seeds: every transfer-function preset, and the example scenes.
fn json_seeds(project: &Path) -> Result<[Seeds; 2]> {
    let json = |p: &str| read(&project.join(p));
    let tfs = vellum_render::classify::transfer::PRESETS
        .iter()
        .map(|p| {
            Ok(
                vellum_render::classify::transfer::TransferFunction::preset(p)?
                    .to_json()
                    .into_bytes(),
            )
        })
        .collect::<Result<Vec<_>>>()?;
    let scenes = [
        "examples/two_level_cthead.json",
        "examples/importance_stipple_cthead.json",
        "examples/occlusion_nested.json",
        "examples/features_nested.json",
        "examples/one_pass_shepp_logan.json",
    ]
    .iter()
    .map(|p| json(p))
    .collect::<Result<Vec<_>>>()?;

    Ok([tfs, scenes])
}

/// Every target with seeds made from `data` (../shared/data) and `project` (the crate root).
pub fn targets(data: &Path, project: &Path, scratch: &Path) -> Result<Vec<Target>> {
    std::fs::create_dir_all(scratch).map_err(|e| Error::io(scratch, e))?;
    let formats = data.join("formats");
    let volumes = data.join("volumes");
    let tooth = real_block(&formats.join("nrrd/tooth.nrrd"))?;
    let mask = real_block(&formats.join("nrrd/seg3d_skull_mask.nrrd"))?;
    let stroke = real_block(&formats.join("nifti/stroke_t1.nii.gz"))?;
    let avm = real_block(&formats.join("nifti/ct_avm.nii.gz"))?;
    let head = real_block(&formats.join("metaimage/HeadMRVolume.mhd"))?;
    let engine = real_block(&volumes.join("engine/engine.nhdr"))?;

    let [nhdr, mhd, mha] = header_seeds(data, &engine, &head)?;

    let mut dicom_files: Vec<PathBuf> = ["dicom/seg3d_mr_640", "dicom/vs_seg001_t1"]
        .iter()
        .filter_map(|d| std::fs::read_dir(formats.join(d)).ok())
        .filter_map(|mut entries| entries.next()?.ok().map(|e| e.path()))
        .collect();
    dicom_files.sort();
    let dicom = dicom_files
        .iter()
        .map(|p| small_dicom(p, scratch))
        .collect::<Result<Vec<_>>>()?;

    let json = |p: &str| read(&project.join(p));
    let [tfs, scenes] = json_seeds(project)?;
    let stores = store_targets(scratch, &engine)?;

    let mut all = vec![
        Target {
            name: "nrrd",
            file: "input.nrrd",
            reader: Reader::Volume,
            companions: vec![],
            seeds: vec![
                written(scratch, "a.nrrd", &tooth)?,
                written(scratch, "b.nrrd", &mask)?,
                written(scratch, "c.nrrd", &stroke)?,
            ],
        },
        Target {
            name: "nrrd-detached",
            file: "input.nhdr",
            reader: Reader::Volume,
            companions: vec![("data.raw".into(), engine.data.as_bytes().to_vec())],
            seeds: vec![nhdr],
        },
        Target {
            name: "nifti",
            file: "input.nii",
            reader: Reader::Volume,
            companions: vec![],
            seeds: vec![
                written(scratch, "a.nii", &stroke)?,
                written(scratch, "b.nii", &avm)?,
            ],
        },
        Target {
            name: "nifti-gz",
            file: "input.nii.gz",
            reader: Reader::Volume,
            companions: vec![],
            seeds: vec![written(scratch, "a.nii.gz", &stroke)?],
        },
        Target {
            name: "metaimage",
            file: "input.mha",
            reader: Reader::Volume,
            companions: vec![],
            seeds: vec![mha],
        },
        Target {
            name: "metaimage-detached",
            file: "input.mhd",
            reader: Reader::Volume,
            companions: vec![("data.raw".into(), head.data.as_bytes().to_vec())],
            seeds: vec![mhd],
        },
        Target {
            name: "dicom",
            file: "series/slice.dcm",
            reader: Reader::Folder,
            companions: vec![],
            seeds: dicom,
        },
        Target {
            name: "transfer-function",
            file: "tf.json",
            reader: Reader::TransferFunction,
            companions: vec![],
            seeds: tfs,
        },
        Target {
            name: "occlusion-tf",
            file: "otf.json",
            reader: Reader::OcclusionTf,
            companions: vec![],
            seeds: vec![
                json("examples/nested_otf.json")?,
                json("examples/mri_brain_otf.json")?,
            ],
        },
        Target {
            name: "feature-map",
            file: "map.features.json",
            reader: Reader::FeatureMap,
            companions: vec![],
            seeds: vec![json("examples/features/nested_sphere.features.json")?],
        },
        Target {
            name: "scene",
            file: "scene.json",
            reader: Reader::Scene,
            companions: vec![],
            seeds: scenes,
        },
    ];
    all.extend(stores);
    Ok(all)
}

fn run_reader(reader: Reader, path: &Path) -> Result<()> {
    match reader {
        Reader::Volume => vellum_volume::io::load(path, None).map(drop),
        Reader::Folder => vellum_volume::io::load(path.parent().unwrap_or(path), None).map(drop),
        Reader::TransferFunction => {
            vellum_render::classify::transfer::TransferFunction::load(path).map(drop)
        }
        Reader::OcclusionTf => vellum_render::classify::otf::OcclusionTf::load(path).map(drop),
        Reader::FeatureMap => vellum_volume::feature::FeatureMap::load(path).map(drop),
        Reader::Scene => vellum_render::render::scene::Scene::load(path).map(drop),
        Reader::Store => read_store(path),
    }
}

/// The store holding `path` opened, its finest level of at most 16 Mi voxels read whole (as
/// `info` reads it) and a box of every level, and its bricked pyramid made (the recorded range
/// checked).
fn read_store(path: &Path) -> Result<()> {
    use vellum_volume::io::ome_zarr::Multiscale;
    let root = path
        .ancestors()
        .find(|p| p.to_string_lossy().ends_with(".zarr"))
        .unwrap_or(path);
    let ms = Multiscale::open(root)?;
    if let Some(pick) = ms.finest_within(1 << 24) {
        ms.read_level(pick)?;
    }
    for (i, l) in ms.levels.iter().enumerate() {
        ms.read_box(i, [0; 3], l.dims.map(|n| n.min(16)))?;
    }
    vellum_volume::bricks::BrickLevels::of_store(Arc::new(ms), 1 << 24).map(drop)
}

/// Every file under `root`, as (path relative to `under`, bytes), sorted.
fn files_under(root: &Path, under: &Path) -> Result<Vec<(String, Vec<u8>)>> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).map_err(|e| Error::io(&dir, e))? {
            let p = entry.map_err(|e| Error::io(&dir, e))?.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p
                    .strip_prefix(under)
                    .unwrap_or(&p)
                    .to_string_lossy()
                    .into_owned();
                out.push((rel, read(&p)?));
            }
        }
    }
    out.sort();
    Ok(out)
}

/// Every file of a store: its key (path inside the store's folder) and its bytes.
type StoreFiles = Vec<(String, Vec<u8>)>;

/// Seeds of the store targets: `block` written by vellum (NGFF 0.5, Zarr v3, zstd, chunks of
/// 8, two levels) as `v3.ome.zarr`, and as NGFF 0.4 on Zarr v2 with zstd chunks of 8 and `.`
/// keys, as Python's ome-zarr writes it, as `v2.zarr`: every file of each.
fn store_seeds(scratch: &Path, block: &Volume) -> Result<[StoreFiles; 2]> {
    use vellum_volume::io::ome_zarr;
    let v3 = scratch.join("v3.ome.zarr");
    let _ = std::fs::remove_dir_all(&v3);
    let opts = ome_zarr::WriteOptions {
        chunk: 8,
        levels: Some(2),
        threads: Some(1),
    };
    ome_zarr::write(&v3, block, &opts)?;
    let v3 = files_under(&v3, scratch)?;
    let [x, y, z] = block.dims;
    let mut v2 = vec![
        (
            "v2.zarr/.zgroup".to_string(),
            br#"{"zarr_format": 2}"#.to_vec(),
        ),
        (
            "v2.zarr/.zattrs".to_string(),
            br#"{"multiscales": [{"version": "0.4", "axes": [{"name": "z", "type": "space"},
                {"name": "y", "type": "space"}, {"name": "x", "type": "space"}],
                "datasets": [{"path": "0", "coordinateTransformations": [
                    {"type": "scale", "scale": [2.0, 1.0, 1.0]}]}]}]}"#
                .to_vec(),
        ),
        (
            "v2.zarr/0/.zarray".to_string(),
            format!(
                r#"{{"zarr_format": 2, "shape": [{z}, {y}, {x}], "chunks": [8, 8, 8],
                "dtype": "<f4", "compressor": {{"id": "zstd", "level": 3}}, "fill_value": 0.0,
                "order": "C", "filters": null}}"#
            )
            .into_bytes(),
        ),
    ];
    let f = block.data.to_f32();
    for cz in 0..z.div_ceil(8) {
        for cy in 0..y.div_ceil(8) {
            for cx in 0..x.div_ceil(8) {
                // A v2 chunk is whole: voxels past the edge are the fill value.
                let mut bytes = Vec::with_capacity(8 * 8 * 8 * 4);
                for k in 0..8 {
                    for j in 0..8 {
                        for i in 0..8 {
                            let p = [cx * 8 + i, cy * 8 + j, cz * 8 + k];
                            let inside = p[0] < x && p[1] < y && p[2] < z;
                            let v = if inside {
                                f[p[0] + x * (p[1] + y * p[2])]
                            } else {
                                0.0
                            };
                            bytes.extend_from_slice(&v.to_le_bytes());
                        }
                    }
                }
                let packed = zstd::bulk::compress(&bytes, 3).map_err(|e| Error::io(scratch, e))?;
                v2.push((format!("v2.zarr/0/{cz}.{cy}.{cx}"), packed));
            }
        }
    }
    Ok([v3, v2])
}

/// The store targets: for each seed store, one target per kind of file mutated (its root
/// metadata, level 0's array metadata, its first chunk), the store's other files beside it.
fn store_targets(scratch: &Path, block: &Volume) -> Result<Vec<Target>> {
    let [v3, v2] = store_seeds(scratch, block)?;
    let cases: [(&'static str, &'static str, &StoreFiles); 6] = [
        ("store-v3-root", "v3.ome.zarr/zarr.json", &v3),
        ("store-v3-array", "v3.ome.zarr/0/zarr.json", &v3),
        ("store-v3-chunk", "v3.ome.zarr/0/c/0/0/0", &v3),
        ("store-v2-attrs", "v2.zarr/.zattrs", &v2),
        ("store-v2-array", "v2.zarr/0/.zarray", &v2),
        ("store-v2-chunk", "v2.zarr/0/0.0.0", &v2),
    ];
    cases
        .into_iter()
        .map(|(name, file, all)| {
            let seed = all.iter().find(|(p, _)| p == file).map(|(_, b)| b.clone());
            let seed =
                seed.ok_or_else(|| Error::Invalid(format!("the seed store has no {file}")))?;
            Ok(Target {
                name,
                file,
                reader: Reader::Store,
                companions: all.iter().filter(|(p, _)| p != file).cloned().collect(),
                seeds: vec![seed],
            })
        })
        .collect()
}

/// Peak resident memory of this process in MiB (Linux), if known.
pub fn peak_memory_mib() -> Option<f64> {
    vellum_volume::memory::peak_resident_kib().map(|k| k as f64 / 1024.0)
}

/// Milliseconds since the watchdog's epoch; 0 means "no input running".
fn now_ms(epoch: Instant) -> u64 {
    epoch.elapsed().as_millis() as u64 + 1
}

/// Runs every selected target for `options.inputs` inputs each, targets in parallel.
pub fn run(targets: &[Target], options: &FuzzOptions) -> Result<Vec<TargetReport>> {
    let chosen: Vec<&Target> = targets
        .iter()
        .filter(|t| {
            options.only.is_empty() || options.only.iter().any(|o| t.name.contains(o.as_str()))
        })
        .collect();
    if chosen.is_empty() {
        return Err(Error::Invalid(format!(
            "no fuzz target matches {:?}; expected some of {}",
            options.only,
            targets
                .iter()
                .map(|t| t.name)
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    let epoch = Instant::now();
    let started: Arc<Vec<AtomicU64>> = Arc::new(chosen.iter().map(|_| AtomicU64::new(0)).collect());
    let dirs: Vec<PathBuf> = chosen
        .iter()
        .map(|t| options.work_dir.join(t.name))
        .collect();
    for (t, dir) in chosen.iter().zip(&dirs) {
        let input = dir.join(t.file);
        let parent = input.parent().unwrap_or(dir);
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
        for (name, bytes) in &t.companions {
            let at = dir.join(name);
            if let Some(folder) = at.parent() {
                std::fs::create_dir_all(folder).map_err(|e| Error::io(folder, e))?;
            }
            std::fs::write(&at, bytes).map_err(|e| Error::io(&at, e))?;
        }
    }
    // The watchdog: an input running past the bound is saved and the process ends with 3.
    let bound = options.time_bound.as_millis() as u64;
    let watch = {
        let started = Arc::clone(&started);
        let names: Vec<(&'static str, PathBuf)> = chosen
            .iter()
            .zip(&dirs)
            .map(|(t, d)| (t.name, d.join(t.file)))
            .collect();
        let keep = options.work_dir.clone();
        std::thread::spawn(move || loop {
            std::thread::sleep(Duration::from_millis(100));
            for (k, s) in started.iter().enumerate() {
                let t0 = s.load(Ordering::SeqCst);
                if t0 == u64::MAX {
                    return;
                }
                if t0 > 0 && now_ms(epoch).saturating_sub(t0) > bound {
                    let (name, input) = &names[k];
                    let saved = keep.join(format!("hang-{name}"));
                    let _ = std::fs::copy(input, &saved);
                    eprintln!(
                        "fuzz: {name}: an input ran past {bound} ms (a hang); saved as {}",
                        saved.display()
                    );
                    std::process::exit(3);
                }
            }
        })
    };
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let reports: Vec<TargetReport> = std::thread::scope(|scope| {
        let handles: Vec<_> = chosen
            .iter()
            .enumerate()
            .map(|(k, t)| {
                let (started, dir) = (&started, &dirs[k]);
                scope.spawn(move || fuzz_target(t, k, options, dir, started, epoch))
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_default())
            .collect()
    });
    std::panic::set_hook(hook);
    started[0].store(u64::MAX, Ordering::SeqCst);
    let _ = watch.join();
    Ok(reports)
}

fn fuzz_target(
    t: &Target,
    k: usize,
    options: &FuzzOptions,
    dir: &Path,
    started: &[AtomicU64],
    epoch: Instant,
) -> TargetReport {
    let mut rng = Rng::new(options.seed ^ (k as u64 + 1).wrapping_mul(0xA24B_AED4_963E_E407));
    let input = dir.join(t.file);
    let mut r = TargetReport {
        target: t.name.to_string(),
        ..Default::default()
    };
    let mut total = Duration::ZERO;
    for i in 0..options.inputs {
        let seed = &t.seeds[rng.below(t.seeds.len())];
        let other = &t.seeds[rng.below(t.seeds.len())];
        // Every 16th input is a seed as it is, so accepted inputs keep being exercised.
        let bytes = if i % 16 == 0 {
            seed.clone()
        } else {
            mutate(&mut rng, seed, other)
        };
        if std::fs::File::create(&input)
            .and_then(|mut f| f.write_all(&bytes))
            .is_err()
        {
            continue;
        }
        started[k].store(now_ms(epoch), Ordering::SeqCst);
        let t0 = Instant::now();
        let outcome = catch_unwind(AssertUnwindSafe(|| run_reader(t.reader, &input)));
        let dt = t0.elapsed();
        started[k].store(0, Ordering::SeqCst);
        total += dt;
        r.inputs += 1;
        r.max_ms = r.max_ms.max(dt.as_secs_f64() * 1e3);
        match outcome {
            Ok(Ok(())) => r.accepted += 1,
            Ok(Err(e)) => {
                r.refused += 1;
                // What the command line shows: the message made one line.
                let text = vellum_error::one_line(&e.to_string());
                if text.trim().is_empty() || text.contains('\n') {
                    r.unclear += 1;
                    if r.unclear_messages.len() < 3 {
                        r.unclear_messages.push(text);
                        let saved = options.work_dir.join(format!("unclear-{}-{i}", t.name));
                        let _ = std::fs::write(saved, &bytes);
                    }
                }
            }
            Err(panic) => {
                r.crashes += 1;
                let msg = panic
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                if r.crash_messages.len() < 5 && !r.crash_messages.contains(&msg) {
                    r.crash_messages.push(msg);
                }
                if r.crashes <= 20 {
                    let saved = options.work_dir.join(format!("crash-{}-{i}", t.name));
                    let _ = std::fs::write(saved, &bytes);
                }
            }
        }
    }
    r.mean_us = total.as_secs_f64() * 1e6 / r.inputs.max(1) as f64;
    r
}
