//! Reading volumes from files, and writing them as NRRD.
//!
//! [`load`] picks a reader from the extension (or the first bytes), and every reader funnels its
//! voxel bytes through two shared helpers: `read_payload`, which insists on exactly the byte
//! count the header promises and turns decompression failures into sentences, and `decode`,
//! which converts the file's type and byte order into one of the four [`VoxelType`]s vellum keeps.
//! Types vellum does not keep are widened: int8 becomes i16 (exact), and uint32, int32 and float64
//! become f32, which is exact only up to 2^24 in magnitude (float64 also loses precision): a file
//! whose rounding would merge distinct values is refused, and visible rounding is warned about. A
//! header is checked with [`check_dims`] before any voxel buffer is allocated, so a corrupt size
//! cannot make us try to allocate terabytes.

mod dicom;
pub(crate) mod guarded_store;
pub mod http_store;
mod metaimage;
mod ngff_checks;
pub(crate) mod nifti;
pub mod nrrd;
pub mod ome_zarr;
mod raw;

pub(crate) use nifti::write_nifti;
pub use nrrd::write_nrrd;

use std::fs::File;
use std::io::{self, BufReader, Read};
use std::path::Path;

use flate2::read::{MultiGzDecoder, ZlibDecoder};
use rayon::prelude::*;

use super::{check_dims, Volume, VoxelData, VoxelType};
use vellum_error::{Error, Result};

/// How to read a headerless file (`--raw-dims`, `--raw-type` and friends on the command line).
#[derive(Clone, Debug, PartialEq)]
pub struct RawSpec {
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// Type of every voxel in the file.
    pub voxel_type: VoxelType,
    /// True when multi-byte voxels are stored most significant byte first.
    pub big_endian: bool,
    /// Bytes to skip before the voxels (after decompression for `.gz` files).
    pub offset: u64,
    /// Physical voxel size along x, y, z.
    pub spacing: [f64; 3],
}

/// Writes a volume in the format its extension names: `.nrrd` (gzip-encoded NRRD), `.nii` or
/// `.nii.gz` (NIfTI-1). Any other extension is refused before anything is written.
pub fn write(path: &Path, volume: &Volume) -> Result<()> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    if name.ends_with(".nii") || name.ends_with(".nii.gz") {
        write_nifti(path, volume)
    } else {
        crate::output::check_extension(path, &["nrrd", "nii", "nii.gz"], "a volume")?;
        write_nrrd(path, volume)
    }
}

/// Level 0 of the OME-Zarr store at `path` (a folder or a URL), in core. `render` streams larger
/// ones through the brick cache without coming here; anything else must fit in memory.
fn load_store(path: &Path, pick: ome_zarr::Pick) -> Result<Volume> {
    load_level(path, pick, 0)
}

/// Level `level` of the OME-Zarr store at `path` (the time point and channel of `pick`), read
/// whole with its spacing and placement; refused in one sentence when it is not a store, has no
/// such level, or the level would take more than half of this machine's memory.
pub fn load_level(path: &Path, pick: ome_zarr::Pick, level: usize) -> Result<Volume> {
    if !ome_zarr::is_store(path) {
        return Err(Error::Invalid(format!(
            "`level` picks a level of an OME-Zarr store's pyramid; {} is not one",
            path.display()
        )));
    }
    let ms = ome_zarr::Multiscale::open_picked(path, pick)?;
    if level >= ms.levels.len() {
        return Err(Error::format(
            path,
            format!(
                "has levels 0 to {}; level {level} is not one of them",
                ms.levels.len() - 1
            ),
        ));
    }
    let bytes = ms.level_bytes(level);
    if !crate::memory::fits_in_memory(bytes) {
        return Err(Error::format(
            path,
            format!(
                "level {level} holds {:.1} GiB, more than half of this machine's memory; expected a level that fits (a coarser one), or `vellum render` (which streams it through the brick cache)",
                bytes as f64 / (1u64 << 30) as f64
            ),
        ));
    }
    ms.read_level(level)
}

