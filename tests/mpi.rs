//! MPI (issue 27), with the `mpi` feature, under Open MPI's `mpirun` (oversubscribed on this
//! machine's cores), validation and synchronization validation on in every rank:
//! - chunked importance (R = 10, the real engine block) and occlusion (R = 16 with its spectrum,
//!   the real neghip) written by 2, 3 and 4 ranks are the single process's stores byte for byte,
//!   every chunk and every level; the normals by 3 ranks too;
//! - a corrupt chunk that one rank reads ends the job with one sentence naming that rank and the
//!   chunk's key, leaves no output, and does not hang (every run is under a time limit);
//! - a rank that cannot open its input, or that was given another input, ends the job before any
//!   work, in one sentence.
#![cfg(feature = "mpi")]

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Seconds any one job may take before the test fails (a hang would otherwise stall CI).
const LIMIT: &str = "300";

/// `mpirun -n ranks vellum args…` under a time limit, with what `common::vellum` sets.
fn mpirun(ranks: usize, args: &[&str]) -> Output {
    let mut c = launcher(ranks);
    c.arg(env!("CARGO_BIN_EXE_vellum")).args(args);
    c.output().expect("run mpirun")
}

/// `timeout LIMIT mpirun --oversubscribe -n ranks`, allowed to run as root (CI containers are).
fn launcher(ranks: usize) -> Command {
    let mut c = Command::new("timeout");
    c.args([
        LIMIT,
        "mpirun",
        "--allow-run-as-root",
        "--oversubscribe",
        "-n",
    ])
    .arg(ranks.to_string())
    .env("VELLUM_VALIDATION", "1")
    .env_remove("RUST_BACKTRACE");
    c
}

/// The job's report (rank 0 prints it), after checking that it succeeded and that no rank's
/// validation layer spoke.
fn ok_job(out: &Output) -> serde_json::Value {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("validation layer"), "{stderr}");
    serde_json::from_slice(&out.stdout).expect("one JSON report, from rank 0")
}

/// The job failed, not by the time limit (status 124), with exactly one `error:` line, which
/// contains every phrase.
fn failed_job(out: &Output, phrases: &[&str]) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "succeeded: {stderr}");
    assert_ne!(out.status.code(), Some(124), "hung: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let errors: Vec<&str> = stderr
        .lines()
        .filter(|l| l.starts_with("error: "))
        .collect();
    assert_eq!(errors.len(), 1, "one sentence: {stderr}");
    for p in phrases {
        assert!(errors[0].contains(p), "expected '{p}' in {}", errors[0]);
    }
}

