//! OME-Zarr stores read over HTTP and HTTPS (issue 42): a Zarr store whose keys are URLs under a
//! base, read by `ureq` with a stall time-out, retries and a bounded on-disk cache.
//!
//! - A request that stalls (no byte for [`RemoteOptions::timeout`]), breaks off, comes back
//!   shorter than its `Content-Length`, or is answered 408, 429 or 5xx is tried again, up to
//!   [`RemoteOptions::retries`] more times with a growing pause; then it fails in one sentence
//!   that names the URL and the last answer.
//! - 404 (and 403, which object stores answer for a missing key when listing is denied) is a
//!   missing key, which Zarr reads as the array's fill value.
//! - A value is read to at most the bytes its key may hold (the store guard's bound), so a
//!   server cannot make us buffer more than a chunk.
//! - Requests run in parallel: each of the readers' threads (zarrs' chunk retrieval, the brick
//!   loaders) sends its own, over one pool of kept-alive connections.
//! - Chunk values (not metadata, so a changed store's shape is always seen) are kept in a cache
//!   folder, bounded by [`RemoteOptions::cache_mib`]; the oldest-used go first. A cached file
//!   begins with its URL, which is checked on every hit, and is written under a temporary name
//!   and renamed, so a cache file is whole or absent. The cache assumes a store is not rewritten
//!   in place under the same URL (as a browser's cache of immutable chunks does).

use sha2::{Digest as _, Sha256};
use std::io::{Read as _, Write as _};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, RwLock};
use std::time::Duration;
use zarrs::storage::byte_range::ByteRange;
use zarrs::storage::StorageError;

/// How stores on a server are read: set once by a front end ([`configure`]) before it opens one.
#[derive(Clone, Debug, PartialEq)]
pub struct RemoteOptions {
    /// A request fails when no byte arrives for this long (connecting, or partway through).
    pub timeout: Duration,
    /// How many more times a failed request is tried.
    pub retries: u32,
    /// The cache folder; `None` keeps no cache.
    pub cache_dir: Option<PathBuf>,
    /// The cache's size in MiB; 0 keeps no cache.
    pub cache_mib: u64,
}

impl Default for RemoteOptions {
    fn default() -> Self {
        RemoteOptions {
            timeout: Duration::from_secs(20),
            retries: 3,
            cache_dir: default_cache_dir(),
            cache_mib: 1024,
        }
    }
}

/// `$XDG_CACHE_HOME/vellum/http`, or `~/.cache/vellum/http`.
pub fn default_cache_dir() -> Option<PathBuf> {
    let base = std::env::var_os("XDG_CACHE_HOME")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))?;
    Some(base.join("vellum").join("http"))
}

static OPTIONS: RwLock<Option<RemoteOptions>> = RwLock::new(None);

/// Sets how stores on a server are read from now on (the stores opened before keep theirs).
pub fn configure(options: RemoteOptions) {
    *OPTIONS.write().unwrap_or_else(|p| p.into_inner()) = Some(options);
}

/// The options stores on a server are read with.
pub fn options() -> RemoteOptions {
    OPTIONS
        .read()
        .unwrap_or_else(|p| p.into_inner())
        .clone()
        .unwrap_or_default()
}

/// Whether `path` is an `http://` or `https://` URL.
pub fn is_url(path: &Path) -> bool {
    path.to_str().is_some_and(|s| {
        let s = s.to_ascii_lowercase();
        s.starts_with("http://") || s.starts_with("https://")
    })
}

/// A store under a base URL.
pub(crate) struct HttpStore {
    base: String,
    agent: ureq::Agent,
    retries: u32,
    timeout: Duration,
    cache: Option<DiskCache>,
}

/// What one try of a request came to.
enum Try {
    /// The value's bytes (a range's when one was asked).
    Got(Vec<u8>),
    /// The key is not there.
    Missing,
    /// A failure worth another try, in words.
    Again(String),
    /// A failure no try will mend, in words.
    Fail(String),
}