/// Loads a volume. With `raw` the file is read as headerless voxels; otherwise a folder is read as
/// a DICOM series and a file by its extension (`.nrrd`, `.nhdr`, `.nii`, `.nii.gz`, `.mhd`, `.mha`)
/// or, failing that, by its first bytes. Float volumes with NaN or infinite voxels are rejected.
pub fn load(path: &Path, raw: Option<&RawSpec>) -> Result<Volume> {
    load_picked(path, raw, ome_zarr::Pick::default())
}

/// [`load`], reading the time point and channel of `pick` from an OME-Zarr store; a pick of any
/// other input is refused.
pub fn load_picked(path: &Path, raw: Option<&RawSpec>, pick: ome_zarr::Pick) -> Result<Volume> {
    if pick != ome_zarr::Pick::default() && !ome_zarr::is_store(path) {
        return Err(Error::Invalid(format!(
            "`time` and `channels` pick a time point and a channel of an OME-Zarr store; {} is not one",
            path.display()
        )));
    }
    if http_store::is_url(path) && raw.is_none() {
        return load_store(path, pick);
    }
    if !path.exists() && std::fs::symlink_metadata(path).is_ok() {
        return Err(Error::io(
            path,
            io::Error::new(
                io::ErrorKind::NotFound,
                "it is a symbolic link that leads nowhere (a loop, or a missing target); expected a volume file or DICOM folder",
            ),
        ));
    }
    if !path.exists() {
        return Err(Error::io(
            path,
            io::Error::new(
                io::ErrorKind::NotFound,
                "the file does not exist; expected a volume file or DICOM folder",
            ),
        ));
    }
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let has = |ext: &str| name.ends_with(ext);
    let volume = if let Some(spec) = raw {
        raw::read(path, spec)?
    } else if ome_zarr::is_store(path) {
        load_store(path, pick)?
    } else if path.is_dir() {
        dicom::read(path)?
    } else if has(".nrrd") || has(".nhdr") {
        nrrd::read(path)?
    } else if has(".img") || has(".img.gz") {
        return Err(Error::format(
            path,
            "NIfTI-1/Analyze .hdr/.img pairs are not supported; expected a single .nii or .nii.gz file",
        ));
    } else if has(".nii") || has(".nii.gz") || has(".hdr") || has(".hdr.gz") {
        nifti::read(path)?
    } else if has(".mhd") || has(".mha") {
        metaimage::read(path)?
    } else {
        match sniff(path)? {
            Some(Sniffed::Nrrd) => nrrd::read(path)?,
            Some(Sniffed::Nifti) => nifti::read(path)?,
            None if has(".zarr") => {
                return Err(Error::format(
                    path,
                    "is a file; expected an OME-Zarr store to be a folder (holding zarr.json or .zgroup)",
                ))
            }
            None => {
                return Err(Error::format(
                    path,
                    "unknown format; expected .nrrd, .nhdr, .nii, .nii.gz, .mhd, .mha, an OME-Zarr \
                     folder (.zarr), a DICOM folder, or raw input with --raw-dims and --raw-type",
                ))
            }
        }
    };
    volume.check_finite(&path.display().to_string())?;
    Ok(volume)
}

enum Sniffed {
    Nrrd,
    Nifti,
}

/// Opens a file for reading, refusing anything that is not a regular file: a FIFO would block
/// forever and a device such as /dev/zero never ends.
pub(crate) fn open_regular(path: &Path) -> Result<File> {
    open_regular_as(path, "a volume file")
}

/// [`open_regular`] with what the file should have been (`expected`) in the sentence.
fn open_regular_as(path: &Path, expected: &str) -> Result<File> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(Error::io(
            path,
            io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "it is not a regular file (a folder, FIFO, device or socket); expected {expected}"
                ),
            ),
        ));
    }
    File::open(path).map_err(|e| Error::io(path, e))
}

/// The largest text file vellum reads (transfer functions, occlusion TFs, feature maps, scenes):
/// far above any real one, and small enough that a wrong path cannot exhaust memory.
pub(crate) const MAX_TEXT_BYTES: u64 = 64 << 20;

