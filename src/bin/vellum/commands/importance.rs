//! `vellum importance` and `vellum normals`.

use crate::args::*;
use crate::commands::{context, report_validation, together};
use anyhow::{Context as _, Result};
use serde_json::json;
use vellum::team::Team;

pub(crate) fn importance(
    (cli, team): (&Cli, &dyn Team),
    input: &InputArgs,
    radius: u32,
    (out, slices): (Option<&std::path::Path>, Option<&std::path::Path>),
    chunking: &ChunkArgs,
    json: bool,
) -> Result<()> {
    use super::chunked::{plan, Plan};
    let bytes = vellum::passes::chunked::IMPORTANCE_BYTES;
    let whole = [("--slices", slices.is_some())];
    let v = match plan(team, input, out, chunking, radius as usize, bytes, &whole)? {
        Plan::InCore(_) if !team.is_root() => return Ok(()),
        Plan::InCore(v) => v,
        Plan::Chunked { source, plan } => {
            let ctx = together(team, context(cli))?;
            let out = out.ok_or_else(|| anyhow::anyhow!("a chunked pass needs --out"))?;
            let boxes = source.boxes()?;
            let grid = (boxes.dims(), plan.chunk);
            let (store, secs) =
                super::chunked::run_with_bar(team, &ctx, grid, "importance chunks", |on_chunk| {
                    vellum::passes::chunked::importance_store(
                        (team, &ctx),
                        &*boxes,
                        radius,
                        out,
                        plan,
                        on_chunk,
                    )
                })?;
            let mut r = super::chunked::report(team, &ctx, &store, plan, radius as usize, secs);
            r["max_abs_delta_d"] = json!(store.range[0].abs().max(store.range[1].abs()));
            if !team.is_root() {
                return Ok(());
            }
            if json {
                println!("{}", serde_json::to_string_pretty(&r)?);
            } else {
                println!(
                    "importance map of {} (R = {radius}) on {}, chunk by chunk: {}",
                    input.input, ctx.info.name, r
                );
            }
            return Ok(());
        }
    };
    let ctx = context(cli)?;
    let mut map = vellum::passes::importance::ImportanceMap::new(&ctx)?;
    let r = map.compute(&v, radius, false)?;
    report_validation(&ctx);
    if let Some(path) = out {
        vellum::volume::io::write(path, &r.delta_d)
            .with_context(|| format!("writing ΔD to {}", path.display()))?;
    }
    if let Some(path) = slices {
        let limit = vellum::volume::slices::abs_quantile(
            (0..r.delta_d.len()).map(|i| r.delta_d.data.get_f64(i)),
            0.995,
        );
        let (w, h, rgb) = vellum::volume::slices::thermal_slices(&r.delta_d, limit);
        vellum::output::write_png_rgb(path, w, h, &rgb)?;
    }
    let passes = super::passes_json(&r.passes);
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(
                &json!({ "device": ctx.info.name, "radius": radius, "dims": v.dims, "passes": passes, "total_ms": r.total_ms })
            )?
        );
    } else {
        let s = vellum::volume::stats::stats(&r.delta_d, 0);
        println!(
            "importance map of {} (R = {radius}) on {}",
            input.input, ctx.info.name
        );
        println!("  ΔD range {:.4} .. {:.4}", s.min, s.max);
        for p in &r.passes {
            println!("  {:<9} {:>9.3} ms", p.name, p.ms);
        }
        println!(
            "  total     {:>9.3} ms (conversion, allocation, upload, passes, readback)",
            r.total_ms
        );
    }
    Ok(())
}

/// `vellum normals`: always chunk by chunk into a store (the normals have four channels, which
/// only the store holds).
pub(crate) fn normals(
    (cli, team): (&Cli, &dyn Team),
    input: &InputArgs,
    out: &std::path::Path,
    chunking: &ChunkArgs,
    json: bool,
) -> Result<()> {
    use vellum::passes::chunked::{normals_store, NORMALS_BYTES, NORMALS_HALO};
    anyhow::ensure!(
        super::chunked::is_store_path(out),
        "{} is not a store; the normals are written as an OME-Zarr store of four channels, expected --out x.ome.zarr",
        out.display()
    );
    let (source, dims) = super::chunked::open_shared(team, input)?;
    let boxes = source.boxes()?;
    let plan = super::chunked::chunk_plan(chunking, dims, NORMALS_HALO, NORMALS_BYTES)?;
    let ctx = together(team, context(cli))?;
    let range = together(team, source.range())?;
    let grid = (dims, plan.chunk);
    let (store, secs) =
        super::chunked::run_with_bar(team, &ctx, grid, "normal chunks", |on_chunk| {
            normals_store((team, &ctx), &*boxes, range, out, plan, on_chunk)
        })?;
    if !team.is_root() {
        return Ok(());
    }
    let mut r = super::chunked::report(team, &ctx, &store, plan, NORMALS_HALO, secs);
    r["voxels_per_second"] = json!(dims.iter().product::<usize>() as f64 / secs.max(1e-9));
    r["intensity_range"] = json!(range);
    if json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "normals of {} on {}, chunk by chunk: {r}",
            input.input, ctx.info.name
        );
    }
    Ok(())
}
