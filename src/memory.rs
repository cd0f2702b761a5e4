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
pub fn fits_in_memory(bytes: u64) -> bool {
    total_kib().is_none_or(|k| bytes <= k * 1024 / 2)
}

/// The largest resident set so far (`VmHWM`), KiB.
pub fn peak_resident_kib() -> Option<u64> {
    status_kib("VmHWM:")
}