/// Reads a JSON or other text file: a regular file (a FIFO would block forever and a device never
/// ends) of at most `MAX_TEXT_BYTES`, in UTF-8.
pub fn read_text(path: &Path) -> Result<String> {
    let file = open_regular_as(path, "a JSON file")?;
    let mut bytes = Vec::new();
    file.take(MAX_TEXT_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| Error::io(path, e))?;
    if bytes.len() as u64 > MAX_TEXT_BYTES {
        return Err(Error::format(
            path,
            format!(
                "it is larger than {} MiB; expected a text file of settings",
                MAX_TEXT_BYTES >> 20
            ),
        ));
    }
    String::from_utf8(bytes).map_err(|e| {
        Error::format(
            path,
            format!("it is not UTF-8 text ({e}); expected a JSON file"),
        )
    })
}

/// Recognises NRRD ("NRRD" magic) and NIfTI-1 (sizeof_hdr 348, possibly gzipped) by content.
fn sniff(path: &Path) -> Result<Option<Sniffed>> {
    let mut head = Vec::with_capacity(348);
    let file = open_regular(path)?;
    file.take(348)
        .read_to_end(&mut head)
        .map_err(|e| Error::io(path, e))?;
    if head.starts_with(b"NRRD") {
        return Ok(Some(Sniffed::Nrrd));
    }
    let is_nifti = |h: &[u8]| {
        h.len() >= 4 && {
            let b = [h[0], h[1], h[2], h[3]];
            i32::from_le_bytes(b) == 348 || i32::from_be_bytes(b) == 348
        }
    };
    if is_nifti(&head) {
        return Ok(Some(Sniffed::Nifti));
    }
    if head.starts_with(&[0x1f, 0x8b]) {
        let file = open_regular(path)?;
        let mut inner = Vec::with_capacity(4);
        // A failure to decompress just means "not a gzipped NIfTI".
        let _ = MultiGzDecoder::new(BufReader::new(file))
            .take(4)
            .read_to_end(&mut inner);
        if is_nifti(&inner) {
            return Ok(Some(Sniffed::Nifti));
        }
    }
    Ok(None)
}

/// Checks header dims with [`check_dims`], naming the file, and returns the voxel count.
pub(crate) fn voxel_count(path: &Path, dims: [usize; 3]) -> Result<usize> {
    check_dims(dims).map_err(|e| Error::format(path, e.to_string()))?;
    Ok(dims.iter().product())
}

/// [`Volume::new`] with the file named in the error.
pub(crate) fn build(
    path: &Path,
    dims: [usize; 3],
    spacing: [f64; 3],
    data: VoxelData,
) -> Result<Volume> {
    Volume::new(dims, spacing, data).map_err(|e| Error::format(path, e.to_string()))
}

/// How voxel bytes are stored in a file.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(crate) enum Compression {
    None,
    Gzip,
    Zlib,
}

impl Compression {
    fn stream(self) -> &'static str {
        match self {
            Compression::None => "data",
            Compression::Gzip => "gzip stream",
            Compression::Zlib => "zlib stream",
        }
    }
}

/// Wraps `src` in the decompressor for `compression`.
pub(crate) fn decoder<'a>(src: impl Read + 'a, compression: Compression) -> Box<dyn Read + 'a> {
    match compression {
        Compression::None => Box::new(src),
        Compression::Gzip => Box::new(MultiGzDecoder::new(BufReader::new(src))),
        Compression::Zlib => Box::new(ZlibDecoder::new(src)),
    }
}

/// Turns a read error into a sentence: decompressors report truncation as `UnexpectedEof` and
/// damage as `InvalidInput`/`InvalidData`; anything else is an I/O failure.
pub(crate) fn read_error(path: &Path, compression: Compression, e: io::Error) -> Error {
    let stream = compression.stream();
    match e.kind() {
        io::ErrorKind::UnexpectedEof if compression != Compression::None => Error::format(
            path,
            format!("{stream} is truncated; expected a complete {stream} holding all voxels"),
        ),
        io::ErrorKind::InvalidInput | io::ErrorKind::InvalidData
            if compression != Compression::None =>
        {
            Error::format(
                path,
                format!("{stream} is corrupt ({e}); expected a valid {stream}"),
            )
        }
        _ => Error::io(path, e),
    }
}