/// Every file under `root`, by its path inside it.
fn files(root: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut todo = vec![root.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                todo.push(p);
            } else {
                let rel = p.strip_prefix(root).unwrap().to_path_buf();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

/// Runs `args` (with `{out}` replaced by a store path) alone and by each of `ranks`, and
/// asserts that every store is the lone process's, byte for byte.
fn same_store_for(ranks: &[usize], args: &[&str], dir: &Path) -> serde_json::Value {
    let run = |n: usize| {
        // The same store name in each folder: the name is written into the metadata.
        let out = dir.join(format!("n{n}")).join("out.ome.zarr");
        std::fs::create_dir_all(out.parent().unwrap()).unwrap();
        let o = out.to_str().unwrap().to_string();
        let args: Vec<&str> = args
            .iter()
            .map(|a| if *a == "{out}" { o.as_str() } else { a })
            .collect();
        let report = match n {
            0 => common::ok_json(&common::vellum(&args)),
            n => ok_job(&mpirun(n, &args)),
        };
        (files(&out), report)
    };
    let (alone, report) = run(0);
    assert!(alone.len() > 8, "{} files", alone.len());
    for &n in ranks {
        let (shared, r) = run(n);
        assert_eq!(r["ranks"], n, "{r}");
        assert_eq!(shared.len(), alone.len(), "{n} ranks: the same files");
        for ((pa, a), (pb, b)) in alone.iter().zip(&shared) {
            assert_eq!(pa, pb);
            assert!(a == b, "{n} ranks: {} differs", pa.display());
        }
        println!("{n} ranks: {} files, byte for byte", shared.len());
    }
    report
}

/// A real volume streamed into a store with `chunk`-voxel chunks; `None` without
/// ../shared/data (which fails under CI).
fn real_store(name: &str, chunk: &str, dir: &Path) -> Option<String> {
    let root = common::shared_data()?;
    let input = root.join(format!("volumes/{name}/{name}.nhdr"));
    let store = dir.join(format!("{name}.ome.zarr"));
    let s = store.to_str().unwrap().to_string();
    let out = common::vellum(&["convert", input.to_str().unwrap(), &s, "--chunk", chunk]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(s)
}

/// A two-rank job whose ranks run `importance` on different inputs, `first` and `second`, into
/// `out` (two programs of one mpirun, `A : B`).
fn two_programs(first: &str, second: &str, out: &str) -> Output {
    let exe = env!("CARGO_BIN_EXE_vellum");
    launcher(1)
        .args([exe, "importance", first, "--out", out, ":", "-n", "1"])
        .args([exe, "importance", second, "--out", out])
        .output()
        .unwrap()
}

/// `phantom:NAME` streamed into a store at `path` with `chunk`-voxel chunks.
fn phantom_store(name: &str, chunk: &str, path: &Path) -> PathBuf {
    let p = path.to_str().unwrap();
    let spec = format!("phantom:{name}");
    common::ok_json(&common::vellum(&[
        "convert", &spec, p, "--chunk", chunk, "--json",
    ]));
    path.to_path_buf()
}

#[test]
fn chunked_importance_and_normals_by_many_ranks_are_the_single_process_stores() {
    let dir = tempfile::tempdir().unwrap();
    let Some(engine) = real_store("engine", "64", dir.path()) else {
        return;
    };
    let args = [
        "importance",
        &engine,
        "--radius",
        "10",
        "--out",
        "{out}",
        "--chunk",
        "64",
        "--json",
    ];
    let r = same_store_for(&[2, 3, 4], &args, &dir.path().join("importance"));
    assert!(r["max_abs_delta_d"].as_f64().unwrap() > 0.0, "{r}");
    let args = [
        "normals", &engine, "--out", "{out}", "--chunk", "64", "--json",
    ];
    same_store_for(&[3], &args, &dir.path().join("normals"));
}

#[test]
fn chunked_occlusion_by_many_ranks_is_the_single_process_store_with_its_spectrum() {
    let dir = tempfile::tempdir().unwrap();
    let Some(neghip) = real_store("neghip", "32", dir.path()) else {
        return;
    };
    // Run by 3 ranks into `o3.ome.zarr` too, for the spectrum.
    let o3 = dir.path().join("o3.ome.zarr");
    let [args, mut again] = [0, 1].map(|_| {
        let a = ["occlusion", &neghip, "--radius", "16", "--out", "{out}"];
        a.into_iter()
            .chain(["--chunk", "32", "--json"])
            .collect::<Vec<_>>()
    });
    again[5] = o3.to_str().unwrap();
    let alone = same_store_for(&[2, 4], &args, &dir.path().join("occlusion"));
    // The spectrum is summed over the ranks: every voxel counted once.
    let total = ok_job(&mpirun(3, &again))["spectrum_total"].clone();
    assert_eq!(total, 64 * 64 * 64);
    assert_eq!(alone["spectrum_total"], total);
}

#[test]
fn a_failing_rank_ends_the_job_in_one_sentence_with_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let store = phantom_store("shepp-logan:96", "32", &dir.path().join("in.ome.zarr"));
    let s = store.to_str().unwrap();
    // The last chunk of the grid is corrupt: with 4 ranks, the last rank reads it.
    std::fs::write(store.join("0/c/2/2/2"), b"not zstd").unwrap();
    let out = dir.path().join("dd.ome.zarr");
    let o = out.to_str().unwrap();
    let job = mpirun(
        4,
        &[
            "importance",
            s,
            "--radius",
            "5",
            "--out",
            o,
            "--chunk",
            "32",
        ],
    );
    failed_job(&job, &["rank 3 of 4 failed", "chunk 0/c/2/2/2"]);
    assert!(!out.exists());
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".vellum"))
        .collect();
    assert!(left.is_empty(), "temporary folders left: {left:?}");

    // Rank 1 of an MPMD job cannot open its input: found before any work.
    let missing = dir.path().join("missing.ome.zarr");
    let job = two_programs(s, missing.to_str().unwrap(), o);
    failed_job(&job, &["rank 1 of 2 failed", "missing.ome.zarr"]);
    // Rank 1 was given another store of the same grid: refused.
    let other = phantom_store("nested:96", "64", &dir.path().join("other.ome.zarr"));
    let job = two_programs(s, other.to_str().unwrap(), o);
    failed_job(&job, &["rank 1 of 2 failed", "differ from rank 0's"]);
    assert!(!out.exists());
}

