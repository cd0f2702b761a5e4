//! Headerless voxel files described on the command line. With no header to cross-check, the file
//! size is the only guard against wrong dims or type, so it must match exactly.

use std::io::{BufReader, Seek, SeekFrom};
use std::path::Path;

use super::{build, decode, decoder, read_payload, voxel_count, Compression, RawSpec};
use crate::Volume;
use vellum_error::{Error, Result};

/// Reads `path` as `spec` describes. A `.gz` file is decompressed first; `spec.offset` is then
/// counted in decompressed bytes.
pub(super) fn read(path: &Path, spec: &RawSpec) -> Result<Volume> {
    let n = voxel_count(path, spec.dims)?;
    let expected = n * spec.voxel_type.size();
    let mut file = super::open_regular(path)?;
    let gz = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("gz"));
    let bytes = if gz {
        read_payload(
            path,
            &mut decoder(file, Compression::Gzip),
            Compression::Gzip,
            spec.offset,
            expected,
        )?
    } else {
        let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        let needed = spec.offset + expected as u64;
        if len != needed {
            let [x, y, z] = spec.dims;
            return Err(Error::format(
                path,
                format!(
                    "file holds {len} bytes but {x}x{y}x{z} voxels of {} after an offset of {} need exactly {needed}",
                    spec.voxel_type.name(),
                    spec.offset
                ),
            ));
        }
        file.seek(SeekFrom::Start(spec.offset))
            .map_err(|e| Error::io(path, e))?;
        read_payload(
            path,
            &mut BufReader::new(file),
            Compression::None,
            0,
            expected,
        )?
    };
    let data = decode(path, spec.voxel_type.into(), spec.big_endian, &bytes)?;
    build(path, spec.dims, spec.spacing, data)
}
