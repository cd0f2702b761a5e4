//! The process's memory as Linux reports it in /proc/self/status (and the machine's in
//! /proc/meminfo): what the benchmarks, the
//! fuzzer, the viewer's bench and the out-of-core commands report and tests bound.

/// A `Vm…` field of /proc/self/status in KiB, where the system has one.
fn status_kib(key: &str) -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with(key))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// The resident set now (`VmRSS`), KiB.
pub fn resident_kib() -> Option<u64> {
    status_kib("VmRSS:")
}

/// The machine's memory (`MemTotal` of /proc/meminfo), KiB.
pub fn total_kib() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemTotal:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Whether `bytes` may be read whole: at most half of the machine's memory (always, where the
/// system does not say).
pub(crate) fn fits_in_memory(bytes: u64) -> bool {
    total_kib().is_none_or(|k| bytes <= k * 1024 / 2)
}

/// The largest resident set so far (`VmHWM`), KiB.
pub fn peak_resident_kib() -> Option<u64> {
    status_kib("VmHWM:")
}

/// Bytes of Rust heap allocations live now, counted by [`Counting`] when a binary installs it as
/// its global allocator (`vellum` does); `None` otherwise. Memory that C libraries allocate
/// themselves (the Vulkan driver and the validation layer) is not in it, which is the point:
/// it tells what vellum's own code keeps, where the resident set also moves with theirs.
pub fn live_heap_bytes() -> Option<u64> {
    counted_bytes(&LIVE)
}

/// `counter`'s bytes, where [`Counting`] counts them.
fn counted_bytes(counter: &std::sync::atomic::AtomicI64) -> Option<u64> {
    use std::sync::atomic::Ordering;
    COUNTING
        .load(Ordering::Relaxed)
        .then(|| counter.load(Ordering::Relaxed).max(0) as u64)
}

static LIVE: std::sync::atomic::AtomicI64 = std::sync::atomic::AtomicI64::new(0);
static COUNTING: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Adds `bytes` to the live count, and marks the count as kept (read first: a shared line that
/// every thread only reads after the first allocation).
fn counted(bytes: i64) {
    use std::sync::atomic::Ordering;
    if !COUNTING.load(Ordering::Relaxed) {
        COUNTING.store(true, Ordering::Relaxed);
    }
    let now = LIVE.fetch_add(bytes, Ordering::Relaxed) + bytes;
    if now > PEAK.load(Ordering::Relaxed) {
        PEAK.fetch_max(now, Ordering::Relaxed);
    }
}

static PEAK: std::sync::atomic::AtomicI64 = std::sync::atomic::AtomicI64::new(0);

/// The most bytes of Rust heap live at once so far, where [`Counting`] counts them: beside the
/// peak resident set, it tells what vellum kept at its peak from what the driver and the layers
/// kept (`render --json`'s `peak_heap_mib`).
pub fn peak_heap_bytes() -> Option<u64> {
    counted_bytes(&PEAK)
}

/// [`peak_heap_bytes`] in MiB, as the reports give it.
pub fn peak_heap_mib() -> Option<f64> {
    peak_heap_bytes().map(|b| b as f64 / (1u64 << 20) as f64)
}

/// The system allocator, counting the bytes live ([`live_heap_bytes`]) and their peak
/// ([`peak_heap_bytes`]): one relaxed atomic add per allocation and per free, and a relaxed load
/// of the peak per allocation (a store only when the peak rises).
pub struct Counting;

// SAFETY: every call is forwarded to the system allocator unchanged; the counter only adds.
unsafe impl std::alloc::GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        counted(layout.size() as i64);
        // SAFETY: the caller's contract for `alloc` is passed on.
        unsafe { std::alloc::System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        LIVE.fetch_sub(layout.size() as i64, std::sync::atomic::Ordering::Relaxed);
        // SAFETY: as for `dealloc`.
        unsafe { std::alloc::System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: std::alloc::Layout) -> *mut u8 {
        counted(layout.size() as i64);
        // SAFETY: as for `alloc_zeroed`.
        unsafe { std::alloc::System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, new: usize) -> *mut u8 {
        let grown = new as i64 - layout.size() as i64;
        counted(grown);
        // SAFETY: as for `realloc`.
        unsafe { std::alloc::System.realloc(ptr, layout, new) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::Ordering;

    /// The peak follows the live count up and stays when it falls. (The test binary does not
    /// install `Counting`, so only these calls move the counts.)
    #[test]
    fn the_peak_keeps_the_most_live_at_once() {
        let base = LIVE.load(Ordering::Relaxed);
        counted(1 << 40);
        counted(-(1 << 40));
        assert_eq!(LIVE.load(Ordering::Relaxed), base);
        assert!(PEAK.load(Ordering::Relaxed) >= base + (1 << 40));
        assert_eq!(peak_heap_bytes(), Some(PEAK.load(Ordering::Relaxed) as u64));
    }
}
