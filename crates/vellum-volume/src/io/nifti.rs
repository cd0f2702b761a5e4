//! NIfTI-1 single files (`.nii`, `.nii.gz`), the common currency of neuroimaging. Voxels stay in
//! file order (as the copies in `shared/data/volumes` do); spacing comes from pixdim (taken as
//! millimetres whatever `xyzt_units` says), intensity scaling is applied, and the geometry comes
//! from the sform when `sform_code > 0`, else the qform (quaternion) when `qform_code > 0`, else
//! none (spacing only), converted from NIfTI's RAS to LPS.

use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;

use rayon::prelude::*;

use super::{build, decode, decoder, read_error, read_payload, voxel_count, Compression, FileType};
use crate::geometry::{ras_to_lps, Geometry, Space};
use crate::{Volume, VoxelData, VoxelType};
use vellum_error::{Error, Result};

const HEADER_BYTES: usize = 348;

/// Reads a NIfTI-1 file, gzipped or not (decided by the gzip magic, not the name).
pub(super) fn read(path: &Path) -> Result<Volume> {
    let file = super::open_regular(path)?;
    let mut buffered = BufReader::new(file);
    let head = buffered.fill_buf().map_err(|e| Error::io(path, e))?;
    let compression = if head.starts_with(&[0x1f, 0x8b]) {
        Compression::Gzip
    } else {
        Compression::None
    };
    let mut src = decoder(buffered, compression);

    let mut head = Vec::with_capacity(HEADER_BYTES);
    (&mut src)
        .take(HEADER_BYTES as u64)
        .read_to_end(&mut head)
        .map_err(|e| read_error(path, compression, e))?;
    let Ok(bytes) = <[u8; HEADER_BYTES]>::try_from(head) else {
        return Err(Error::format(
            path,
            "file ends inside the 348-byte NIfTI-1 header; expected a complete header",
        ));
    };
    let h = Header {
        big_endian: byte_order(path, &bytes)?,
        bytes,
    };
    let dims = h.dims(path)?;
    let n = voxel_count(path, dims)?;
    let ty = file_type(path, h.i16_at(70))?;
    let pixdim: [f32; 4] = std::array::from_fn(|i| h.f32_at(76 + 4 * i));
    let spacing = [1, 2, 3].map(|i| match pixdim[i].abs() as f64 {
        s if s.is_finite() && s > 0.0 => s,
        _ => 1.0,
    });
    let geometry = h.geometry(path, &pixdim)?;
    let vox_offset = h.f32_at(108);
    if !(vox_offset >= HEADER_BYTES as f32 && vox_offset.fract() == 0.0) {
        return Err(Error::format(
            path,
            format!("vox_offset is {vox_offset}; expected a whole number of at least 348"),
        ));
    }
    let (slope, inter) = (h.f32_at(112), h.f32_at(116));

    let skip = vox_offset as u64 - HEADER_BYTES as u64;
    let bytes = read_payload(path, &mut src, compression, skip, n * ty.size())?;
    let mut data = decode(path, ty, h.big_endian, &bytes)?;
    if slope != 0.0 && slope.is_finite() && !(slope == 1.0 && inter == 0.0) {
        let inter = if inter.is_finite() { inter as f64 } else { 0.0 };
        let len = data.len();
        data = VoxelData::F32(
            (0..len)
                .into_par_iter()
                .map(|i| (data.get_f64(i) * slope as f64 + inter) as f32)
                .collect(),
        );
    }
    let v = build(path, dims, spacing, data)?;
    match geometry {
        Some(g) => v
            .with_geometry(g)
            .map_err(|e| Error::format(path, e.to_string())),
        None => Ok(v),
    }
}

/// The byte order of a NIfTI-1 header (true: big-endian), from `sizeof_hdr`, once the magic
/// says it is a single-file NIfTI-1.
fn byte_order(path: &Path, h: &[u8; HEADER_BYTES]) -> Result<bool> {
    let le = i32::from_le_bytes([h[0], h[1], h[2], h[3]]);
    let be = i32::from_be_bytes([h[0], h[1], h[2], h[3]]);
    let big_endian = match (le, be) {
        (348, _) => false,
        (_, 348) => true,
        (540, _) | (_, 540) => {
            return Err(Error::format(
                path,
                "file is NIfTI-2, which is not supported; expected NIfTI-1 (sizeof_hdr 348)",
            ))
        }
        _ => {
            return Err(Error::format(
                path,
                format!("sizeof_hdr is {le}; expected 348 for a NIfTI-1 file"),
            ))
        }
    };
    match &h[344..348] {
        b"n+1\0" => Ok(big_endian),
        b"ni1\0" => Err(Error::format(
            path,
            "file is half of a NIfTI-1 .hdr/.img pair, which is not supported; expected a single .nii or .nii.gz file",
        )),
        m => Err(Error::format(
            path,
            format!("magic is {:?}; expected \"n+1\" (a single-file NIfTI-1)", String::from_utf8_lossy(m)),
        )),
    }
}

