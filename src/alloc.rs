//! A per-thread cap on single allocations, for code that trusts sizes read from files.
//!
//! The DICOM parser (dicom-rs) reserves whatever length an element claims before reading it, with
//! `try_reserve_exact`: a 4 KB file can ask for gigabytes. `volume::io::dicom` checks the claims
//! it can follow, and parses each slice under [`with_cap`]; with [`CappedAllocator`] installed as
//! the global allocator (the `vellum` binary, the fuzz harness), an allocation above the cap fails,
//! the parser's `try_reserve_exact` reports it, and the file is refused with a sentence. Without
//! the allocator installed the cap does nothing.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

thread_local! {
    static CAP: Cell<usize> = const { Cell::new(usize::MAX) };
}

fn cap() -> usize {
    CAP.try_with(Cell::get).unwrap_or(usize::MAX)
}

/// The system allocator, refusing single allocations above this thread's cap.
pub struct CappedAllocator;

// SAFETY: every call forwards to `System` with the same arguments, or returns null (allocation
// failure), which the GlobalAlloc contract allows.
unsafe impl GlobalAlloc for CappedAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > cap() {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if layout.size() > cap() {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > cap() {
            return std::ptr::null_mut();
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Runs `f` with single allocations above `bytes` refused on this thread (when
/// [`CappedAllocator`] is the global allocator). Keep the cap far above what `f` legitimately
/// needs: an infallible allocation above it aborts the process.
pub fn with_cap<R>(bytes: usize, f: impl FnOnce() -> R) -> R {
    struct Restore(usize);
    impl Drop for Restore {
        fn drop(&mut self) {
            let _ = CAP.try_with(|c| c.set(self.0));
        }
    }
    let _restore = Restore(CAP.with(|c| c.replace(bytes)));
    f()
}
