//! `vellum info`.

use crate::args::*;
use crate::commands::{context, report_validation};
use anyhow::Result;
use serde_json::json;
use vellum::gpu::ContextDesc;

pub(crate) fn devices(cli: &Cli, json: bool) -> Result<()> {
    let (candidates, chosen) = vellum::gpu::context::probe_devices(&ContextDesc {
        validation: Some(false),
        device: cli.device.clone(),
    })?;
    let selector = ContextDesc {
        validation: None,
        device: cli.device.clone(),
    }
    .device_selector();
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({ "devices": candidates, "chosen": chosen }))?
        );
        if chosen.is_none() {
            anyhow::bail!(
                "no device matches{}; the listing above gives each device's reason",
                selector.map_or(String::new(), |s| format!(" the selector {s:?}"))
            );
        }
        return Ok(());
    }
    for c in &candidates {
        let mark = if Some(c.index) == chosen { "*" } else { " " };
        println!(
            "{mark} [{}] {} ({}, Vulkan {}, driver {})",
            c.index, c.name, c.device_type, c.api_version, c.driver
        );
        if let Some(r) = &c.rejected {
            println!("      rejected: {r}");
        }
    }
    if chosen.is_none() {
        match selector {
            Some(s) => anyhow::bail!(
                "no device matches the selector {s:?}; expected an index or part of a name from the list above"
            ),
            None => anyhow::bail!("no listed device can be used (see the reasons above)"),
        }
    }
    Ok(())
}

/// Voxels of the finest level `info` reads whole for a store's statistics: 16 Mi (64 MiB of
/// floats), so that a store of any size is described in bounded time and memory.
const STATS_VOXELS: usize = 1 << 24;

