//! Deferred release and resource accounting, owned by the [`Context`](crate::Context), whose
//! methods of the same names delegate here. `G` is the context's garbage (a closure that frees
//! handles given the context); this file knows nothing else of it.
//!
//! ## Deferred release
//! Every submission gets a serial number, and the context remembers the newest serial known to
//! have completed. A buffer or image dropped while work that may use it is still in flight is not
//! destroyed at once: its handles and memory go on a list tagged with the newest serial that can
//! reference it, and they are freed once that serial completes (Granite's per-frame destroy lists,
//! kajiya's deferred release, keyed by one counter instead of one list per frame). Buffers,
//! images, samplers, pipelines, pipeline layouts and query pools all go through it. A resource
//! dropped while nothing is in flight or being recorded is freed immediately, so one-shot tools
//! behave exactly as before.
//!
//! The rule this relies on: recording into a command buffer is bracketed by
//! `Context::begin_recording` / `Context::end_recording` (the frame types do this), so an object
//! dropped mid-recording waits for the submission that is about to be made. One recording is open
//! at a time per context; a second is refused with an error rather than allowed to take the
//! first one's serial.
//!
//! ## Accounting
//! GPU memory allocations and host transfers (uploads and readbacks, by image or buffer name) are
//! counted, so tests can assert that steady-state frames allocate nothing and that a change re-uploads
//! only what it must.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::Mutex;

/// Host transfers of one named resource.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct TransferCount {
    /// Uploads recorded.
    pub uploads: u64,
    /// Bytes uploaded.
    pub upload_bytes: u64,
    /// Readbacks recorded.
    pub readbacks: u64,
    /// Bytes read back.
    pub(crate) readback_bytes: u64,
}

/// Serial numbers, the garbage list and the counters.
pub(crate) struct Lifetimes<G> {
    submitted: AtomicU64,
    completed: AtomicU64,
    recording: AtomicU32,
    garbage: Mutex<Vec<(u64, G)>>,
    allocations: AtomicU64,
    /// Bytes of GPU memory allocated now, and the most at any time.
    allocated_bytes: AtomicU64,
    peak_allocated_bytes: AtomicU64,
    transfers: Mutex<BTreeMap<String, TransferCount>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    // The protected data stays consistent even if a holder panicked.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl<G> Default for Lifetimes<G> {
    fn default() -> Self {
        Lifetimes {
            submitted: AtomicU64::new(0),
            completed: AtomicU64::new(0),
            recording: AtomicU32::new(0),
            garbage: Mutex::new(Vec::new()),
            allocations: AtomicU64::new(0),
            allocated_bytes: AtomicU64::new(0),
            peak_allocated_bytes: AtomicU64::new(0),
            transfers: Mutex::new(BTreeMap::new()),
        }
    }
}

impl<G> Lifetimes<G> {
    /// The garbage whose serial has completed, taken off the list so that the caller runs it
    /// outside the lock (freeing takes the allocator lock).
    fn ripe(&self) -> Vec<G> {
        let done = self.completed.load(Ordering::Acquire);
        let mut g = lock(&self.garbage);
        let mut out = Vec::new();
        let mut i = 0;
        while i < g.len() {
            if g[i].0 <= done {
                out.push(g.swap_remove(i).1);
            } else {
                i += 1;
            }
        }
        out
    }

    /// Everything still on the list (for the context's own drop, after waiting for idle).
    pub(crate) fn drain_all(&self) -> Vec<G> {
        lock(&self.garbage).drain(..).map(|(_, g)| g).collect()
    }

    /// `garbage` back if no submitted or recording work can use it (the caller frees it now);
    /// else it waits on the list until the newest such work has completed.
    pub(crate) fn retire(&self, garbage: G) -> Option<G> {
        let l = self;
        let submitted = l.submitted.load(Ordering::Acquire);
        let tag = if l.recording.load(Ordering::Acquire) > 0 {
            submitted + 1
        } else {
            submitted
        };
        if tag <= l.completed.load(Ordering::Acquire) {
            Some(garbage)
        } else {
            lock(&l.garbage).push((tag, garbage));
            None
        }
    }

    /// Marks the start of recording a command buffer that will be submitted; `what` names it.
    ///
    /// One recording at a time per context: an object dropped while a frame records is tagged
    /// with the serial that frame's submission will take, so a second recording submitted first
    /// would take that serial and free the object while the first frame still uses it. A
    /// recording begun while another is open (a one-shot submission from inside a frame's
    /// recording, say) is refused.
    pub(crate) fn begin_recording(&self, what: &str) -> vellum_error::Result<()> {
        self
            .recording
            .compare_exchange(0, 1, Ordering::AcqRel, Ordering::Acquire)
            .map(|_| ())
            .map_err(|_| {
                vellum_error::Error::Invalid(format!(
                    "{what} was started while another frame is being recorded on this device; submit that frame first"
                ))
            })
    }

    /// Marks the end of recording (after the submission, or after abandoning the commands).
    pub(crate) fn end_recording(&self) {
        self.recording.store(0, Ordering::Release);
    }

    /// The serial of a submission about to be made.
    pub(crate) fn next_serial(&self) -> u64 {
        self.submitted.fetch_add(1, Ordering::AcqRel) + 1
    }

    /// Records that submission `serial` (and, the queue being in order, every earlier one) has
    /// completed; returns the garbage it held back, for the caller to free.
    pub(crate) fn mark_completed(&self, serial: u64) -> Vec<G> {
        self.completed.fetch_max(serial, Ordering::AcqRel);
        self.ripe()
    }

    /// Objects waiting for their submission to complete before they are freed.
    pub(crate) fn pending_releases(&self) -> usize {
        lock(&self.garbage).len()
    }

    pub(crate) fn count_allocation(&self, bytes: u64) {
        let l = self;
        l.allocations.fetch_add(1, Ordering::Relaxed);
        let now = l.allocated_bytes.fetch_add(bytes, Ordering::Relaxed) + bytes;
        l.peak_allocated_bytes.fetch_max(now, Ordering::Relaxed);
    }

    /// Notes `bytes` of GPU memory freed.
    pub(crate) fn count_free(&self, bytes: u64) {
        self.allocated_bytes.fetch_sub(bytes, Ordering::Relaxed);
    }

    /// Bytes of GPU memory allocated through the allocator now.
    pub(crate) fn allocated_bytes(&self) -> u64 {
        self.allocated_bytes.load(Ordering::Relaxed)
    }

    /// The most bytes of GPU memory allocated through the allocator at any time.
    pub(crate) fn peak_allocated_bytes(&self) -> u64 {
        self.peak_allocated_bytes.load(Ordering::Relaxed)
    }

    /// GPU memory allocations made through the allocator since the context was created.
    pub(crate) fn allocation_count(&self) -> u64 {
        self.allocations.load(Ordering::Relaxed)
    }

    /// Notes a recorded host transfer of `bytes` to (`upload`) or from the resource `name`.
    pub(crate) fn count_transfer(&self, name: &str, upload: bool, bytes: u64) {
        let mut t = lock(&self.transfers);
        let c = t.entry(name.to_string()).or_default();
        if upload {
            c.uploads += 1;
            c.upload_bytes += bytes;
        } else {
            c.readbacks += 1;
            c.readback_bytes += bytes;
        }
    }

    /// Host transfers recorded so far, by resource name.
    pub(crate) fn transfers(&self) -> BTreeMap<String, TransferCount> {
        lock(&self.transfers).clone()
    }
}