/// Mean and max absolute difference of two PNGs' 8-bit channels, in 1/255.
fn png_diff(a: &Path, b: &Path) -> (f64, u8) {
    let (a, b) = (
        image::open(a).unwrap().to_rgb8(),
        image::open(b).unwrap().to_rgb8(),
    );
    assert_eq!(a.dimensions(), b.dimensions());
    let d: Vec<u8> = a
        .iter()
        .zip(b.iter())
        .map(|(x, y)| x.abs_diff(*y))
        .collect();
    let mean = d.iter().map(|&x| x as f64).sum::<f64>() / d.len() as f64;
    (mean, d.iter().copied().max().unwrap_or(0))
}

#[test]
fn a_frame_shared_by_1_to_8_ranks_is_the_single_process_frame() {
    let dir = tempfile::tempdir().unwrap();
    let store = phantom_store("shepp-logan:128", "64", &dir.path().join("head.ome.zarr"));
    let s = store.to_str().unwrap();
    // Through a 2 MiB brick cache, so each rank streams the bricks of its own region.
    let scene = [
        s,
        "--tf",
        "grey",
        "--camera",
        "30,20,2.5",
        "--size",
        "128x128",
    ];
    let scene = scene
        .into_iter()
        .chain(["--renderer", "raycast", "--gpu-budget", "2"]);
    let frames: [(&str, Vec<&str>, &[usize]); 3] = [
        ("two levels", vec!["--iso", "0.9"], &[1, 2, 3, 4, 8]),
        ("one pass", vec!["--one-pass"], &[3]),
        (
            "style 3 (canny)",
            vec!["--iso", "0.9", "--style", "canny"],
            &[2, 4],
        ),
    ];
    for (what, extra, ranks) in frames {
        let args = |out: &Path| -> Vec<String> {
            let out = out.to_str().unwrap().to_string();
            let mut a = vec!["render".to_string()];
            a.extend(
                scene
                    .clone()
                    .chain(extra.iter().copied())
                    .map(str::to_string),
            );
            a.extend(["--out".into(), out, "--json".into()]);
            a
        };
        let alone = dir.path().join("alone.png");
        let a = args(&alone);
        common::ok_json(&common::vellum(
            &a.iter().map(String::as_str).collect::<Vec<_>>(),
        ));
        for &n in ranks {
            let shared = dir.path().join(format!("shared{n}.png"));
            let a = args(&shared);
            let r = ok_job(&mpirun(
                n,
                &a.iter().map(String::as_str).collect::<Vec<_>>(),
            ));
            assert_eq!(r["ranks"], n);
            let (mean, max) = png_diff(&alone, &shared);
            println!(
                "{what}, {n} ranks ({}): mean {mean:.4}/255, max {max}/255",
                r["compositing"]
            );
            assert!(
                mean <= 1.0 && max <= 8,
                "{what}, {n} ranks: mean {mean}, max {max}"
            );
        }
    }
}