/// A store: its levels, and the statistics of its finest level of at most [`STATS_VOXELS`]
/// voxels (level 0 itself when it is that small). Level 0 is never read whole otherwise.
fn store_summary(
    ms: &vellum::volume::io::ome_zarr::Multiscale,
    pick: vellum::volume::io::ome_zarr::Pick,
    json: bool,
) -> Result<()> {
    let level = ms
        .finest_within(STATS_VOXELS)
        .unwrap_or(ms.levels.len() - 1);
    let v = ms.read_level(level)?;
    let s = vellum::volume::stats::stats(&v, 16);
    let levels: Vec<_> = ms
        .levels
        .iter()
        .map(|l| json!({"path": l.path, "dims": l.dims, "chunk": l.chunk, "spacing": l.spacing, "origin": l.origin}))
        .collect();
    if json {
        let out = json!({
            "input": ms.root, "ngff": ms.version, "voxel_type": ms.voxel, "channels": ms.channels, "times": ms.times, "levels": levels,
            "range": ms.range, "statistics_level": level,
            "statistics": {"min": s.min, "max": s.max, "mean": s.mean, "histogram": s.histogram},
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    let (t, c) = (pick.time.unwrap_or(0), pick.channel.unwrap_or(0));
    let channels = match (ms.times, ms.channels) {
        (1, 1) => String::new(),
        (1, n) => format!(", {n} channels; the statistics below are channel {c}'s"),
        (times, 1) => format!(", {times} time points; the statistics below are time point {t}'s"),
        (times, n) => format!(
            ", {times} time points of {n} channels; the statistics below are time point {t}'s, channel {c}"
        ),
    };
    println!(
        "input:   {} (OME-NGFF {}, {}{channels})",
        ms.root.display(),
        ms.version,
        ms.voxel.name()
    );
    for l in &ms.levels {
        println!(
            "level {}: {} x {} x {}, chunks {} x {} x {}, spacing {} x {} x {}",
            l.path,
            l.dims[0],
            l.dims[1],
            l.dims[2],
            l.chunk[0],
            l.chunk[1],
            l.chunk[2],
            l.spacing[0],
            l.spacing[1],
            l.spacing[2]
        );
    }
    if let Some([lo, hi]) = ms.range {
        println!("range:   {lo} .. {hi} (level 0, as recorded when written)");
    }
    let of = match level {
        0 => "level 0".to_string(),
        l => format!("level {l}, the finest of at most {STATS_VOXELS} voxels: extremes finer than its voxels may not show"),
    };
    let channel = match ms.channels {
        1 => "",
        _ => ", channel 0",
    };
    println!(
        "statistics of {of}{channel}: min {} max {} mean {:.4}",
        s.min, s.max, s.mean
    );
    Ok(())
}

pub(crate) fn info(input: &InputArgs, json: bool) -> Result<()> {
    use vellum::volume::io::ome_zarr;
    let path = std::path::Path::new(&input.input);
    if ome_zarr::is_store(path) && input.raw.spec()?.is_none() {
        // A store of several channels or time points is described whole, with the statistics
        // of the one picked (channel 0 at time 0 unless --channel and --time say).
        let pick = ome_zarr::Pick {
            time: Some(input.time.unwrap_or(0)),
            channel: Some(input.channel.unwrap_or(0)),
        };
        let ms = ome_zarr::Multiscale::open_picked(path, pick)?;
        return store_summary(&ms, pick, json);
    }
    let v = input.load()?;
    let s = vellum::volume::stats::stats(&v, 16);
    if json {
        let out = json!({
            "input": input.input, "dims": v.dims, "voxel_type": v.voxel_type(), "spacing": v.spacing,
            "origin": v.geometry.origin, "direction": v.geometry.direction,
            "orientation": v.geometry.orientation_code(), "space": v.geometry.space,
            "min": s.min, "max": s.max, "mean": s.mean, "histogram": s.histogram, "sha256": v.sha256_hex(),
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!("input:   {}", input.input);
    println!(
        "dims:    {} x {} x {} ({} voxels)",
        v.dims[0],
        v.dims[1],
        v.dims[2],
        v.len()
    );
    println!("type:    {}", v.voxel_type().name());
    println!(
        "spacing: {} x {} x {}",
        v.spacing[0], v.spacing[1], v.spacing[2]
    );
    let g = &v.geometry;
    println!(
        "origin:  {} {} {} (LPS, mm)",
        g.origin[0], g.origin[1], g.origin[2]
    );
    for (r, row) in g.direction.iter().enumerate() {
        println!(
            "{}{:>10.6} {:>10.6} {:>10.6}",
            if r == 0 { "direction: " } else { "           " },
            row[0],
            row[1],
            row[2]
        );
    }
    match g.is_oriented() {
        true => println!("orientation: {}", g.orientation_code()),
        false => println!(
            "orientation: unknown: {}",
            vellum::volume::geometry::Geometry::UNKNOWN_ORIENTATION
        ),
    }
    println!("range:   {} .. {}", s.min, s.max);
    println!("mean:    {:.4}", s.mean);
    println!("sha256:  {}", v.sha256_hex());
    println!("histogram (16 bins over the range):");
    let peak = s.histogram.iter().copied().max().unwrap_or(1).max(1);
    let width = (s.max - s.min) / 16.0;
    for (i, &c) in s.histogram.iter().enumerate() {
        let bar = "#".repeat(((c as f64 / peak as f64) * 40.0).ceil() as usize);
        println!("  {:>12.3} {:>10}  {bar}", s.min + i as f64 * width, c);
    }
    Ok(())
}

pub(crate) fn roundtrip(cli: &Cli, input: &InputArgs, json: bool) -> Result<()> {
    let v = input.load()?;
    let ctx = context(cli)?;
    let r = vellum::passes::volume_image::round_trip(&ctx, &v)?;
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({ "device": ctx.info.name, "round_trip": r }))?
        );
    } else {
        let ms = |n: &str| vellum::gpu::profiler::total_ms(&r.passes, n);
        println!(
            "GPU round trip on {}: {} bytes, upload {:.2} ms, readback {:.2} ms, {}",
            ctx.info.name,
            r.bytes,
            ms("upload"),
            ms("readback"),
            if r.bit_exact { "bit-exact" } else { "MISMATCH" }
        );
    }
    report_validation(&ctx);
    anyhow::ensure!(
        r.bit_exact,
        "the volume read back from the GPU differs from what was uploaded"
    );
    Ok(())
}
