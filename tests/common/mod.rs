//! Shared test helpers: a validated GPU context that fails the test on any validation error or
//! warning, and the path to ../shared/data (required under CI).
#![allow(dead_code)]

use std::path::PathBuf;
use std::sync::Arc;
use vellum::gpu::{Context, ContextDesc};

/// A context with the Khronos validation layer on. Drop the returned guard at the end of the test
/// (or let it fall out of scope): it asserts that no error or warning was reported.
pub struct Gpu {
    pub ctx: Arc<Context>,
}

impl Gpu {
    pub fn new() -> Gpu {
        let ctx = Context::new(&ContextDesc {
            validation: Some(true),
            device: None,
        })
        .expect("a Vulkan device with validation");
        assert!(ctx.validation, "validation must be on in tests");
        Gpu { ctx }
    }
}

impl Drop for Gpu {
    fn drop(&mut self) {
        let m = self.ctx.messages();
        if !std::thread::panicking() {
            assert!(
                m.is_clean(),
                "validation reported {} error(s) and {} warning(s): {:#?}",
                m.errors,
                m.warnings,
                m.messages
            );
        }
    }
}

/// ../shared/data beside the checkout. Under CI=true its absence fails the test loudly; elsewhere
/// the test is skipped with a note.
pub fn shared_data() -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    if p.is_dir() {
        return Some(p);
    }
    if std::env::var("CI").as_deref() == Ok("true") {
        panic!("../shared/data is missing; CI requires it");
    }
    eprintln!("note: ../shared/data is missing; skipping");
    None
}

/// A real volume from ../shared/data/volumes by dataset name.
pub fn real_volume(name: &str) -> Option<vellum::volume::Volume> {
    let root = shared_data()?;
    let path = root.join("volumes").join(name).join(format!("{name}.nhdr"));
    Some(vellum::volume::io::load(&path, None).expect("real volume loads"))
}