impl HttpStore {
    /// The store at `base` (an `http://` or `https://` URL), read with the [`options`] now set.
    pub(crate) fn new(base: &str) -> Result<Self, String> {
        let o = options();
        let agent: ureq::Agent = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .timeout_connect(Some(o.timeout))
            .timeout_per_read(Some(o.timeout))
            .max_idle_connections_per_host(32)
            .max_idle_connections(64)
            .user_agent(concat!("vellum/", env!("CARGO_PKG_VERSION")))
            .build()
            .into();
        let cache = match (&o.cache_dir, o.cache_mib) {
            (Some(dir), mib) if mib > 0 => Some(DiskCache::open(dir, mib << 20)?),
            _ => None,
        };
        Ok(HttpStore {
            base: base.trim_end_matches('/').to_string(),
            agent,
            retries: o.retries,
            timeout: o.timeout,
            cache,
        })
    }

    fn url(&self, key: &str) -> String {
        format!("{}/{}", self.base, key.trim_start_matches('/'))
    }

    /// The value at `key` (or its `range`), of at most `limit` bytes; `None` when missing.
    pub(crate) fn get(
        &self,
        key: &str,
        range: Option<&ByteRange>,
        limit: u64,
        cache: bool,
    ) -> Result<Option<Vec<u8>>, StorageError> {
        let url = self.url(key);
        let header = range.map(range_header);
        let cache_key = match &header {
            Some(h) => format!("{url}#{h}"),
            None => url.clone(),
        };
        let cache = self.cache.as_ref().filter(|_| cache);
        if let Some(bytes) = cache.and_then(|c| c.get(&cache_key)) {
            return Ok(Some(bytes));
        }
        let mut last = String::new();
        for attempt in 0..=self.retries {
            if attempt > 0 {
                std::thread::sleep(Duration::from_millis(100 << (2 * (attempt - 1)).min(6)));
            }
            if vellum_error::interrupted() {
                return Err(StorageError::Other("interrupted".into()));
            }
            match self.try_get(&url, header.as_deref(), limit) {
                Try::Got(bytes) => {
                    if let Some(c) = cache {
                        c.put(&cache_key, &bytes);
                    }
                    return Ok(Some(bytes));
                }
                Try::Missing => return Ok(None),
                Try::Fail(why) => return Err(StorageError::Other(why)),
                Try::Again(why) => last = why,
            }
        }
        Err(self.gave_up(&last))
    }

    fn try_get(&self, url: &str, range: Option<&str>, limit: u64) -> Try {
        let mut request = self.agent.get(url);
        if let Some(r) = range {
            request = request.header("Range", r);
        }
        let response = match request.call() {
            Ok(r) => r,
            Err(e) => return Try::Again(format!("the request failed ({e})")),
        };
        let status = response.status().as_u16();
        match status {
            200 | 206 => {}
            404 | 403 => return Try::Missing,
            408 | 429 | 500..=599 => return Try::Again(format!("the server answered {status}")),
            _ => return Try::Fail(format!("the server answered {status}; expected 200")),
        }
        let declared = content_length(response.headers());
        if let Some(n) = declared.filter(|&n| n > limit) {
            return Try::Fail(format!(
                "the server sends {n} bytes; at most {limit} expected for this key"
            ));
        }
        let mut body = Vec::new();
        let read = response
            .into_body()
            .into_reader()
            .take(limit + 1)
            .read_to_end(&mut body);
        if let Err(e) = read {
            let n = body.len();
            let of = declared.map(|d| format!(" of {d}")).unwrap_or_default();
            if e.kind() == std::io::ErrorKind::TimedOut || e.to_string().contains("timeout") {
                let t = self.timeout.as_secs_f64();
                return Try::Again(format!(
                    "the server stalled: no byte for {t} s after {n}{of} bytes"
                ));
            }
            return Try::Again(format!("the answer broke off after {n}{of} bytes ({e})"));
        }
        if body.len() as u64 > limit {
            return Try::Fail(format!(
                "the server sends more than {limit} bytes; at most {limit} expected for this key"
            ));
        }
        if declared.is_some_and(|n| n != body.len() as u64) {
            return Try::Again(format!(
                "the answer ended after {} of {} bytes",
                body.len(),
                declared.unwrap_or(0)
            ));
        }
        if status == 200 && range.is_some() {
            // A server that ignores ranges sends the whole value: cut the range from it.
            return match cut(&body, range) {
                Some(part) => Try::Got(part),
                None => Try::Fail("the range asked lies beyond the value".into()),
            };
        }
        Try::Got(body)
    }