/// Reads exactly `expected` voxel bytes from `src` (already decompressed by [`decoder`]) after
/// skipping `skip` bytes. More or fewer bytes than the header promises is an error. The buffer
/// grows as data arrives, so a header that overstates the size cannot force a huge allocation.
pub(crate) fn read_payload(
    path: &Path,
    src: &mut dyn Read,
    compression: Compression,
    skip: u64,
    expected: usize,
) -> Result<Vec<u8>> {
    let err = |e| read_error(path, compression, e);
    let skipped = io::copy(&mut (&mut *src).take(skip), &mut io::sink()).map_err(err)?;
    let mut buf = Vec::with_capacity(expected.min(1 << 26));
    (&mut *src)
        .take(expected as u64 + 1)
        .read_to_end(&mut buf)
        .map_err(err)?;
    if skipped == skip && buf.len() == expected {
        return Ok(buf);
    }
    let extra = if buf.len() > expected {
        io::copy(src, &mut io::sink()).map_err(err)?
    } else {
        0
    };
    let held = skipped + buf.len() as u64 + extra;
    let skip_note = if skip > 0 {
        format!(" ({skip} to skip plus {expected} of voxels)")
    } else {
        String::new()
    };
    Err(Error::format(
        path,
        format!(
            "{} holds {held} bytes but the header needs {}{skip_note}",
            compression.stream(),
            skip + expected as u64
        ),
    ))
}

/// Voxel types found in files, before widening to a [`VoxelType`].
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(crate) enum FileType {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    F32,
    F64,
}

impl FileType {
    /// Bytes per voxel in the file.
    pub(crate) fn size(self) -> usize {
        match self {
            FileType::U8 | FileType::I8 => 1,
            FileType::U16 | FileType::I16 => 2,
            FileType::U32 | FileType::I32 | FileType::F32 => 4,
            FileType::F64 => 8,
        }
    }
}

impl From<VoxelType> for FileType {
    fn from(t: VoxelType) -> Self {
        match t {
            VoxelType::U8 => FileType::U8,
            VoxelType::U16 => FileType::U16,
            VoxelType::I16 => FileType::I16,
            VoxelType::F32 => FileType::F32,
        }
    }
}

/// Converts `N`-byte values in the given byte order with `f`, in parallel.
fn convert<const N: usize, T: Send>(
    bytes: &[u8],
    big_endian: bool,
    f: impl Fn([u8; N]) -> T + Sync,
) -> Vec<T> {
    bytes
        .par_chunks_exact(N)
        .map(|c| {
            let mut b = [0u8; N];
            b.copy_from_slice(c);
            if big_endian {
                b.reverse();
            }
            f(b)
        })
        .collect()
}

/// Decodes voxels of file type `ty` into vellum's types, widening as described in the module docs.
/// `bytes.len()` must be a multiple of the type size.
///
/// uint32, int32 and float64 voxels become f32. Where that rounding is large against the data's
/// own range, the data is refused (it would collapse: uint32 values 4000000000..4000000255 become
/// two floats); where it is merely visible, a warning says how much was lost. See
/// [`check_precision`].
pub(crate) fn decode(
    path: &Path,
    ty: FileType,
    big_endian: bool,
    bytes: &[u8],
) -> Result<VoxelData> {
    debug_assert_eq!(bytes.len() % ty.size(), 0);
    let be = big_endian;
    Ok(match ty {
        FileType::U8 => VoxelData::U8(bytes.to_vec()),
        FileType::I8 => VoxelData::I16(bytes.par_iter().map(|&b| b as i8 as i16).collect()),
        FileType::U16 => VoxelData::U16(convert(bytes, be, u16::from_le_bytes)),
        FileType::I16 => VoxelData::I16(convert(bytes, be, i16::from_le_bytes)),
        FileType::U32 => narrow(
            path,
            "uint32",
            convert(bytes, be, |b| u32::from_le_bytes(b) as f64),
        )?,
        FileType::I32 => narrow(
            path,
            "int32",
            convert(bytes, be, |b| i32::from_le_bytes(b) as f64),
        )?,
        FileType::F32 => VoxelData::F32(convert(bytes, be, f32::from_le_bytes)),
        FileType::F64 => narrow(path, "float64", convert(bytes, be, f64::from_le_bytes))?,
    })
}

