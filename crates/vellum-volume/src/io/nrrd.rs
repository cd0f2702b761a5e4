//! NRRD (teem) files: attached (`.nrrd`) and detached (`.nhdr` + `data file:`) headers, raw and
//! gzip encodings. This is the format vellum writes, because it is a plain-text header that
//! every volume tool reads and it keeps the spacing. Only 3D grids are read (4D with a leading
//! axis of size 1 is accepted), and only the encodings vellum can write, plus raw.

use std::collections::HashMap;
use std::fs::File;
use std::io::{self, BufRead, BufReader, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use flate2::write::GzEncoder;

use super::{
    build, decode, decoder, parse_list, read_error, read_payload, voxel_count, Compression,
    FileType,
};
use crate::geometry::{Geometry, Space};
use crate::{Volume, VoxelType};
use vellum_error::{Error, Result};

/// Longest header vellum reads, so a binary file with no blank line is not read whole as a header.
const MAX_HEADER_BYTES: u64 = 1 << 20;

/// Reads an attached or detached NRRD file.
pub(super) fn read(path: &Path) -> Result<Volume> {
    let file = super::open_regular(path)?;
    let mut reader = BufReader::new(file);
    let fields = read_header(path, &mut reader)?;
    let field = |k: &str| fields.get(k).map(String::as_str);
    let required = |k: &str| {
        field(k)
            .ok_or_else(|| Error::format(path, format!("header has no '{k}' field; expected one")))
    };

    let ty = file_type(path, required("type")?)?;
    let dimension: usize = required("dimension")?
        .parse()
        .map_err(|_| Error::format(path, "field 'dimension' is not a whole number; expected 3"))?;
    let mut sizes: Vec<usize> = parse_list(path, "sizes", required("sizes")?, dimension)?;
    // Index of the first of the three spatial axes.
    let first = match (dimension, sizes.first()) {
        (3, _) => 0,
        (4, Some(1)) => 1,
        _ => {
            return Err(Error::format(
                path,
                format!("dimension is {dimension} with sizes {sizes:?}; expected 3 (or 4 with a leading axis of size 1)"),
            ))
        }
    };
    sizes.drain(..first);
    let dims = [sizes[0], sizes[1], sizes[2]];
    let n = voxel_count(path, dims)?;

    let spacing = spacing(path, &fields, dimension, first)?;
    let big_endian = match field("endian") {
        Some("little") => false,
        Some("big") => true,
        None if ty.size() == 1 => false,
        Some(other) => {
            return Err(Error::format(
                path,
                format!("endian is '{other}'; expected 'little' or 'big'"),
            ))
        }
        None => {
            return Err(Error::format(
                path,
                "header has no 'endian' field; expected 'little' or 'big' for multi-byte types",
            ))
        }
    };
    let compression = match required("encoding")? {
        "raw" => Compression::None,
        "gzip" | "gz" => Compression::Gzip,
        other => {
            return Err(Error::format(
                path,
                format!("encoding '{other}' is not supported; expected raw, gzip or gz"),
            ))
        }
    };
    let line_skip: u64 = parse_skip(path, &fields, "lineskip")?
        .try_into()
        .map_err(|_| {
            Error::format(
                path,
                "field 'line skip' is negative; expected a whole number of lines of zero or more",
            )
        })?;
    let byte_skip = parse_skip(path, &fields, "byteskip")?;
    if byte_skip < -1 || (byte_skip == -1 && compression != Compression::None) {
        return Err(Error::format(
            path,
            format!("byte skip is {byte_skip}; expected zero or more, or -1 with raw encoding"),
        ));
    }

    let expected = n * ty.size();
    let (data_path, mut data) = match field("datafile") {
        Some(name) => {
            let data_path = data_file(path, name)?;
            let file = super::open_regular(&data_path)?;
            (data_path, BufReader::new(file))
        }
        None => (path.to_path_buf(), reader),
    };
    for _ in 0..line_skip {
        data.read_until(b'\n', &mut Vec::new())
            .map_err(|e| Error::io(&data_path, e))?;
    }
    let bytes = if byte_skip == -1 {
        // The voxels are the last `expected` bytes of the file.
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
        read_payload(&data_path, &mut data, compression, 0, expected)?
    } else {
        read_payload(
            &data_path,
            &mut decoder(data, compression),
            compression,
            byte_skip as u64,
            expected,
        )?
    };
    let geometry = geometry(path, &fields, first)?;
    build(path, dims, spacing, decode(path, ty, big_endian, &bytes)?)?
        .with_geometry(geometry)
        .map_err(|e| Error::format(path, e.to_string()))
}

/// The geometry from `space`, `space directions` and `space origin`, in LPS. Without `space`
/// (or with one that is not a 3D anatomical space) the directions and origin are kept but the
/// orientation is unknown; with `spacings` only, the identity.
fn geometry(path: &Path, fields: &HashMap<String, String>, first: usize) -> Result<Geometry> {
    let space = fields
        .get("space")
        .map(|s| s.trim().to_lowercase().replace(' ', ""));
    // Sign flips from the file's space to LPS.
    let (flip, anatomical) = match space.as_deref() {
        Some("left-posterior-superior" | "lps") => ([1.0, 1.0, 1.0], true),
        Some("right-anterior-superior" | "ras") => ([-1.0, -1.0, 1.0], true),
        Some("left-anterior-superior" | "las") => ([1.0, -1.0, 1.0], true),
        _ => ([1.0; 3], false),
    };
    let to_lps = |v: &[f64]| -> [f64; 3] { std::array::from_fn(|r| flip[r] * v[r]) };
    let axes = match fields.get("spacedirections") {
        Some(dirs) => {
            let vectors = parse_directions(path, dirs)?;
            let mut axes = [[0.0; 3]; 3];
            for (a, v) in axes.iter_mut().zip(vectors.iter().skip(first)) {
                let v = v.as_ref().filter(|v| v.len() == 3).ok_or_else(|| {
                    Error::format(
                        path,
                        "space directions needs a 3-vector for every spatial axis",
                    )
                })?;
                *a = to_lps(v);
            }
            axes
        }
        None => crate::geometry::IDENTITY,
    };
    let origin = match fields.get("spaceorigin") {
        Some(o) => {
            let v = parse_directions(path, o)?;
            match v.as_slice() {
                [Some(p)] if p.len() == 3 => to_lps(p),
                _ => {
                    return Err(Error::format(
                        path,
                        format!("space origin '{o}' is malformed; expected '(x,y,z)'"),
                    ))
                }
            }
        }
        None => [0.0; 3],
    };
    let mut g = Geometry::lps(origin, axes).map_err(|e| Error::format(path, e.to_string()))?;
    if !anatomical {
        g.space = Space::Unknown;
    }
    Ok(g)
}

/// Reads the magic line and `key: value` fields up to a blank line (attached) or the end of the
/// file (detached). Keys are lower-cased with spaces removed, so `data file` and `datafile` agree.
fn read_header(path: &Path, reader: &mut BufReader<File>) -> Result<HashMap<String, String>> {
    let mut fields = HashMap::new();
    let mut line = Vec::new();
    let mut total = 0u64;
    let mut first = true;
    loop {
        line.clear();
        let read = (&mut *reader)
            .take(MAX_HEADER_BYTES - total)
            .read_until(b'\n', &mut line)
            .map_err(|e| read_error(path, Compression::None, e))?;
        total += read as u64;
        if read == 0 {
            break;
        }
        if total >= MAX_HEADER_BYTES {
            return Err(Error::format(
                path,
                "header has no end within 1 MiB; expected a blank line after the fields",
            ));
        }
        let text = String::from_utf8_lossy(&line);
        let text = text.trim_end_matches(['\n', '\r']);
        if first {
            if !text.starts_with("NRRD000") {
                return Err(Error::format(
                    path,
                    "file does not start with 'NRRD000'; expected a NRRD header",
                ));
            }
            first = false;
            continue;
        }
        if text.is_empty() {
            break;
        }
        if text.starts_with('#') || text.contains(":=") {
            continue;
        }
        let Some((key, value)) = text.split_once(':') else {
            return Err(Error::format(
                path,
                format!("header line '{text}' has no ':'; expected 'field: value'"),
            ));
        };
        fields.insert(
            key.to_lowercase().replace(' ', ""),
            value.trim().to_string(),
        );
    }
    if first {
        return Err(Error::format(path, "file is empty; expected a NRRD header"));
    }
    Ok(fields)
}

/// Maps NRRD type names (all of teem's spellings) to file types.
fn file_type(path: &Path, name: &str) -> Result<FileType> {
    Ok(match name {
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => FileType::U8,
        "signed char" | "int8" | "int8_t" => FileType::I8,
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => FileType::U16,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => FileType::I16,
        "uint" | "unsigned int" | "uint32" | "uint32_t" => FileType::U32,
        "int" | "signed int" | "int32" | "int32_t" => FileType::I32,
        "float" => FileType::F32,
        "double" => FileType::F64,
        other => {
            return Err(Error::format(
                path,
                format!(
                    "type '{other}' is not supported; expected one of int8, uint8, int16, uint16, int32, uint32, float, double"
                ),
            ))
        }
    })
}

/// Spacing of the three spatial axes: the length of each `space directions` vector, else
/// `spacings`, else 1. Unknown (`nan`) spacings become 1.
fn spacing(
    path: &Path,
    fields: &HashMap<String, String>,
    dimension: usize,
    first: usize,
) -> Result<[f64; 3]> {
    let mut spacing = [1.0; 3];
    if let Some(dirs) = fields.get("spacedirections") {
        let vectors = parse_directions(path, dirs)?;
        if vectors.len() != dimension {
            return Err(Error::format(
                path,
                format!(
                    "space directions has {} entries; expected {dimension}",
                    vectors.len()
                ),
            ));
        }
        for (s, v) in spacing.iter_mut().zip(&vectors[first..]) {
            let v = v.as_ref().ok_or_else(|| {
                Error::format(
                    path,
                    "space directions gives 'none' for a spatial axis; expected a vector",
                )
            })?;
            *s = v.iter().map(|c| c * c).sum::<f64>().sqrt();
        }
    } else if let Some(value) = fields.get("spacings") {
        let values: Vec<f64> = parse_list(path, "spacings", value, dimension)?;
        for (s, v) in spacing.iter_mut().zip(&values[first..]) {
            *s = if v.is_nan() { 1.0 } else { v.abs() };
        }
    }
    Ok(spacing)
}

/// Parses `(a,b,c) none (d,e,f) ...` into one optional vector per axis.
fn parse_directions(path: &Path, text: &str) -> Result<Vec<Option<Vec<f64>>>> {
    let bad = || {
        Error::format(
            path,
            format!(
                "space directions '{text}' is malformed; expected '(x,y,z)' or 'none' per axis"
            ),
        )
    };
    let mut out = Vec::new();
    let mut rest = text.trim_start();
    while !rest.is_empty() {
        if let Some(r) = rest.strip_prefix("none") {
            out.push(None);
            rest = r;
        } else if let Some(r) = rest.strip_prefix('(') {
            let (inner, r) = r.split_once(')').ok_or_else(bad)?;
            let v: Option<Vec<f64>> = inner.split(',').map(|c| c.trim().parse().ok()).collect();
            out.push(Some(v.ok_or_else(bad)?));
            rest = r;
        } else {
            return Err(bad());
        }
        rest = rest.trim_start();
    }
    Ok(out)
}

fn parse_skip(path: &Path, fields: &HashMap<String, String>, key: &str) -> Result<i64> {
    match fields.get(key) {
        None => Ok(0),
        Some(v) => v.parse().map_err(|_| {
            Error::format(
                path,
                format!("field '{key}' is '{v}'; expected a whole number"),
            )
        }),
    }
}

/// Resolves a single detached data file relative to the header's folder.
fn data_file(path: &Path, name: &str) -> Result<PathBuf> {
    if name.starts_with("LIST") || name.split_whitespace().count() > 1 {
        return Err(Error::format(
            path,
            format!("data file '{name}' names several files; expected a single data file"),
        ));
    }
    Ok(path.parent().unwrap_or(Path::new(".")).join(name))
}

/// Writes `volume` as an attached-header, gzip-encoded NRRD, through `output::write_atomic`: a
/// failure never leaves a partial file at `path`, and inside a command's transaction the file
/// appears only with the command's other outputs.
pub fn write_nrrd(path: &Path, volume: &Volume) -> Result<()> {
    crate::output::check_extension(path, &["nrrd"], "an NRRD volume")?;
    crate::output::write_atomic(path, |w| write_to(w, volume))
}

fn write_to(out: &mut impl Write, volume: &Volume) -> io::Result<()> {
    let type_name = match volume.voxel_type() {
        VoxelType::U8 => "uint8",
        VoxelType::U16 => "uint16",
        VoxelType::I16 => "int16",
        VoxelType::F32 => "float",
    };
    let [x, y, z] = volume.dims;
    let g = &volume.geometry;
    // Space directions are the axis directions scaled by the spacing; `{}` prints the shortest
    // decimal that parses back to the same f64, so geometry round-trips exactly.
    let dir = |c: usize| {
        let a = g.axis(c).map(|v| v * volume.spacing[c]);
        format!("({},{},{})", a[0], a[1], a[2])
    };
    let [ox, oy, oz] = g.origin;
    // A volume with no known anatomical orientation says only how many space axes there are.
    let space = match g.space {
        Space::Lps => "space: left-posterior-superior",
        Space::Unknown => "space dimension: 3",
    };
    write!(
        out,
        "NRRD0004\n# written by vellum\ntype: {type_name}\ndimension: 3\n{space}\n\
         sizes: {x} {y} {z}\nspace directions: {} {} {}\nspace origin: ({ox},{oy},{oz})\n\
         endian: little\nencoding: gzip\n\n",
        dir(0),
        dir(1),
        dir(2)
    )?;
    let mut gz = GzEncoder::new(out, flate2::Compression::default());
    gz.write_all(volume.data.as_bytes())?;
    gz.finish()?;
    Ok(())
}