/// A NIfTI-1 header and its byte order.
struct Header {
    bytes: [u8; HEADER_BYTES],
    big_endian: bool,
}

impl Header {
    fn i16_at(&self, o: usize) -> i16 {
        let b = [self.bytes[o], self.bytes[o + 1]];
        match self.big_endian {
            true => i16::from_be_bytes(b),
            false => i16::from_le_bytes(b),
        }
    }

    fn f32_at(&self, o: usize) -> f32 {
        let b = [
            self.bytes[o],
            self.bytes[o + 1],
            self.bytes[o + 2],
            self.bytes[o + 3],
        ];
        match self.big_endian {
            true => f32::from_be_bytes(b),
            false => f32::from_le_bytes(b),
        }
    }

    /// The volume's size: `dim[1..4]` of a 3D volume (any further sizes 1).
    fn dims(&self, path: &Path) -> Result<[usize; 3]> {
        let dim: Vec<i16> = (0..8).map(|i| self.i16_at(40 + 2 * i)).collect();
        if !(3..=7).contains(&dim[0]) {
            return Err(Error::format(
                path,
                format!(
                    "dim[0] is {}; expected a 3D volume (3 to 7 with extra sizes of 1)",
                    dim[0]
                ),
            ));
        }
        if let Some(i) = (4..=dim[0] as usize).find(|&i| dim[i] != 1) {
            return Err(Error::format(
                path,
                format!("dim[{i}] is {}; expected a single 3D volume (every size past the third equal to 1)", dim[i]),
            ));
        }
        if dim[1..4].iter().any(|&d| d < 0) {
            return Err(Error::format(
                path,
                format!(
                    "dims {:?} are negative; expected positive sizes",
                    &dim[1..4]
                ),
            ));
        }
        Ok([dim[1] as usize, dim[2] as usize, dim[3] as usize])
    }

    /// The orientation in LPS: the sform when its code is set, else the qform, else none.
    fn geometry(&self, path: &Path, pixdim: &[f32; 4]) -> Result<Option<Geometry>> {
        let f = |o: usize| self.f32_at(o) as f64;
        let (qform_code, sform_code) = (self.i16_at(252), self.i16_at(254));
        let geometry = if sform_code > 0 {
            let row = |o: usize| -> [f64; 4] { std::array::from_fn(|k| f(o + 4 * k)) };
            let (x, y, z) = (row(280), row(296), row(312));
            let axes = [0, 1, 2].map(|c| ras_to_lps([x[c], y[c], z[c]]));
            Some(Geometry::lps(ras_to_lps([x[3], y[3], z[3]]), axes))
        } else if qform_code > 0 {
            let r = quaternion_matrix([f(256), f(260), f(264)]);
            let qfac = if pixdim[0] < 0.0 { -1.0 } else { 1.0 };
            let axes = [0, 1, 2].map(|k| {
                let s = if k == 2 { qfac } else { 1.0 };
                ras_to_lps([s * r[0][k], s * r[1][k], s * r[2][k]])
            });
            Some(Geometry::lps(ras_to_lps([f(268), f(272), f(276)]), axes))
        } else {
            if pixdim[1..4].iter().any(|&p| p < 0.0) {
                return Err(Error::format(
                    path,
                    format!(
                        "pixdims {:?} are negative while both qform_code and sform_code are 0; expected positive voxel sizes when no orientation is given",
                        &pixdim[1..4]
                    ),
                ));
            }
            None
        };
        geometry
            .transpose()
            .map_err(|e| Error::format(path, format!("the orientation is unusable: {e}")))
    }
}

