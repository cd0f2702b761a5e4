//! `vellum view`.

use crate::args::*;
#[cfg(feature = "viewer")]
use crate::flags::*;
use anyhow::Result;
#[cfg(feature = "viewer")]
use std::path::PathBuf;

/// Without the `viewer` feature (a build for a machine with no window): one sentence.
#[cfg(not(feature = "viewer"))]
pub(crate) fn view(_cli: &Cli, _a: &ViewArgs) -> Result<()> {
    anyhow::bail!(
        "this vellum was built without its viewer (cargo feature `viewer`, which `make run` leaves out); expected a build with the default features for `vellum view`: `make view` or `cargo build --release`"
    )
}

#[cfg(feature = "viewer")]
pub(crate) fn view(cli: &Cli, a: &ViewArgs) -> Result<()> {
    let scene = a.scene.view_scene()?;
    let window_size = match &a.scene.size {
        Some(s) => parse_size(s)?,
        None => [1100, 700],
    };
    if let Some(0) = a.bench {
        anyhow::bail!("--bench 0 is invalid; expected a number of frames of 1 or more");
    }
    anyhow::ensure!(
        a.json <= a.bench.is_some(),
        "--json prints the report of --bench N; add --bench"
    );
    anyhow::ensure!(
        a.bench_full <= a.bench.is_some(),
        "--bench-full changes the orbit of --bench N; add --bench"
    );
    anyhow::ensure!(
        a.bench_log.is_none() || a.bench.is_some(),
        "--bench-log writes the frames of --bench N; add --bench"
    );
    if let Some(p) = &a.screenshot_on_exit {
        vellum::output::check_extension(p, &["png"], "a PNG image")?;
    }
    if let Some(p) = &a.bench_log {
        vellum::output::check_extension(p, &["csv"], "the bench's frames as CSV")?;
        // Refused before the window opens, not after the orbit.
        let folder = p.parent().filter(|f| !f.as_os_str().is_empty());
        anyhow::ensure!(
            folder.is_none_or(|f| f.is_dir()),
            "--bench-log {}: its folder does not exist; expected a path in an existing folder",
            p.display()
        );
    }
    let screenshot_dir = a
        .screenshot_dir
        .clone()
        .unwrap_or_else(|| PathBuf::from("."));
    anyhow::ensure!(
        screenshot_dir.is_dir(),
        "--screenshot-dir {} is not a folder; expected an existing folder",
        screenshot_dir.display()
    );
    // The viewer's files (screenshots, scenes) land when they are made, each atomically, not at
    // the end of the command: close the command's all-or-nothing transaction.
    anyhow::ensure!(
        a.play_rate.is_finite() && (0.1..=1000.0).contains(&a.play_rate),
        "--play-rate {} is out of range; expected time points per second from 0.1 to 1000",
        a.play_rate
    );
    vellum::output::commit()?;
    let report = vellum::viewer::run(vellum::viewer::ViewOptions {
        scene,
        device: cli.device.clone(),
        window_size,
        screenshot_dir,
        screenshot_on_exit: a.screenshot_on_exit.clone(),
        vsync: !a.no_vsync,
        bench_frames: a.bench.map(|n| n + 5),
        bench_full: a.bench_full,
        bench_rows: a.bench_log.is_some(),
        gpu_budget: a.gpu_budget,
        memory_budget: a.memory_budget,
        play: a.play,
        play_rate: a.play_rate,
    })?;
    if let Some(r) = report {
        if let Some(p) = &a.bench_log {
            vellum::output::write_atomic(p, |w| vellum::viewer::FrameRow::write_csv(&r.rows, w))?;
        }
        if a.json {
            println!("{}", serde_json::to_string_pretty(&r)?);
        } else {
            println!(
                "{} at {}x{} ({} quality, rendered at {}x{}) on {}: {:.1} fps over {} frames; frame time p50 {:.2} ms, p95 {:.2} ms, p99 {:.2} ms",
                r.input, r.size[0], r.size[1], r.quality, r.render_size[0], r.render_size[1], r.device, r.fps, r.frames, r.p50_ms, r.p95_ms, r.p99_ms
            );
            for (name, ms) in &r.gpu_ms {
                println!("  {name:<14} {ms:>9.3} ms (median GPU)");
            }
            if let Some(ms) = r.first_frame_ms {
                println!("  first frame {ms:.0} ms after the window's device was ready");
            }
            if let Some(s) = &r.streaming {
                println!("  {s}");
            }
            if let (Some(a), Some(b)) = (r.rss_kib.first(), r.rss_kib.last()) {
                println!(
                    "  resident set {:.1} MiB after frame {}, {:.1} MiB after frame {}",
                    a.1 as f64 / 1024.0,
                    a.0,
                    b.1 as f64 / 1024.0,
                    b.0
                );
            }
        }
    }
    Ok(())
}
