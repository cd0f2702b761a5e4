//! DICOM series: a folder of single-frame slices, each parsed with `dicom-object`. Pixel data is
//! decoded here for the uncompressed transfer syntaxes only, which keeps the JPEG and JPEG 2000
//! codec stack out of the build. Slices are ordered by their position along the slice normal,
//! because file names and instance numbers are not reliably in spatial order.

use std::fs;
use std::path::{Path, PathBuf};

use dicom_dictionary_std::tags;
use dicom_object::mem::InMemElement;
use dicom_object::{DefaultDicomObject, Tag};
use rayon::prelude::*;

use super::{build, decode, voxel_count, FileType};
use crate::geometry::Geometry;
use crate::{Volume, VoxelData};
use vellum_error::{Error, Result};

/// The uncompressed transfer syntaxes: (UID, name, big endian).
const SUPPORTED: [(&str, &str, bool); 3] = [
    ("1.2.840.10008.1.2", "implicit VR little endian", false),
    ("1.2.840.10008.1.2.1", "explicit VR little endian", false),
    ("1.2.840.10008.1.2.2", "explicit VR big endian", true),
];

/// What one slice contributes to the volume.
struct Slice {
    file: PathBuf,
    series: Option<String>,
    rows: usize,
    cols: usize,
    bits_allocated: u16,
    bits_stored: u16,
    signed: bool,
    position: Option<[f64; 3]>,
    orientation: Option<[f64; 6]>,
    instance: Option<i64>,
    pixel_spacing: Option<[f64; 2]>,
    slice_spacing: Option<f64>,
    slope: f64,
    intercept: f64,
    /// Pixels as little-endian bytes.
    pixels: Vec<u8>,
}

