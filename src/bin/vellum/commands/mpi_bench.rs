//! `vellum bench mpi` (issue 27): each step is an `mpirun -n N` job of this binary (built with the
//! `mpi` feature), so the figures are the jobs' own: strong scaling of the chunked importance
//! map and occlusion on a phantom streamed into a store, and the compositing of a shared frame
//! against N, the image size and the exchange (direct send, binary swap), with its bytes.

use anyhow::{Context as _, Result};
use serde_json::{json, Value};
use std::path::Path;

/// Runs `mpirun -n ranks vellum ARGS --json` (oversubscribed: N may exceed the cores) and parses
/// rank 0's report.
fn job(ranks: usize, args: &[&str]) -> Result<Value> {
    let exe = std::env::current_exe().context("finding this binary")?;
    let mut c = std::process::Command::new("mpirun");
    c.args(["--allow-run-as-root", "--oversubscribe", "-n"])
        .arg(ranks.to_string())
        .arg(exe)
        .args(args)
        .arg("--json");
    let what = format!("mpirun -n {ranks} vellum {}", args.join(" "));
    super::scale::report_of(c, &what)
}

/// The strong-scaling rows: the chunked importance map (R = 10) and occlusion (R = 16) of
/// `store` by each count of `ranks`.
fn passes(store: &str, ranks: &[usize], chunk: &str, dir: &Path) -> Result<Vec<Value>> {
    let mut rows = Vec::new();
    for &n in ranks {
        for (pass, radius) in [("importance", "10"), ("occlusion", "16")] {
            let out = dir.join(format!("{pass}_{n}.ome.zarr"));
            let _ = std::fs::remove_dir_all(&out);
            let o = out.to_string_lossy().to_string();
            let args = [
                pass, store, "--radius", radius, "--out", &o, "--chunk", chunk,
            ];
            let r = job(n, &args)?;
            let _ = std::fs::remove_dir_all(&out);
            eprintln!(
                "{pass} by {n} ranks: {:.2} s",
                r["seconds"].as_f64().unwrap_or(0.0)
            );
            rows.push(
                json!({ "pass": pass, "ranks": n, "seconds": r["seconds"], "chunk": r["chunk"] }),
            );
        }
    }
    Ok(rows)
}

/// The compositing rows: a two-level frame of `store` at each image size, by each count of
/// ranks above one, by each exchange that applies.
fn compositing(store: &str, ranks: &[usize], images: &[u32], dir: &Path) -> Result<Vec<Value>> {
    let png = dir.join("frame.png").to_string_lossy().to_string();
    let mut rows = Vec::new();
    for &size in images {
        let s = format!("{size}x{size}");
        for &n in ranks.iter().filter(|&&n| n > 1) {
            let mut ways = vec!["direct-send"];
            if n.is_power_of_two() {
                ways.push("binary-swap");
            }
            for how in ways {
                let mut args = super::scale::render_args(store, &s, &png);
                args.extend(["--composite", how]);
                let r = job(n, &args)?;
                let c = &r["compositing"];
                eprintln!(
                    "{size}² by {n} ranks, {how}: {:.1} ms",
                    c["ms"].as_f64().unwrap_or(0.0)
                );
                rows.push(json!({
                    "image": size, "ranks": n, "exchange": how, "ms": c["ms"], "over_ms": c["over_ms"],
                    "bytes_sent": c["bytes_sent"], "raycast_ms": r["passes"]["raycast"],
                }));
            }
        }
    }
    Ok(rows)
}

pub(crate) fn mpi(
    (size, chunk): (usize, usize),
    ranks: &[usize],
    images: &[u32],
    (dir, keep, json): (&Path, bool, bool),
) -> Result<()> {
    anyhow::ensure!(
        ranks.iter().all(|&n| (1..=1024).contains(&n)),
        "--ranks {ranks:?} is invalid; expected counts from 1 to 1024"
    );
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let dir = &std::path::absolute(dir).with_context(|| format!("resolving {}", dir.display()))?;
    let store = dir.join(format!("mpi_{size}.ome.zarr"));
    let _ = std::fs::remove_dir_all(&store);
    let s = store.to_string_lossy().to_string();
    let phantom = format!("phantom:shepp-logan:{size}");
    let write = job(1, &["convert", &phantom, &s, "--chunk", "64"])?;
    let chunk = chunk.to_string();
    let pass_rows = passes(&s, ranks, &chunk, dir)?;
    let frame_rows = compositing(&s, ranks, images, dir)?;
    if !keep {
        let _ = std::fs::remove_dir_all(&store);
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let report = json!({
        "store": size, "cores": cores, "write": write, "passes": pass_rows, "compositing": frame_rows,
    });
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!("{size}³ store, {cores} cores (ranks beyond them are oversubscribed)");
    for r in &pass_rows {
        println!(
            "  {:<10} {:>2} ranks {:>8.2} s",
            r["pass"].as_str().unwrap_or(""),
            r["ranks"],
            r["seconds"].as_f64().unwrap_or(0.0)
        );
    }
    for r in &frame_rows {
        println!(
            "  {:>5}² {:>2} ranks {:<11} {:>8.1} ms {:>8.1} MiB sent",
            r["image"],
            r["ranks"],
            r["exchange"].as_str().unwrap_or(""),
            r["ms"].as_f64().unwrap_or(0.0),
            r["bytes_sent"].as_f64().unwrap_or(0.0) / (1 << 20) as f64
        );
    }
    Ok(())
}
