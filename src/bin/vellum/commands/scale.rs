//! `vellum bench scale` (issue 26): each step runs this binary as a child process, so that every
//! row's host peak (VmHWM) and device peak (the allocator's) are that step's alone.

use anyhow::{Context as _, Result};
use serde_json::{json, Value};
use std::path::Path;

/// Runs `vellum ARGS --json` and parses its report.
fn child(args: &[&str]) -> Result<Value> {
    let exe = std::env::current_exe().context("finding this binary")?;
    let mut c = std::process::Command::new(exe);
    c.args(args).arg("--json");
    report_of(c, &format!("vellum {}", args.join(" ")))
}

/// A bricked render's step: its report with the floor of its streaming measured after the frame
/// (the same chunks decoded plainly, and their bytes uploaded). Its budgets hold the store's
/// intensity, so the session is held to stored gradients (`VELLUM_GRADIENTS_AT_SAMPLE=0`): else it
/// would draw it in core with the gradients made at each sample.
fn bricked(args: &[&str]) -> Result<Value> {
    let exe = std::env::current_exe().context("finding this binary")?;
    let mut c = std::process::Command::new(exe);
    c.args(args)
        .args(["--json", "--first-frame", "--time-whole-frame"])
        .env("VELLUM_STREAM_FLOOR", "1")
        .env("VELLUM_GRADIENTS_AT_SAMPLE", "0");
    report_of(c, &format!("vellum {}", args.join(" ")))
}

/// Runs a bench step and parses the JSON it prints; its stderr in one sentence when it fails.
pub(crate) fn report_of(mut step: std::process::Command, what: &str) -> Result<Value> {
    let out = step
        .output()
        .with_context(|| format!("running the bench step `{what}`"))?;
    if !out.status.success() {
        anyhow::bail!(
            "bench step `{what}` failed: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    Ok(serde_json::from_slice(&out.stdout)?)
}

/// The render's flags for a store at a square image of `image` pixels.
pub(crate) fn render_args<'a>(store: &'a str, size: &'a str, png: &'a str) -> Vec<&'a str> {
    let mut a = vec![
        "render",
        store,
        "--iso",
        "0.9",
        "--tf",
        "grey",
        "--camera",
        "30,20,2.5",
    ];
    a.extend(["--size", size, "--renderer", "raycast", "--out", png]);
    a
}

/// One size: the store written, rendered through the cache (held to stored gradients, [`bricked`])
/// (where it fits in core, at level 0 everywhere through a pool just below (0.99×) the in-core
/// need of intensity and stored gradients, against the in-core frame; above,
/// through 2 GiB (or half the level's need, when that is less) at level 0 everywhere and by the
/// level-of-detail rule), and the importance map chunked against in core where it fits.
fn row(n: usize, image: u32, dir: &Path) -> Result<Value> {
    let store = dir.join(format!("scale_{n}.ome.zarr"));
    let s = store.to_string_lossy().to_string();
    let phantom = format!("phantom:shepp-logan:{n}");
    let write = child(&["convert", &phantom, &s])?;
    let size = format!("{image}x{image}");
    let png = dir
        .join(format!("scale_{n}.png"))
        .to_string_lossy()
        .to_string();
    let in_core_mib = (n as f64).powi(3) * 10.0 / (1 << 20) as f64;
    let mut row = json!({ "n": n, "write": write });
    if n <= 512 {
        let mut a = render_args(&s, &size, &png);
        let big = format!("{}", in_core_mib * 1.5);
        a.extend(["--gpu-budget", big.as_str()]);
        row["in_core"] = child(&a)?;
        // The same samples as in core (level 0 everywhere), through a pool just below (0.99×) the
        // in-core need, for the frame-time ratio.
        let mut a = render_args(&s, &size, &png);
        let small = format!("{}", in_core_mib * 0.99);
        a.extend(["--gpu-budget", small.as_str(), "--lod", "finest"]);
        row["bricked"] = bricked(&a)?;
        let dd = dir
            .join(format!("dd_{n}.ome.zarr"))
            .to_string_lossy()
            .to_string();
        row["importance_in_core"] = child(&["importance", &phantom, "--radius", "5"])?;
        row["importance_chunked"] = child(&[
            "importance",
            &phantom,
            "--radius",
            "5",
            "--out",
            &dd,
            "--chunk",
            "128",
        ])?;
    } else {
        let budget = format!("{}", (in_core_mib / 2.0).min(2048.0));
        for (key, lod) in [("bricked", "finest"), ("bricked_auto", "auto")] {
            let mut a = render_args(&s, &size, &png);
            a.extend(["--gpu-budget", budget.as_str(), "--lod", lod]);
            row[key] = bricked(&a)?;
        }
    }
    Ok(row)
}

