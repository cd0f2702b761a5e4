//! A store's files read under guard (issue 40): the filesystem store of `zarrs`, with every
//! value checked before and after it is read.
//!
//! - Only a regular file is read. A FIFO, a socket or a device would block or stream forever,
//!   and a link to nothing would otherwise read as a missing chunk (the fill value) without a
//!   word; each is refused, naming its key.
//! - A value's size is bounded: metadata documents at [`METADATA_BYTES`], a chunk at its array's
//!   declared chunk size (with room for a codec's headers and a shard's index) once the array is
//!   known, at [`MAX_CHUNK_BYTES`] before.
//! - A compressed chunk may not decode to more than its declared size. Zstandard frames carry
//!   their decoded size, which is read from their headers; a frame without it is decoded here
//!   with a bound before `zarrs` decodes it. A Blosc chunk's header gives its decoded size too;
//!   a gzip chunk (whose trailer gives its size only modulo 4 GiB) is decoded under the bound.
//!   So a chunk of 33 KB that would decode to a gigabyte is refused after reading 33 KB.
//!
//! A store on a server (issue 42) is read through the same guards: its values are read to at
//! most the same bounds (`http_store.rs`), and the file checks have no counterpart there.

use super::http_store::{is_url, HttpStore};
use std::io::Read as _;
use std::path::Path;
use std::sync::RwLock;
use zarrs::filesystem::FilesystemStore;
use zarrs::storage::byte_range::{ByteRange, ByteRangeIterator};
use zarrs::storage::{Bytes, MaybeBytesIterator, ReadableStorageTraits, StorageError, StoreKey};

/// Bytes a metadata document (`zarr.json`, `.zarray`, `.zattrs`, `.zgroup`) may hold.
pub(crate) const METADATA_BYTES: u64 = 16 << 20;

/// Bytes a chunk may decode to, whatever its array declares (the arrays' checks refuse larger
/// chunks before any is read).
pub(crate) const MAX_CHUNK_BYTES: u64 = 1 << 30;

/// Where a guarded store's values come from.
enum Backend {
    /// A folder.
    Files(FilesystemStore),
    /// A base URL.
    Http(HttpStore),
}

/// The store of a Zarr hierarchy, in a folder or on a server, read under the guards above.
pub(crate) struct GuardedStore {
    inner: Backend,
    /// Per array (its path in the store, with a trailing '/'), the bytes a chunk decodes to.
    chunk_bytes: RwLock<Vec<(String, u64)>>,
}

impl GuardedStore {
    /// The store at `root`: a folder, or an `http://` or `https://` URL.
    pub(crate) fn new(root: &Path) -> Result<Self, String> {
        let inner = if is_url(root) {
            let url = root.to_str().unwrap_or_default();
            Backend::Http(HttpStore::new(url)?)
        } else {
            Backend::Files(FilesystemStore::new(root).map_err(|e| e.to_string())?)
        };
        Ok(GuardedStore {
            inner,
            chunk_bytes: RwLock::new(Vec::new()),
        })
    }

    /// Bounds the chunks of the array at `path` (in the store, without a leading '/') to
    /// `bytes` decoded.
    pub(crate) fn bound_array(&self, path: &str, bytes: u64) {
        let prefix = format!("{}/", path.trim_matches('/'));
        let mut all = self.chunk_bytes.write().unwrap_or_else(|p| p.into_inner());
        all.retain(|(p, _)| *p != prefix);
        all.push((prefix, bytes.min(MAX_CHUNK_BYTES)));
        // Longest first, so that a nested array's bound wins over its parent's.
        all.sort_by_key(|(p, _)| std::cmp::Reverse(p.len()));
    }

    /// The bytes the value at `key` may decode to, and whether it is a metadata document.
    fn bound(&self, key: &StoreKey) -> (u64, bool) {
        let k = key.as_str().trim_start_matches('/');
        let name = k.rsplit('/').next().unwrap_or(k);
        if matches!(
            name,
            "zarr.json" | ".zarray" | ".zattrs" | ".zgroup" | ".zmetadata"
        ) {
            return (METADATA_BYTES, true);
        }
        let all = self.chunk_bytes.read().unwrap_or_else(|p| p.into_inner());
        let bytes = all
            .iter()
            .find(|(p, _)| k.starts_with(p.as_str()))
            .map_or(MAX_CHUNK_BYTES, |(_, b)| *b);
        (bytes, false)
    }

