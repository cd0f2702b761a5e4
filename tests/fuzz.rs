//! A short run of the fuzz harness (`vellum::fuzz`; `make fuzz` runs it long): every reader of
//! outside input, on mutated small real files, in-process. No input may panic, run past the time
//! bound, or be refused with anything but one sentence; each reader must accept its own seeds
//! and refuse some mutants, or the run exercised nothing.

mod common;

use std::path::Path;
use std::time::Duration;

use vellum::fuzz::{self, FuzzOptions};

#[test]
fn readers_survive_mutated_real_files() {
    let Some(data) = common::shared_data() else {
        return;
    };
    let project = Path::new(env!("CARGO_MANIFEST_DIR"));
    let work = tempfile::tempdir().unwrap();
    let targets = fuzz::targets(&data, project, &work.path().join("seeds")).unwrap();
    assert_eq!(targets.len(), 11);
    let options = FuzzOptions {
        inputs: 5000,
        seed: 20261123,
        time_bound: Duration::from_secs(20),
        work_dir: work.path().to_path_buf(),
        only: vec![],
    };
    let reports = fuzz::run(&targets, &options).unwrap();
    for r in &reports {
        println!(
            "{:<20} {} inputs: {} accepted, {} refused, {} crashes, max {:.1} ms",
            r.target, r.inputs, r.accepted, r.refused, r.crashes, r.max_ms
        );
        assert_eq!(r.inputs, options.inputs, "{}", r.target);
        assert_eq!(r.crashes, 0, "{}: {:?}", r.target, r.crash_messages);
        assert_eq!(
            r.unclear, 0,
            "{}: a refusal that is not one sentence",
            r.target
        );
        assert!(r.accepted > 0 && r.refused > 0, "{}: {r:?}", r.target);
    }
    println!(
        "peak memory {:.0} MiB",
        fuzz::peak_memory_mib().unwrap_or(f64::NAN)
    );
}