/// Reads every DICOM image in `dir` as one series.
pub(super) fn read(dir: &Path) -> Result<Volume> {
    let entries = fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut files = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| Error::io(dir, e))?.path();
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if path.is_file() && !name.starts_with('.') && name != "DICOMDIR" {
            files.push(path);
        }
    }
    files.sort();
    let parsed: Vec<Option<Slice>> = files
        .par_iter()
        .map(|f| read_slice(f))
        .collect::<Result<_>>()?;
    let mut slices: Vec<Slice> = parsed.into_iter().flatten().collect();
    let Some(first) = slices.first() else {
        return Err(Error::format(
            dir,
            "folder holds no DICOM images; expected a folder of DICOM slices",
        ));
    };
    if let Some(other) = slices.iter().find(|s| s.series != first.series) {
        return Err(Error::format(
            dir,
            format!(
                "folder mixes series {} and {} ({}); expected a single series",
                first.series.as_deref().unwrap_or("(none)"),
                other.series.as_deref().unwrap_or("(none)"),
                other.file.display()
            ),
        ));
    }
    let shape = |s: &Slice| (s.rows, s.cols, s.bits_allocated, s.bits_stored, s.signed);
    if let Some(other) = slices.iter().find(|s| shape(s) != shape(first)) {
        return Err(Error::format(
            dir,
            format!(
                "slice {} is {}x{} with {} bits (signed: {}) but slice {} is {}x{} with {} bits (signed: {}); \
                 expected every slice to share size and type",
                other.file.display(),
                other.cols,
                other.rows,
                other.bits_allocated,
                other.signed,
                first.file.display(),
                first.cols,
                first.rows,
                first.bits_allocated,
                first.signed
            ),
        ));
    }

    // Order along the normal of the image plane when every slice has a position and orientation.
    let normal = first.orientation.map(|o| {
        let (r, c) = ([o[0], o[1], o[2]], [o[3], o[4], o[5]]);
        [
            r[1] * c[2] - r[2] * c[1],
            r[2] * c[0] - r[0] * c[2],
            r[0] * c[1] - r[1] * c[0],
        ]
    });
    let along = |s: &Slice| {
        Some(
            s.position?
                .iter()
                .zip(normal?)
                .map(|(p, n)| p * n)
                .sum::<f64>(),
        )
    };
    let mut z_spacing = first.slice_spacing.unwrap_or(1.0);
    if slices.iter().all(|s| along(s).is_some()) {
        slices.sort_by(|a, b| along(a).unwrap_or(0.0).total_cmp(&along(b).unwrap_or(0.0)));
        let mut gaps: Vec<f64> = slices
            .windows(2)
            .map(|w| along(&w[1]).unwrap_or(0.0) - along(&w[0]).unwrap_or(0.0))
            .collect();
        if !gaps.is_empty() {
            gaps.sort_by(f64::total_cmp);
            z_spacing = gaps[gaps.len() / 2];
            if z_spacing < 1e-6 {
                return Err(Error::format(
                    dir,
                    "several slices share the same position; expected one slice per position (a single series)",
                ));
            }
            let (lo, hi) = (gaps[0], gaps[gaps.len() - 1]);
            if hi - lo > SPACING_TOLERANCE * z_spacing {
                return Err(Error::format(
                    dir,
                    format!("slices are unevenly spaced ({lo:.4} to {hi:.4} mm apart); expected one spacing within {}%, as resampling an uneven series is not supported", SPACING_TOLERANCE * 100.0),
                ));
            }
        }
    } else if slices.iter().all(|s| s.instance.is_some()) {
        slices.sort_by_key(|s| s.instance);
    }

    let first = &slices[0];
    let dims = [first.cols, first.rows, slices.len()];
    voxel_count(dir, dims)?;
    let [row_spacing, col_spacing] = first.pixel_spacing.unwrap_or([1.0, 1.0]);
    let spacing = [col_spacing, row_spacing, z_spacing];
    let ty = match (first.bits_allocated, first.signed) {
        (8, false) => FileType::U8,
        (8, true) => FileType::I8,
        (16, false) => FileType::U16,
        _ => FileType::I16,
    };
    let bytes: Vec<u8> = slices
        .iter()
        .flat_map(|s| s.pixels.iter().copied())
        .collect();
    let mut data = decode(dir, ty, false, &bytes)?;
    drop(bytes);
    mask_unused_bits(&mut data, first.bits_stored);
    if slices.iter().any(|s| s.slope != 1.0 || s.intercept != 0.0) {
        let params: Vec<(f64, f64)> = slices.iter().map(|s| (s.slope, s.intercept)).collect();
        data = rescale(&data, &params, first.rows * first.cols);
    }
    let v = build(dir, dims, spacing, data)?;
    // The geometry: row and column directions, their normal (the sorted slices run along it),
    // and the first slice's position.
    match (first.orientation, first.position, normal) {
        (Some(o), Some(p), Some(n)) => v
            .with_geometry(
                Geometry::lps(p, [[o[0], o[1], o[2]], [o[3], o[4], o[5]], n])
                    .map_err(|e| Error::format(dir, e.to_string()))?,
            )
            .map_err(|e| Error::format(dir, e.to_string())),
        _ => Ok(v),
    }
}

/// Largest spread of slice gaps, as a fraction of the median gap, taken as one spacing.
const SPACING_TOLERANCE: f64 = 0.01;

/// Where a Part 10 file's "DICM" magic is: after the 128-byte preamble, or at the start of a file
/// written without one (which the parser also accepts).
fn magic_offset(bytes: &[u8]) -> Option<usize> {
    [128, 0]
        .into_iter()
        .find(|&at| bytes.get(at..at + 4) == Some(&b"DICM"[..]))
}