    /// The file of `key`, if there is one and it may be read: a regular file (through links),
    /// of at most the bytes its value may take.
    fn check_file(
        &self,
        files: &FilesystemStore,
        key: &StoreKey,
    ) -> Result<Option<u64>, StorageError> {
        let path = files.key_to_fspath(key);
        let refuse = |what: String| Err(StorageError::Other(format!("`{}` {what}", key.as_str())));
        let link = match std::fs::symlink_metadata(&path) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e.into()),
        };
        let meta = match std::fs::metadata(&path) {
            Ok(m) => m,
            Err(e) if link.file_type().is_symlink() && e.kind() == std::io::ErrorKind::NotFound => {
                return refuse("is a link to nothing; expected a chunk file".into())
            }
            Err(e) => return Err(e.into()),
        };
        if meta.is_dir() {
            return Ok(None);
        }
        if !meta.is_file() {
            return refuse(format!(
                "is not a regular file ({}); expected a chunk or metadata file",
                special_kind(&meta)
            ));
        }
        let (bound, metadata) = self.bound(key);
        let limit = stored_limit(bound, metadata);
        if meta.len() > limit {
            return refuse(format!(
                "holds {} bytes; at most {limit} expected{}",
                meta.len(),
                if metadata {
                    " of a metadata document"
                } else {
                    " for its array's chunk size"
                }
            ));
        }
        Ok(Some(meta.len()))
    }
}

/// The bytes a value may take as stored: a chunk's file may exceed its decoded size by a codec's
/// headers or a shard's index.
fn stored_limit(bound: u64, metadata: bool) -> u64 {
    if metadata {
        bound
    } else {
        bound + bound / 4 + (1 << 20)
    }
}

#[cfg(unix)]
fn special_kind(meta: &std::fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    if t.is_fifo() {
        "a FIFO"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_block_device() || t.is_char_device() {
        "a device"
    } else {
        "not a file"
    }
}

#[cfg(not(unix))]
fn special_kind(_: &std::fs::Metadata) -> &'static str {
    "not a file"
}

/// The zstd frame's magic number, little-endian at the start of each frame.
const ZSTD_MAGIC: [u8; 4] = [0x28, 0xb5, 0x2f, 0xfd];

/// The bytes `value` decodes to at most, as far as its codec says without decoding it, or by
/// a bounded decode of zstd frames that do not say: `Err` with the sentence when more than
/// `bound`.
pub(crate) fn check_decoded_size(value: &[u8], bound: u64) -> Result<(), String> {
    if value.starts_with(&ZSTD_MAGIC) {
        return check_zstd(value, bound);
    }
    // Gzip records its size only modulo 4 GiB, and a member can hide behind another: decoded
    // here under the bound (a gzip chunk is decoded twice; zstd and Blosc are the common codecs).
    if value.starts_with(&[0x1f, 0x8b]) {
        let mut d = flate2::read::MultiGzDecoder::new(value);
        let n = std::io::copy(&mut (&mut d).take(bound + 1), &mut std::io::sink())
            .map_err(|e| format!("could not be decoded (gzip: {e})"))?;
        if n > bound {
            return Err(format!(
                "decodes to more than {bound} bytes (gzip); its array's chunks hold at most {bound}"
            ));
        }
        return Ok(());
    }
    // Blosc 1 and 2: version, versionlz, flags, typesize, then the decoded and compressed sizes
    // (u32, little-endian); the compressed size is the whole value's.
    if value.len() >= 16 && matches!(value[0], 1 | 2) {
        let u32_at =
            |i: usize| u32::from_le_bytes([value[i], value[i + 1], value[i + 2], value[i + 3]]);
        if u32_at(12) as usize == value.len() && u64::from(u32_at(4)) > bound {
            return Err(format!(
                "declares {} bytes decoded (Blosc); its array's chunks hold at most {bound}",
                u32_at(4)
            ));
        }
    }
    Ok(())
}

/// The zstd frames at the start of `value` (a chunk, or the inner chunks that begin a shard)
/// decode to at most `bound` bytes together.
fn check_zstd(value: &[u8], bound: u64) -> Result<(), String> {
    let too_many = |n: u64| {
        format!("decodes to more than {bound} bytes (zstd, {n} or more); its array's chunks hold at most {bound}")
    };
    let mut rest = value;
    let mut total = 0u64;
    while rest.starts_with(&ZSTD_MAGIC) {
        let Ok(len) = zstd::zstd_safe::find_frame_compressed_size(rest) else {
            break;
        };
        let frame = &rest[..len.min(rest.len())];
        let size = match zstd::zstd_safe::get_frame_content_size(frame) {
            Ok(Some(n)) => n,
            // No size in the header: decode with a bound.
            _ => {
                let mut d = zstd::stream::read::Decoder::with_buffer(frame)
                    .map_err(|e| format!("is not a zstd frame ({e})"))?
                    .single_frame();
                let mut sink = std::io::sink();
                let left = bound.saturating_sub(total) + 1;
                std::io::copy(&mut (&mut d).take(left), &mut sink)
                    .map_err(|e| format!("could not be decoded (zstd: {e})"))?
            }
        };
        total = total.saturating_add(size);
        if total > bound {
            return Err(too_many(total));
        }
        rest = &rest[len.min(rest.len())..];
    }
    Ok(())
}

impl GuardedStore {
    /// Whether the store holds a value at `key`, when that can be told without reading it: in a
    /// folder, by the file's presence; `None` on a server, where asking is a request. A key the
    /// guards refuse counts as held, so that its reader names what is wrong with it.
    pub(crate) fn holds_locally(&self, key: &StoreKey) -> Option<bool> {
        match &self.inner {
            Backend::Files(files) => Some(!matches!(self.check_file(files, key), Ok(None))),
            Backend::Http(_) => None,
        }
    }

