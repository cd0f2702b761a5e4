//! NIfTI-1 single files (`.nii`, `.nii.gz`), the common currency of neuroimaging. Voxels stay in
//! file order (as the copies in `shared/data/volumes` do); spacing comes from pixdim (taken as
//! millimetres whatever `xyzt_units` says), intensity scaling is applied, and the geometry comes
//! from the sform when `sform_code > 0`, else the qform (quaternion) when `qform_code > 0`, else
//! none (spacing only), converted from NIfTI's RAS to LPS.

use std::io::{BufRead, BufReader, Read};
use std::path::Path;

use rayon::prelude::*;

use super::{build, decode, decoder, read_error, read_payload, voxel_count, Compression, FileType};
use crate::error::{Error, Result};
use crate::volume::geometry::{ras_to_lps, Geometry};
use crate::volume::{Volume, VoxelData};

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
    let Ok(h) = <[u8; HEADER_BYTES]>::try_from(head) else {
        return Err(Error::format(
            path,
            "file ends inside the 348-byte NIfTI-1 header; expected a complete header",
        ));
    };
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
        b"n+1\0" => {}
        b"ni1\0" => {
            return Err(Error::format(
                path,
                "file is half of a NIfTI-1 .hdr/.img pair, which is not supported; expected a single .nii or .nii.gz file",
            ))
        }
        m => {
            return Err(Error::format(
                path,
                format!("magic is {:?}; expected \"n+1\" (a single-file NIfTI-1)", String::from_utf8_lossy(m)),
            ))
        }
    }
    let i16_at = |o: usize| {
        let b = [h[o], h[o + 1]];
        if big_endian {
            i16::from_be_bytes(b)
        } else {
            i16::from_le_bytes(b)
        }
    };
    let f32_at = |o: usize| {
        let b = [h[o], h[o + 1], h[o + 2], h[o + 3]];
        if big_endian {
            f32::from_be_bytes(b)
        } else {
            f32::from_le_bytes(b)
        }
    };

    let dim: Vec<i16> = (0..8).map(|i| i16_at(40 + 2 * i)).collect();
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
    let dims = [dim[1] as usize, dim[2] as usize, dim[3] as usize];
    let n = voxel_count(path, dims)?;

    let datatype = i16_at(70);
    let ty = file_type(path, datatype)?;
    let pixdim: Vec<f32> = (0..4).map(|i| f32_at(76 + 4 * i)).collect();
    let spacing = [1, 2, 3].map(|i| match pixdim[i].abs() as f64 {
        s if s.is_finite() && s > 0.0 => s,
        _ => 1.0,
    });
    let (qform_code, sform_code) = (i16_at(252), i16_at(254));
    let geometry = if sform_code > 0 {
        let row = |o: usize| -> [f64; 4] { std::array::from_fn(|k| f32_at(o + 4 * k) as f64) };
        let (x, y, z) = (row(280), row(296), row(312));
        let axes = [0, 1, 2].map(|c| ras_to_lps([x[c], y[c], z[c]]));
        Some(Geometry::lps(ras_to_lps([x[3], y[3], z[3]]), axes))
    } else if qform_code > 0 {
        let (b, c, d) = (f32_at(256) as f64, f32_at(260) as f64, f32_at(264) as f64);
        let a = (1.0 - (b * b + c * c + d * d)).max(0.0).sqrt();
        let r = [
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
        ];
        let qfac = if pixdim[0] < 0.0 { -1.0 } else { 1.0 };
        let axes = [0, 1, 2].map(|k| {
            let s = if k == 2 { qfac } else { 1.0 };
            ras_to_lps([s * r[0][k], s * r[1][k], s * r[2][k]])
        });
        let origin = [f32_at(268) as f64, f32_at(272) as f64, f32_at(276) as f64];
        Some(Geometry::lps(ras_to_lps(origin), axes))
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
    let geometry = geometry
        .transpose()
        .map_err(|e| Error::format(path, format!("the orientation is unusable: {e}")))?;
    let vox_offset = f32_at(108);
    if !(vox_offset >= HEADER_BYTES as f32 && vox_offset.fract() == 0.0) {
        return Err(Error::format(
            path,
            format!("vox_offset is {vox_offset}; expected a whole number of at least 348"),
        ));
    }
    let (slope, inter) = (f32_at(112), f32_at(116));

    let skip = vox_offset as u64 - HEADER_BYTES as u64;
    let bytes = read_payload(path, &mut src, compression, skip, n * ty.size())?;
    let mut data = decode(ty, big_endian, &bytes);
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