/// Refuses a file in which dicom-rs would be asked to allocate more than the file holds: its
/// parser reserves whatever length an element claims before reading the value, so a 4 KB file can
/// ask for gigabytes. The check walks the file with the parser itself (so it sees exactly the
/// elements, sequences and encodings the real parse will), stopping at each header to compare the
/// claimed length with the file's size, before the value is read. A file the parser cannot read
/// passes here and is refused by the real parse with its own message.
fn check_lengths(bytes: &[u8]) -> std::result::Result<(), String> {
    use dicom_encoding::decode::Decode;
    use dicom_encoding::transfer_syntax::TransferSyntaxIndex;
    use dicom_parser::dataset::DataToken;
    let Some(magic) = magic_offset(bytes) else {
        return Ok(());
    };
    let total = bytes.len() as u64;
    let too_long = |what: String, n: u32| {
        Err(format!(
            "{what} claims {n} bytes but the whole file holds {total}"
        ))
    };
    // The meta group is read by dicom-object's own loop, which also reserves before it reads:
    // walk its headers first with the same explicit little-endian decoder, for as many bytes as
    // its group length says.
    let decoder = dicom_encoding::decode::file_header_decoder();
    let mut meta = std::io::Cursor::new(&bytes[magic + 4..]);
    if let Ok((header, _)) = decoder.decode_header(&mut meta) {
        let mut group_length = [0u8; 4];
        if header.len.get() == Some(4)
            && std::io::Read::read_exact(&mut meta, &mut group_length).is_ok()
        {
            let end = meta.position() + u32::from_le_bytes(group_length) as u64;
            while meta.position() < end {
                let Ok((h, _)) = decoder.decode_header(&mut meta) else {
                    break;
                };
                match h.len.get() {
                    Some(n) if n as u64 > total => {
                        return too_long(format!("meta element {}", h.tag), n)
                    }
                    Some(n) => meta.set_position(meta.position() + n as u64),
                    None => break,
                }
            }
        }
    }
    let mut source = std::io::Cursor::new(&bytes[magic..]);
    let Ok(meta) = dicom_object::FileMetaTable::from_reader(&mut source) else {
        return Ok(());
    };
    let ts_uid = meta.transfer_syntax().trim_end_matches(['\0', ' ']);
    let Some(ts) = dicom_transfer_syntax_registry::TransferSyntaxRegistry.get(ts_uid) else {
        return Ok(());
    };
    let Ok(reader) = dicom_parser::DataSetReader::new_with_ts(source, ts) else {
        return Ok(());
    };
    for token in reader {
        let (what, len) = match token {
            Ok(DataToken::ElementHeader(h)) => (format!("element {}", h.tag), h.len),
            Ok(DataToken::SequenceStart { tag, len }) => (format!("sequence {tag}"), len),
            Ok(DataToken::ItemStart { len }) => ("an item".to_string(), len),
            Ok(_) => continue,
            Err(_) => return Ok(()),
        };
        if let Some(n) = len.get().filter(|&n| n as u64 > total) {
            return too_long(what, n);
        }
    }
    Ok(())
}

/// Parses one file as a DICOM object; `None` when it is not DICOM and not named `.dcm`.
fn parse(path: &Path) -> Result<Option<DefaultDicomObject>> {
    let is_dcm = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("dcm"));
    // The parser allocates whatever length an element claims before reading it: a 4 KB file can
    // ask for gigabytes. Check the claims against the file's size first.
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    if let Err(claim) = check_lengths(&bytes) {
        return Err(Error::format(
            path,
            format!("{claim}; expected a complete DICOM file"),
        ));
    }
    // Parsed from the bytes already read, from the magic on, as open_file would read the file.
    let parsed = match magic_offset(&bytes) {
        Some(at) => dicom_object::from_reader(&bytes[at..]),
        None => dicom_object::open_file(path),
    };
    match parsed {
        Ok(obj) => Ok(Some(obj)),
        Err(e) if is_dcm => Err(Error::format(
            path,
            format!("file could not be parsed as DICOM ({e}); expected a DICOM slice"),
        )),
        Err(_) => Ok(None),
    }
}

/// The elements of one parsed file, read with messages that name the file and the element.
struct Fields<'a> {
    obj: &'a DefaultDicomObject,
    path: &'a Path,
}

