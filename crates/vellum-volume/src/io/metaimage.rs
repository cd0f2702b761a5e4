//! MetaImage (ITK) files: `.mhd` headers with a separate `.raw`/`.zraw` data file, and `.mha`
//! files whose data follows the header (`ElementDataFile = LOCAL`). ITK writes zlib streams for
//! `CompressedData = True`; a gzip stream is also accepted, by its magic bytes.

use std::io::{BufRead, BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use super::{build, decode, decoder, parse_list, read_payload, voxel_count, Compression, FileType};
use crate::geometry::{Geometry, Space};
use crate::Volume;
use vellum_error::{Error, Result};

/// Longest header vellum reads before giving up on finding `ElementDataFile`.
const MAX_HEADER_BYTES: u64 = 1 << 20;

/// Reads a `.mhd` or `.mha` file.
pub(super) fn read(path: &Path) -> Result<Volume> {
    let file = super::open_regular(path)?;
    let mut reader = BufReader::new(file);
    let mut fields: Vec<(String, String)> = Vec::new();
    let mut line = Vec::new();
    let mut total = 0u64;
    // ElementDataFile is always the last field; the data of a LOCAL file starts on the next line.
    while !fields.iter().any(|(k, _)| k == "elementdatafile") {
        line.clear();
        let read = (&mut reader)
            .take(MAX_HEADER_BYTES - total)
            .read_until(b'\n', &mut line)
            .map_err(|e| Error::io(path, e))?;
        total += read as u64;
        if read == 0 || total >= MAX_HEADER_BYTES {
            return Err(Error::format(
                path,
                "header has no ElementDataFile field; expected one as its last line",
            ));
        }
        let text = String::from_utf8_lossy(&line);
        let text = text.trim();
        if text.is_empty() {
            continue;
        }
        let Some((key, value)) = text.split_once('=') else {
            return Err(Error::format(
                path,
                format!("header line '{text}' has no '='; expected 'Key = Value'"),
            ));
        };
        fields.push((key.trim().to_lowercase(), value.trim().to_string()));
    }
    let field = |k: &str| {
        fields
            .iter()
            .find(|(key, _)| key == k)
            .map(|(_, v)| v.as_str())
    };
    let required = |k: &str, name: &str| {
        field(k)
            .ok_or_else(|| Error::format(path, format!("header has no {name} field; expected one")))
    };
    let is_true = |k: &str| field(k).is_some_and(|v| v.eq_ignore_ascii_case("true"));

    let ndims = required("ndims", "NDims")?;
    if ndims != "3" {
        return Err(Error::format(path, format!("NDims is {ndims}; expected 3")));
    }
    let d: Vec<usize> = parse_list(path, "DimSize", required("dimsize", "DimSize")?, 3)?;
    let dims = [d[0], d[1], d[2]];
    let n = voxel_count(path, dims)?;
    let spacing = match field("elementspacing").or(field("elementsize")) {
        Some(v) => {
            let s: Vec<f64> = parse_list(path, "ElementSpacing", v, 3)?;
            [s[0].abs(), s[1].abs(), s[2].abs()]
        }
        None => [1.0; 3],
    };
    if let Some(c) = field("elementnumberofchannels").filter(|c| *c != "1") {
        return Err(Error::format(
            path,
            format!("ElementNumberOfChannels is {c}; expected 1 (a scalar volume)"),
        ));
    }
    if field("binarydata").is_some_and(|v| v.eq_ignore_ascii_case("false")) {
        return Err(Error::format(
            path,
            "BinaryData is False (ASCII voxels), which is not supported; expected binary data",
        ));
    }
    let ty = file_type(path, required("elementtype", "ElementType")?)?;
    let big_endian = is_true("elementbyteordermsb") || is_true("binarydatabyteordermsb");
    let compressed = is_true("compresseddata");
    let header_size: i64 = match field("headersize") {
        Some(v) => v.parse().map_err(|_| {
            Error::format(
                path,
                format!("HeaderSize is '{v}'; expected a whole number"),
            )
        })?,
        None => 0,
    };
    if header_size < -1 || (header_size == -1 && compressed) {
        return Err(Error::format(
            path,
            format!(
                "HeaderSize is {header_size}; expected zero or more, or -1 for uncompressed data"
            ),
        ));
    }

    let name = required("elementdatafile", "ElementDataFile")?;
    let (data_path, mut data) = if name.eq_ignore_ascii_case("local") {
        (path.to_path_buf(), reader)
    } else if name.starts_with("LIST") || name.contains('%') || name.split_whitespace().count() > 1
    {
        return Err(Error::format(
            path,
            format!("ElementDataFile '{name}' names several files; expected a single file"),
        ));
    } else {
        let data_path = path.parent().unwrap_or(Path::new(".")).join(name);
        let file = super::open_regular(&data_path)?;
        (data_path, BufReader::new(file))
    };
    let expected = n * ty.size();
    let mut skip = 0;
    if header_size == -1 {
        let len = data
            .get_ref()
            .metadata()
            .map_err(|e| Error::io(&data_path, e))?
            .len();
        let start = len.checked_sub(expected as u64).ok_or_else(|| {
            Error::format(
                &data_path,
                format!("data holds {len} bytes but the header needs {expected}"),
            )
        })?;
        data.seek(SeekFrom::Start(start))
            .map_err(|e| Error::io(&data_path, e))?;
    } else if compressed {
        // HeaderSize counts file bytes before the compressed stream.
        data.seek_relative(header_size)
            .map_err(|e| Error::io(&data_path, e))?;
    } else {
        skip = header_size as u64;
    }
    let compression = match (compressed, data.fill_buf()) {
        (false, _) => Compression::None,
        (true, Ok([0x1f, 0x8b, ..])) => Compression::Gzip,
        (true, _) => Compression::Zlib,
    };
    let bytes = read_payload(
        &data_path,
        &mut decoder(data, compression),
        compression,
        skip,
        expected,
    )?;
    let geometry = geometry(path, &fields)?;
    build(path, dims, spacing, decode(path, ty, big_endian, &bytes)?)?
        .with_geometry(geometry)
        .map_err(|e| Error::format(path, e.to_string()))
}

/// The geometry from `TransformMatrix` (or `Orientation`/`Rotation`; axis i's direction is the
/// i-th triple, as ITK reads it) and `Offset` (or `Origin`/`Position`). MetaImage geometry is in
/// LPS, as ITK writes it; a header with neither field nor `AnatomicalOrientation` has no known
/// orientation.
fn geometry(path: &Path, fields: &[(String, String)]) -> Result<Geometry> {
    let field = |k: &str| {
        fields
            .iter()
            .find(|(key, _)| key == k)
            .map(|(_, v)| v.as_str())
    };
    let matrix = ["transformmatrix", "orientation", "rotation"]
        .iter()
        .find_map(|k| field(k));
    let offset = ["offset", "origin", "position"]
        .iter()
        .find_map(|k| field(k));
    let axes = match matrix {
        Some(m) => {
            let v: Vec<f64> = parse_list(path, "TransformMatrix", m, 9)?;
            [0, 1, 2].map(|i| [v[3 * i], v[3 * i + 1], v[3 * i + 2]])
        }
        None => crate::geometry::IDENTITY,
    };
    let origin = match offset {
        Some(o) => {
            let v: Vec<f64> = parse_list(path, "Offset", o, 3)?;
            [v[0], v[1], v[2]]
        }
        None => [0.0; 3],
    };
    let mut g = Geometry::lps(origin, axes).map_err(|e| Error::format(path, e.to_string()))?;
    if matrix.is_none() && offset.is_none() && field("anatomicalorientation").is_none() {
        g.space = Space::Unknown;
    }
    Ok(g)
}

fn file_type(path: &Path, name: &str) -> Result<FileType> {
    Ok(match name {
        "MET_UCHAR" => FileType::U8,
        "MET_CHAR" => FileType::I8,
        "MET_USHORT" => FileType::U16,
        "MET_SHORT" => FileType::I16,
        "MET_UINT" => FileType::U32,
        "MET_INT" => FileType::I32,
        "MET_FLOAT" => FileType::F32,
        "MET_DOUBLE" => FileType::F64,
        other => {
            return Err(Error::format(
                path,
                format!(
                    "ElementType {other} is not supported; expected one of MET_UCHAR, MET_CHAR, MET_USHORT, \
                     MET_SHORT, MET_UINT, MET_INT, MET_FLOAT, MET_DOUBLE"
                ),
            ))
        }
    })
}