    /// The size of the value at `key`, from a HEAD request.
    pub(crate) fn size(&self, key: &str) -> Result<Option<u64>, StorageError> {
        let url = self.url(key);
        let mut last = String::new();
        for attempt in 0..=self.retries {
            if attempt > 0 {
                std::thread::sleep(Duration::from_millis(100 << (2 * (attempt - 1)).min(6)));
            }
            match self.agent.head(&url).call() {
                Ok(r) => match r.status().as_u16() {
                    200 => {
                        return content_length(r.headers())
                            .map(Some)
                            .ok_or_else(|| StorageError::Other("the server gives no size".into()))
                    }
                    404 | 403 => return Ok(None),
                    s @ (408 | 429 | 500..=599) => last = format!("the server answered {s}"),
                    s => {
                        return Err(StorageError::Other(format!(
                            "the server answered {s}; expected 200"
                        )))
                    }
                },
                Err(e) => last = format!("the request failed ({e})"),
            }
        }
        Err(self.gave_up(&last))
    }

    /// The error after the last try failed with `last`.
    fn gave_up(&self, last: &str) -> StorageError {
        StorageError::Other(format!("{last}; tried {} times", self.retries + 1))
    }
}

/// The `Content-Length` an answer declares.
fn content_length(headers: &ureq::http::HeaderMap) -> Option<u64> {
    headers
        .get("content-length")?
        .to_str()
        .ok()?
        .trim()
        .parse()
        .ok()
}

/// The `Range` header of `range`.
fn range_header(range: &ByteRange) -> String {
    match *range {
        ByteRange::FromStart(start, None) => format!("bytes={start}-"),
        ByteRange::FromStart(start, Some(len)) => {
            format!("bytes={start}-{}", (start + len).saturating_sub(1))
        }
        ByteRange::Suffix(len) => format!("bytes=-{len}"),
    }
}

/// The part of a whole value a `Range` header asks for.
fn cut(whole: &[u8], header: Option<&str>) -> Option<Vec<u8>> {
    let spec = header?.strip_prefix("bytes=")?;
    let n = whole.len();
    let (a, b) = spec.split_once('-')?;
    let (start, end) = if a.is_empty() {
        let len: usize = b.parse().ok()?;
        (n.checked_sub(len)?, n)
    } else {
        let start: usize = a.parse().ok()?;
        let end = if b.is_empty() {
            n
        } else {
            b.parse::<usize>().ok()?.checked_add(1)?
        };
        (start, end)
    };
    (start <= end && end <= n).then(|| whole[start..end].to_vec())
}

/// Cached values, one file each, named by the SHA-256 of their URL.
struct DiskCache {
    dir: PathBuf,
    budget: u64,
    /// Bytes in the folder, counted when it was opened and kept up to date since.
    used: Mutex<u64>,
}

impl DiskCache {
    fn open(dir: &Path, budget: u64) -> Result<Self, String> {
        std::fs::create_dir_all(dir).map_err(|e| {
            format!(
                "the chunk cache folder {} could not be made ({e}); expected a folder we may write (--cache-dir), or --cache-mib 0",
                dir.display()
            )
        })?;
        let used = entries(dir).iter().map(|e| e.1).sum();
        Ok(DiskCache {
            dir: dir.to_path_buf(),
            budget,
            used: Mutex::new(used),
        })
    }

    fn file(&self, key: &str) -> PathBuf {
        let hash = Sha256::digest(key.as_bytes());
        let name: String = hash[..16].iter().map(|b| format!("{b:02x}")).collect();
        self.dir.join(name)
    }

