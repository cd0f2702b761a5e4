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

pub(crate) fn info(input: &InputArgs, json: bool) -> Result<()> {
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
    println!("orientation: {}", g.orientation_code());
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