impl Fields<'_> {
    fn int(&self, tag: Tag, name: &str) -> Result<Option<i64>> {
        element(self.obj, tag)
            .map(|e| e.to_int::<i64>())
            .transpose()
            .map_err(|_| {
                Error::format(
                    self.path,
                    format!("{name} is not a whole number; expected one"),
                )
            })
    }

    fn floats(&self, tag: Tag, name: &str, n: usize) -> Result<Option<Vec<f64>>> {
        match element(self.obj, tag).map(|e| e.to_multi_float64()) {
            None => Ok(None),
            Some(Ok(v)) if v.len() == n => Ok(Some(v)),
            Some(_) => Err(Error::format(
                self.path,
                format!("{name} is malformed; expected {n} numbers"),
            )),
        }
    }

    fn required(&self, tag: Tag, name: &str) -> Result<i64> {
        self.int(tag, name)?.ok_or_else(|| {
            Error::format(
                self.path,
                format!("{name} is missing; expected it in every image slice"),
            )
        })
    }

    /// Rows, columns, bits allocated and stored, and whether pixels are signed: a single-frame
    /// grey image of 8 or 16 bits.
    fn pixel_layout(&self) -> Result<(usize, usize, u16, u16, bool)> {
        let path = self.path;
        let rows = self.required(tags::ROWS, "Rows")?;
        let cols = self.required(tags::COLUMNS, "Columns")?;
        let bits_allocated = self.required(tags::BITS_ALLOCATED, "BitsAllocated")?;
        let bits_stored = self
            .int(tags::BITS_STORED, "BitsStored")?
            .unwrap_or(bits_allocated);
        let signed = self.int(tags::PIXEL_REPRESENTATION, "PixelRepresentation")? == Some(1);
        let samples = self
            .int(tags::SAMPLES_PER_PIXEL, "SamplesPerPixel")?
            .unwrap_or(1);
        let frames = self
            .int(tags::NUMBER_OF_FRAMES, "NumberOfFrames")?
            .unwrap_or(1);
        if bits_allocated != 8 && bits_allocated != 16 {
            return Err(Error::format(
                path,
                format!("BitsAllocated is {bits_allocated}; expected 8 or 16"),
            ));
        }
        if !(1..=bits_allocated).contains(&bits_stored) {
            return Err(Error::format(
                path,
                format!("BitsStored is {bits_stored}; expected 1 to {bits_allocated}"),
            ));
        }
        if samples != 1 || frames != 1 {
            return Err(Error::format(
                path,
                format!("slice has {samples} samples per pixel and {frames} frames; expected a single-frame grey image"),
            ));
        }
        if rows <= 0 || cols <= 0 {
            return Err(Error::format(
                path,
                format!("image is {cols}x{rows}; expected positive Rows and Columns"),
            ));
        }
        Ok((
            rows as usize,
            cols as usize,
            bits_allocated as u16,
            bits_stored as u16,
            signed,
        ))
    }
}