    fn get(&self, key: &str) -> Option<Vec<u8>> {
        let path = self.file(key);
        let mut bytes = std::fs::read(&path).ok()?;
        let head = format!("{key}\n");
        if !bytes.starts_with(head.as_bytes()) {
            return None;
        }
        // Its time of use, for the eviction order.
        if let Ok(f) = std::fs::File::options().append(true).open(&path) {
            let _ = f.set_modified(std::time::SystemTime::now());
        }
        bytes.drain(..head.len());
        Some(bytes)
    }

    fn put(&self, key: &str, value: &[u8]) {
        let head = format!("{key}\n");
        let size = (head.len() + value.len()) as u64;
        if size > self.budget / 4 {
            return;
        }
        let path = self.file(key);
        let tmp = self.dir.join(format!(
            ".tmp-{}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        let written = std::fs::File::create(&tmp)
            .and_then(|mut f| {
                f.write_all(head.as_bytes())?;
                f.write_all(value)
            })
            .and_then(|()| std::fs::rename(&tmp, &path));
        if let Err(e) = written {
            let _ = std::fs::remove_file(&tmp);
            log::warn!("chunk cache: {} could not be written ({e})", path.display());
            return;
        }
        let mut used = self.used.lock().unwrap_or_else(|p| p.into_inner());
        *used += size;
        if *used > self.budget {
            *used = self.evict();
        }
    }

    /// Removes the least recently used files until the folder holds 90 % of the budget; the
    /// bytes it holds then.
    fn evict(&self) -> u64 {
        let mut all = entries(&self.dir);
        all.sort_by_key(|e| e.2);
        let mut used: u64 = all.iter().map(|e| e.1).sum();
        for (path, size, _) in all {
            if used <= self.budget / 10 * 9 {
                break;
            }
            if std::fs::remove_file(&path).is_ok() {
                used -= size;
            }
        }
        used
    }
}

/// The cache files in `dir`: path, size and time of last use.
fn entries(dir: &Path) -> Vec<(PathBuf, u64, std::time::SystemTime)> {
    let Ok(read) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    read.filter_map(|e| {
        let e = e.ok()?;
        let name = e.file_name();
        let name = name.to_str()?;
        if name.len() != 32 || !name.bytes().all(|b| b.is_ascii_hexdigit()) {
            return None;
        }
        let m = e.metadata().ok()?;
        Some((e.path(), m.len(), m.modified().ok()?))
    })
    .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_range_is_cut_from_a_whole_value_as_a_server_would() {
        let v: Vec<u8> = (0..10).collect();
        let h = |r| range_header(&r);
        assert_eq!(
            cut(&v, Some(&h(ByteRange::FromStart(2, Some(3))))),
            Some(vec![2, 3, 4])
        );
        assert_eq!(
            cut(&v, Some(&h(ByteRange::FromStart(7, None)))),
            Some(vec![7, 8, 9])
        );
        assert_eq!(cut(&v, Some(&h(ByteRange::Suffix(2)))), Some(vec![8, 9]));
        assert_eq!(cut(&v, Some(&h(ByteRange::FromStart(8, Some(5))))), None);
        assert_eq!(cut(&v, Some(&h(ByteRange::Suffix(11)))), None);
    }

    #[test]
    fn the_cache_keeps_to_its_budget_and_checks_the_url_of_a_hit() {
        let dir = tempfile::tempdir().unwrap();
        let cache = DiskCache::open(dir.path(), 40_000).unwrap();
        for i in 0..20 {
            cache.put(&format!("http://h/k{i}"), &vec![i as u8; 5000]);
        }
        let held: u64 = entries(dir.path()).iter().map(|e| e.1).sum();
        assert!(held <= 40_000, "{held}");
        assert_eq!(cache.get("http://h/k19"), Some(vec![19u8; 5000]));
        assert_eq!(cache.get("http://h/k0"), None, "the oldest went first");
        // A file under another URL's name is not that URL's value.
        std::fs::copy(cache.file("http://h/k19"), cache.file("http://h/other")).unwrap();
        assert_eq!(cache.get("http://h/other"), None);
        // A value of more than a quarter of the budget is not kept.
        cache.put("http://h/big", &vec![0; 20_000]);
        assert_eq!(cache.get("http://h/big"), None);
    }
}