fn file_type(path: &Path, datatype: i16) -> Result<FileType> {
    Ok(match datatype {
        2 => FileType::U8,
        4 => FileType::I16,
        8 => FileType::I32,
        16 => FileType::F32,
        64 => FileType::F64,
        256 => FileType::I8,
        512 => FileType::U16,
        768 => FileType::U32,
        other => {
            let name = match other {
                1 => "binary",
                32 => "complex64",
                128 => "RGB24",
                1024 => "int64",
                1280 => "uint64",
                1536 => "float128",
                1792 => "complex128",
                2048 => "complex256",
                2304 => "RGBA32",
                _ => "unknown",
            };
            return Err(Error::format(
                path,
                format!(
                    "datatype {other} ({name}) is not supported; expected one of 2 (uint8), 4 (int16), 8 (int32), \
                     16 (float32), 64 (float64), 256 (int8), 512 (uint16), 768 (uint32)"
                ),
            ));
        }
    })
}

/// Writes `volume` as a single-file NIfTI-1 (`.nii`, or gzip-compressed `.nii.gz`), little endian,
/// through `output::write_atomic`.
///
/// Geometry known in LPS is written as both an sform (the exact affine) and a qform (the
/// quaternion, with qfac for a left-handed frame), converted to NIfTI's RAS, both with code 1
/// (scanner). A volume with no anatomical orientation gets codes 0 and its spacing only: NIfTI has
/// no way to say "an origin but no orientation", and claiming one would be a lie.
pub(crate) fn write_nifti(path: &Path, volume: &Volume) -> Result<()> {
    crate::output::check_extension(path, &["nii", "nii.gz"], "a NIfTI-1 volume")?;
    if let Some(&d) = volume.dims.iter().find(|&&d| d > i16::MAX as usize) {
        return Err(Error::Invalid(format!(
            "{}: a dimension of {d} voxels does not fit NIfTI-1's 16-bit sizes; expected at most {} per axis (write .nrrd instead)",
            path.display(),
            i16::MAX
        )));
    }
    if volume.geometry.space == Space::Unknown && volume.geometry != Geometry::default() {
        log::warn!(
            "{}: the volume's origin and directions are not in an anatomical space, so the NIfTI file keeps only its spacing",
            path.display()
        );
    }
    let header = header(volume);
    let gzip = path.to_string_lossy().to_lowercase().ends_with(".gz");
    crate::output::write_atomic(path, |w| {
        if gzip {
            let mut gz = flate2::write::GzEncoder::new(w, flate2::Compression::default());
            gz.write_all(&header)?;
            gz.write_all(volume.data.as_bytes())?;
            gz.finish()?;
        } else {
            w.write_all(&header)?;
            w.write_all(volume.data.as_bytes())?;
        }
        Ok(())
    })
}

/// The 348-byte header plus the 4-byte empty extension flag, little endian.
fn header(volume: &Volume) -> Vec<u8> {
    let mut h = vec![0u8; HEADER_BYTES + 4];
    let mut put = |o: usize, b: &[u8]| h[o..o + b.len()].copy_from_slice(b);
    put(0, &348i32.to_le_bytes());
    put(38, b"r");
    let [x, y, z] = volume.dims.map(|d| d as i16);
    for (i, d) in [3, x, y, z, 1, 1, 1, 1].iter().enumerate() {
        put(40 + 2 * i, &d.to_le_bytes());
    }
    let (datatype, bitpix): (i16, i16) = match volume.voxel_type() {
        VoxelType::U8 => (2, 8),
        VoxelType::I16 => (4, 16),
        VoxelType::U16 => (512, 16),
        VoxelType::F32 => (16, 32),
    };
    put(70, &datatype.to_le_bytes());
    put(72, &bitpix.to_le_bytes());
    let g = &volume.geometry;
    let lps = g.space == Space::Lps;
    // Column c of the RAS direction matrix is axis c with x and y negated.
    let r: [[f64; 3]; 3] = std::array::from_fn(|row| {
        std::array::from_fn(|c| {
            let a = ras_to_lps(g.axis(c));
            a[row]
        })
    });
    let (quat, qfac) = quaternion(r);
    let s = volume.spacing;
    for (i, p) in [qfac, s[0], s[1], s[2], 1.0, 1.0, 1.0, 1.0]
        .iter()
        .enumerate()
    {
        put(76 + 4 * i, &(*p as f32).to_le_bytes());
    }
    put(108, &((HEADER_BYTES + 4) as f32).to_le_bytes());
    put(112, &1f32.to_le_bytes()); // scl_slope 1, scl_inter 0: values as stored
    put(123, &[2u8]); // xyzt_units: millimetres
    let description = b"written by vellum";
    put(148, description);
    let code: i16 = if lps { 1 } else { 0 };
    put(252, &code.to_le_bytes());
    put(254, &code.to_le_bytes());
    if lps {
        let origin = ras_to_lps(g.origin);
        for (i, q) in quat.iter().chain(origin.iter()).enumerate() {
            put(256 + 4 * i, &(*q as f32).to_le_bytes());
        }
        for row in 0..3 {
            for c in 0..3 {
                put(
                    280 + 16 * row + 4 * c,
                    &((r[row][c] * s[c]) as f32).to_le_bytes(),
                );
            }
            put(280 + 16 * row + 12, &(origin[row] as f32).to_le_bytes());
        }
    }
    put(344, b"n+1\0");
    h
}