/// Rounding to f32 that is at most this fraction of the data range passes silently: it is below
/// what any transfer function, histogram or image of vellum can show.
pub(crate) const PRECISION_SILENT: f64 = 1e-6;
/// Rounding beyond this fraction of the data range refuses the file: a 4096-entry table could no
/// longer tell neighbouring values apart.
pub(crate) const PRECISION_REFUSED: f64 = 1.0 / 4096.0;

/// What rounding wider values to f32 did to them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PrecisionLoss {
    /// (min, max) of the values as stored (finite ones only).
    pub(crate) range: [f64; 2],
    /// Voxels whose f32 value differs from the stored one.
    pub(crate) changed: usize,
    /// The largest |f32 − stored| over finite voxels that fit f32's range.
    pub(crate) max_error: f64,
}

/// Measures the rounding of `values` to f32. Values beyond f32's range are left to the finiteness
/// check of [`load`], which names them.
pub(crate) fn precision_loss(values: &[f64]) -> PrecisionLoss {
    let (lo, hi, changed, err) = values
        .par_iter()
        .filter(|v| v.is_finite() && v.abs() <= f32::MAX as f64)
        .map(|&v| {
            let e = (v - v as f32 as f64).abs();
            (v, v, (e > 0.0) as usize, e)
        })
        .reduce(
            || (f64::INFINITY, f64::NEG_INFINITY, 0, 0.0),
            |a, b| (a.0.min(b.0), a.1.max(b.1), a.2 + b.2, a.3.max(b.3)),
        );
    PrecisionLoss {
        range: if lo <= hi { [lo, hi] } else { [0.0, 0.0] },
        changed,
        max_error: err,
    }
}

/// Refuses, warns about or accepts `loss` (see [`PRECISION_SILENT`] and [`PRECISION_REFUSED`]).
/// Returns the warning, if any.
pub(crate) fn check_precision(
    path: &Path,
    type_name: &str,
    loss: &PrecisionLoss,
) -> Result<Option<String>> {
    let width = loss.range[1] - loss.range[0];
    if loss.changed == 0 || width <= 0.0 || loss.max_error <= PRECISION_SILENT * width {
        return Ok(None);
    }
    let [lo, hi] = loss.range;
    let e = loss.max_error;
    let percent = 100.0 * e / width;
    if e > PRECISION_REFUSED * width {
        return Err(Error::format(
            path,
            format!(
                "its {type_name} values {lo}..{hi} do not fit 32-bit floats, which vellum computes in: \
                 rounding moves them by up to {e} ({percent:.3}% of their range), so distinct values would merge; \
                 expected values whose magnitude is small against their range (subtract an offset, or store them as float32)"
            ),
        ));
    }
    Ok(Some(format!(
        "{}: {} of its {type_name} voxels change when rounded to 32-bit floats, by up to {e} ({percent:.4}% of the range {lo}..{hi})",
        path.display(),
        loss.changed
    )))
}

/// Rounds wide values to f32 after [`check_precision`], logging its warning.
fn narrow(path: &Path, type_name: &str, values: Vec<f64>) -> Result<VoxelData> {
    if let Some(warning) = check_precision(path, type_name, &precision_loss(&values))? {
        log::warn!("{warning}");
    }
    // Values beyond f32's range become infinite here and are then reported as out of range (see
    // `load`), not as NaN.
    Ok(VoxelData::F32(
        values.par_iter().map(|&v| v as f32).collect(),
    ))
}

/// Parses a whitespace-separated list of exactly `n` numbers for header field `field`.
pub(crate) fn parse_list<T: std::str::FromStr>(
    path: &Path,
    field: &str,
    value: &str,
    n: usize,
) -> Result<Vec<T>> {
    let items: Option<Vec<T>> = value.split_whitespace().map(|s| s.parse().ok()).collect();
    match items {
        Some(v) if v.len() == n => Ok(v),
        _ => {
            let kind = match std::any::type_name::<T>() {
                "usize" | "u64" | "u32" => "whole numbers of zero or more",
                _ => "numbers",
            };
            Err(Error::format(
                path,
                format!("field '{field}' is '{value}'; expected {n} {kind}"),
            ))
        }
    }
}