fn ms(v: &Value, path: &[&str]) -> Option<f64> {
    path.iter().try_fold(v, |v, k| v.get(k))?.as_f64()
}

/// One line of the text table.
fn line(r: &Value) -> String {
    let f = |x: Option<f64>, d: usize| x.map_or("-".into(), |x| format!("{x:.d$}"));
    let b = &r["bricked"];
    // The last frame's ray casting is a whole frame's only when the frame's bricks all fit.
    let whole = b["bricks"]["whole_frame"].as_bool() == Some(true);
    let raycast = ms(b, &["passes", "raycast"]).filter(|_| whole);
    let core = ms(&r["in_core"], &["passes", "raycast"]);
    let ratio = raycast.zip(core).map(|(b, c)| b / c);
    let stream = |b: &Value| {
        let g = |k: &str| ms(b, &["bricks", k]);
        let floor = b["bricks"]["floor"].is_object().then(|| {
            let f = |k: &str| ms(b, &["bricks", "floor", k]).unwrap_or(0.0);
            f("decode_ms") + f("upload_ms")
        });
        format!(
            "{} loads/touched {:>5}, {:>6} MiB/s, both busy {:>3}%, first {:>6} ms, complete {:>7} ms, floor {:>7} ms",
            b["bricks"].get("passes").map_or("-".into(), |p| format!("{p:>4} passes")),
            f(g("loads_per_touched"), 3),
            f(g("source_mib_per_s"), 0),
            f(g("both_share").map(|x| 100.0 * x), 0),
            f(g("first_frame_ms"), 0),
            f(g("total_ms"), 0),
            f(floor, 0),
        )
    };
    let imp_core = ms(&r["importance_in_core"], &["total_ms"]);
    let imp_chunk = ms(&r["importance_chunked"], &["seconds"]).map(|s| s * 1e3);
    let mut out = format!(
        "{:>5}³ | {:>7} MiB/s {:>6} s | {:>7} ms {:>8} ms {:>8} MiB | {:>6} {:>7} MiB | {:>7} ms {:>7} ms {:>5} | {:>5}\n",
        r["n"],
        f(ms(&r["write"], &["mib_per_s"]), 0),
        f(ms(&r["write"], &["seconds"]), 1),
        f(ms(b, &["bricks", "first_pass_ms"]), 0),
        f(ms(b, &["bricks", "total_ms"]), 0),
        f(ms(b, &["bricks", "bytes_streamed"]).map(|x| x / (1 << 20) as f64), 0),
        f(ms(b, &["peak_rss_mib"]), 0),
        f(ms(b, &["peak_device_mib"]), 0),
        f(raycast, 1),
        f(core, 1),
        f(ratio, 2),
        f(imp_core.zip(imp_chunk).map(|(c, k)| c / k), 2),
    );
    for key in ["bricked", "bricked_auto"] {
        if r[key].is_object() {
            out.push_str(&format!("       {key}: {}\n", stream(&r[key])));
        }
    }
    out
}

pub(crate) fn scale(sizes: &[usize], image: u32, dir: &Path, keep: bool, json: bool) -> Result<()> {
    anyhow::ensure!(
        sizes.iter().all(|&n| (1..=16384).contains(&n)),
        "--sizes {sizes:?} is invalid; expected phantom sizes from 1 to 16384"
    );
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    // Absolute, so that no path handed to a step can be read as a flag (`--dir -7`).
    let dir = &std::path::absolute(dir).with_context(|| format!("resolving {}", dir.display()))?;
    let mut rows = Vec::new();
    for &n in sizes {
        for name in [format!("scale_{n}.ome.zarr"), format!("dd_{n}.ome.zarr")] {
            let _ = std::fs::remove_dir_all(dir.join(name));
        }
        rows.push(row(n, image, dir)?);
        if !keep {
            for name in [format!("scale_{n}.ome.zarr"), format!("dd_{n}.ome.zarr")] {
                let _ = std::fs::remove_dir_all(dir.join(name));
            }
        }
    }
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({ "image": image, "rows": rows }))?
        );
        return Ok(());
    }
    println!(
        "    n | store write rate, time | first pass, complete frame, streamed | host, device peak | raycast bricked, in core, ratio | importance chunked / in core (voxels/s)"
    );
    for r in &rows {
        print!("{}", line(r));
    }
    Ok(())
}