/// The rotation matrix of the qform quaternion (b, c, d), with a = √(1 − b² − c² − d²).
fn quaternion_matrix([b, c, d]: [f64; 3]) -> [[f64; 3]; 3] {
    let a = (1.0 - (b * b + c * c + d * d)).max(0.0).sqrt();
    [
        [
            a * a + b * b - c * c - d * d,
            2.0 * (b * c - a * d),
            2.0 * (b * d + a * c),
        ],
        [
            2.0 * (b * c + a * d),
            a * a + c * c - b * b - d * d,
            2.0 * (c * d - a * b),
        ],
        [
            2.0 * (b * d - a * c),
            2.0 * (c * d + a * b),
            a * a + d * d - b * b - c * c,
        ],
    ]
}

/// The qform quaternion (b, c, d) and qfac of an orthonormal matrix whose columns are the axes:
/// a left-handed frame has its third column negated first (qfac −1), then the rotation's
/// quaternion is taken from whichever of its components is largest, for accuracy, with a ≥ 0.
fn quaternion(mut r: [[f64; 3]; 3]) -> ([f64; 3], f64) {
    let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
        - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
        + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
    let qfac = if det < 0.0 {
        for row in r.iter_mut() {
            row[2] = -row[2];
        }
        -1.0
    } else {
        1.0
    };
    let trace = r[0][0] + r[1][1] + r[2][2];
    let (a, b, c, d) = if trace > -0.5 {
        let a = 0.5 * (1.0 + trace).sqrt();
        (
            a,
            0.25 * (r[2][1] - r[1][2]) / a,
            0.25 * (r[0][2] - r[2][0]) / a,
            0.25 * (r[1][0] - r[0][1]) / a,
        )
    } else if r[0][0] >= r[1][1] && r[0][0] >= r[2][2] {
        let b = 0.5 * (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt();
        (
            0.25 * (r[2][1] - r[1][2]) / b,
            b,
            0.25 * (r[0][1] + r[1][0]) / b,
            0.25 * (r[0][2] + r[2][0]) / b,
        )
    } else if r[1][1] >= r[2][2] {
        let c = 0.5 * (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt();
        (
            0.25 * (r[0][2] - r[2][0]) / c,
            0.25 * (r[0][1] + r[1][0]) / c,
            c,
            0.25 * (r[1][2] + r[2][1]) / c,
        )
    } else {
        let d = 0.5 * (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt();
        (
            0.25 * (r[1][0] - r[0][1]) / d,
            0.25 * (r[0][2] + r[2][0]) / d,
            0.25 * (r[1][2] + r[2][1]) / d,
            d,
        )
    };
    let s = if a < 0.0 { -1.0 } else { 1.0 };
    ([s * b, s * c, s * d], qfac)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The quaternion the writer stores turns back into the matrix the reader builds, for proper
    /// and improper frames, including 180° turns where the trace branch is unusable.
    #[test]
    fn quaternion_round_trips() {
        let (c, s) = (0.6f64, 0.8f64);
        let cases: [[[f64; 3]; 3]; 5] = [
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]],
            [[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]],
            [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]],
            [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]],
        ];
        for r in cases {
            let ([b, c, d], qfac) = quaternion(r);
            let m = quaternion_matrix([b, c, d]);
            for row in 0..3 {
                for k in 0..3 {
                    let want = r[row][k];
                    let got = m[row][k] * if k == 2 { qfac } else { 1.0 };
                    assert!((want - got).abs() < 1e-9, "{r:?}: {m:?} qfac {qfac}");
                }
            }
        }
    }
}