/// Parses one file; `None` when it is not DICOM (and not named `.dcm`) or holds no image.
fn read_slice(path: &Path) -> Result<Option<Slice>> {
    let Some(obj) = parse(path)? else {
        return Ok(None);
    };
    let ts = obj.meta().transfer_syntax();
    let Some(&(_, _, big_endian)) = SUPPORTED.iter().find(|(uid, _, _)| *uid == ts) else {
        return Err(Error::format(
            path,
            format!(
                "transfer syntax {ts} is compressed or unsupported; expected an uncompressed one \
                 (1.2.840.10008.1.2, 1.2.840.10008.1.2.1 or 1.2.840.10008.1.2.2)"
            ),
        ));
    };
    let Some(pixel_data) = element(&obj, tags::PIXEL_DATA) else {
        return Ok(None);
    };
    let f = Fields { obj: &obj, path };
    let (rows, cols, bits_allocated, bits_stored, signed) = f.pixel_layout()?;
    let expected = rows * cols * bits_allocated as usize / 8;
    // OW data was decoded to native (little-endian) words; OB data keeps the file's byte order.
    let mut pixels = pixel_data
        .to_bytes()
        .map_err(|_| {
            Error::format(
                path,
                "PixelData is encapsulated; expected uncompressed native pixels",
            )
        })?
        .into_owned();
    if big_endian && bits_allocated == 16 && pixel_data.vr().to_string() == "OB" {
        pixels.chunks_exact_mut(2).for_each(|c| c.swap(0, 1));
    }
    if pixels.len() < expected {
        return Err(Error::format(
            path,
            format!("PixelData holds {} bytes but {cols}x{rows} pixels of {bits_allocated} bits need {expected}", pixels.len()),
        ));
    }
    pixels.truncate(expected);

    let position = f
        .floats(tags::IMAGE_POSITION_PATIENT, "ImagePositionPatient", 3)?
        .map(|v| [v[0], v[1], v[2]]);
    let orientation = f
        .floats(
            tags::IMAGE_ORIENTATION_PATIENT,
            "ImageOrientationPatient",
            6,
        )?
        .map(|v| [v[0], v[1], v[2], v[3], v[4], v[5]]);
    let pixel_spacing = f
        .floats(tags::PIXEL_SPACING, "PixelSpacing", 2)?
        .map(|v| [v[0].abs(), v[1].abs()])
        .filter(|s| s.iter().all(|x| x.is_finite() && *x > 0.0));
    let slice_spacing = [tags::SPACING_BETWEEN_SLICES, tags::SLICE_THICKNESS]
        .into_iter()
        .filter_map(|t| element(&obj, t)?.to_float64().ok())
        .map(f64::abs)
        .find(|s| s.is_finite() && *s > 0.0);
    let slope = f
        .floats(tags::RESCALE_SLOPE, "RescaleSlope", 1)?
        .map_or(1.0, |v| v[0]);
    let intercept = f
        .floats(tags::RESCALE_INTERCEPT, "RescaleIntercept", 1)?
        .map_or(0.0, |v| v[0]);
    if !(slope.is_finite() && intercept.is_finite()) {
        return Err(Error::format(
            path,
            "RescaleSlope or RescaleIntercept is not finite; expected finite numbers",
        ));
    }
    let series = element(&obj, tags::SERIES_INSTANCE_UID)
        .and_then(|e| e.to_str().ok())
        .map(|s| s.trim_end_matches(['\0', ' ']).to_string());

    Ok(Some(Slice {
        file: path.to_path_buf(),
        series,
        rows,
        cols,
        bits_allocated,
        bits_stored,
        signed,
        position,
        orientation,
        instance: f.int(tags::INSTANCE_NUMBER, "InstanceNumber")?,
        pixel_spacing,
        slice_spacing,
        slope,
        intercept,
        pixels,
    }))
}

/// The element with `tag` if present and non-empty.
fn element(obj: &DefaultDicomObject, tag: Tag) -> Option<&InMemElement> {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .filter(|e| e.to_bytes().map_or(true, |b| !b.is_empty()))
}

/// Clears (unsigned) or sign-extends (signed) the bits above `BitsStored`, which DICOM says to ignore.
fn mask_unused_bits(data: &mut VoxelData, bits_stored: u16) {
    match data {
        VoxelData::U16(v) if bits_stored < 16 => {
            let mask = (1u16 << bits_stored) - 1;
            v.par_iter_mut().for_each(|x| *x &= mask);
        }
        VoxelData::I16(v) if bits_stored < 16 => {
            let shift = 16 - bits_stored as u32;
            v.par_iter_mut().for_each(|x| *x = (*x << shift) >> shift);
        }
        _ => {}
    }
}

/// Applies each slice's `value * slope + intercept`. The result is u16 or i16 when every rescaled
/// value is a whole number in that type's range (the common CT case), f32 otherwise.
fn rescale(raw: &VoxelData, params: &[(f64, f64)], slice_len: usize) -> VoxelData {
    let value = |i: usize| {
        let (slope, intercept) = params[i / slice_len];
        raw.get_f64(i) * slope + intercept
    };
    let (lo, hi, whole) = (0..raw.len())
        .into_par_iter()
        .map(|i| {
            let v = value(i);
            (v, v, v.fract() == 0.0)
        })
        .reduce(
            || (f64::INFINITY, f64::NEG_INFINITY, true),
            |a, b| (a.0.min(b.0), a.1.max(b.1), a.2 && b.2),
        );
    let all = 0..raw.len();
    if whole && lo >= 0.0 && hi <= u16::MAX as f64 {
        VoxelData::U16(all.into_par_iter().map(|i| value(i) as u16).collect())
    } else if whole && lo >= i16::MIN as f64 && hi <= i16::MAX as f64 {
        VoxelData::I16(all.into_par_iter().map(|i| value(i) as i16).collect())
    } else {
        VoxelData::F32(all.into_par_iter().map(|i| value(i) as f32).collect())
    }
}
