//! A short run of the fuzz harness (`vellum::fuzz`; `make fuzz` runs it long): every reader of
//! outside input, on mutated small real files, in-process. No input may panic, run past the time
//! bound, or be refused with anything but one sentence; each reader must accept its own seeds
//! and refuse some mutants, or the run exercised nothing.

mod common;

use std::path::Path;
use std::time::Duration;

use vellum_tools::fuzz::{self, FuzzOptions};

#[test]
fn readers_survive_mutated_real_files() {
    let Some(data) = common::shared_data() else {
        return;
    };
    let project = Path::new(env!("CARGO_MANIFEST_DIR"));
    let work = tempfile::tempdir().unwrap();
    let targets = fuzz::targets(&data, project, &work.path().join("seeds")).unwrap();
    assert_eq!(targets.len(), 17);
    // The file readers at 5000 inputs each, the stores (six targets, each input a store opened
    // and read) at 500.
    let files = [
        "nrrd",
        "nifti",
        "metaimage",
        "dicom",
        "transfer",
        "occlusion",
        "feature",
        "scene",
    ];
    let options = FuzzOptions {
        inputs: 5000,
        seed: 20261123,
        time_bound: Duration::from_secs(20),
        work_dir: work.path().to_path_buf(),
        only: files.iter().map(|s| s.to_string()).collect(),
    };
    let mut reports = fuzz::run(&targets, &options).unwrap();
    assert_eq!(reports.len(), 11);
    let stores = FuzzOptions {
        inputs: 500,
        only: vec!["store".into()],
        ..options.clone()
    };
    reports.extend(fuzz::run(&targets, &stores).unwrap());
    for r in &reports {
        println!(
            "{:<20} {} inputs: {} accepted, {} refused, {} crashes, max {:.1} ms",
            r.target, r.inputs, r.accepted, r.refused, r.crashes, r.max_ms
        );
        let inputs = match r.target.starts_with("store") {
            true => stores.inputs,
            false => options.inputs,
        };
        assert_eq!(r.inputs, inputs, "{}", r.target);
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