    /// The values of `ranges` of `key`, read from the backend under the bounds.
    fn read(
        &self,
        key: &StoreKey,
        ranges: Vec<ByteRange>,
    ) -> Result<Option<Vec<Result<Bytes, StorageError>>>, StorageError> {
        match &self.inner {
            Backend::Files(files) => {
                if self.check_file(files, key)?.is_none() {
                    return Ok(None);
                }
                Ok(files
                    .get_partial_many(key, Box::new(ranges.into_iter()))?
                    .map(|values| values.collect()))
            }
            Backend::Http(http) => {
                let (bound, metadata) = self.bound(key);
                let limit = stored_limit(bound, metadata);
                let whole = |r: &ByteRange| matches!(r, ByteRange::FromStart(0, None));
                let mut values = Vec::with_capacity(ranges.len());
                for r in &ranges {
                    let range = (!whole(r)).then_some(r);
                    match http.get(key.as_str(), range, limit, !metadata)? {
                        Some(v) => values.push(Ok(Bytes::from(v))),
                        None => return Ok(None),
                    }
                }
                Ok(Some(values))
            }
        }
    }
}

impl ReadableStorageTraits for GuardedStore {
    fn get_partial_many<'a>(
        &'a self,
        key: &StoreKey,
        byte_ranges: ByteRangeIterator<'a>,
    ) -> Result<MaybeBytesIterator<'a>, StorageError> {
        let ranges: Vec<ByteRange> = byte_ranges.collect();
        let whole = matches!(ranges.as_slice(), [ByteRange::FromStart(0, None)]);
        let Some(values) = self.read(key, ranges)? else {
            return Ok(None);
        };
        if whole {
            // A whole value: a chunk is checked against its declared size before anyone
            // decodes it.
            let (bound, metadata) = self.bound(key);
            if !metadata {
                if let Some(Ok(bytes)) = values.first() {
                    check_decoded_size(bytes, bound)
                        .map_err(|e| StorageError::Other(format!("`{}` {e}", key.as_str())))?;
                }
            }
        }
        Ok(Some(Box::new(values.into_iter())))
    }

    fn size_key(&self, key: &StoreKey) -> Result<Option<u64>, StorageError> {
        match &self.inner {
            Backend::Files(files) => self.check_file(files, key),
            Backend::Http(http) => http.size(key.as_str()),
        }
    }

    fn supports_get_partial(&self) -> bool {
        match &self.inner {
            Backend::Files(files) => files.supports_get_partial(),
            Backend::Http(_) => true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_zstd_frame_that_decodes_beyond_its_bound_is_refused_unread() {
        let zeros = vec![0u8; 1 << 20];
        let small = zstd::bulk::compress(&zeros, 19).unwrap();
        assert!(small.len() < 4096);
        assert!(check_decoded_size(&small, 1 << 20).is_ok());
        let e = check_decoded_size(&small, (1 << 20) - 1).unwrap_err();
        assert!(e.contains("zstd"), "{e}");
        // Without its size in the header (a streamed frame): the bounded decode finds it.
        let mut streamed = Vec::new();
        {
            let mut enc = zstd::stream::write::Encoder::new(&mut streamed, 3).unwrap();
            enc.include_contentsize(false).unwrap();
            std::io::copy(&mut &zeros[..], &mut enc).unwrap();
            enc.finish().unwrap();
        }
        assert_eq!(
            zstd::zstd_safe::get_frame_content_size(&streamed)
                .ok()
                .flatten(),
            None
        );
        assert!(check_decoded_size(&streamed, 1 << 20).is_ok());
        assert!(check_decoded_size(&streamed, 1000).is_err());
        // Two frames, each within the bound, together beyond it.
        let two = [small.clone(), small].concat();
        assert!(check_decoded_size(&two, 3 << 19).is_err());
        assert!(check_decoded_size(&two, 2 << 20).is_ok());
    }

    #[test]
    fn a_gzip_chunk_that_decodes_beyond_its_bound_is_refused() {
        use std::io::Write as _;
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
        e.write_all(&vec![0u8; 1 << 20]).unwrap();
        let gz = e.finish().unwrap();
        assert!(check_decoded_size(&gz, 1 << 20).is_ok());
        let err = check_decoded_size(&gz, 1000).unwrap_err();
        assert!(err.contains("gzip"), "{err}");
    }

    #[test]
    fn a_blosc_header_beyond_the_bound_is_refused() {
        let mut v = vec![2u8, 1, 0, 4];
        v.extend(4_000_000u32.to_le_bytes());
        v.extend(0u32.to_le_bytes());
        v.extend(20u32.to_le_bytes());
        v.extend([0u8; 4]);
        assert!(check_decoded_size(&v, 1 << 20).is_err());
        assert!(check_decoded_size(&v, 8 << 20).is_ok());
    }
}
