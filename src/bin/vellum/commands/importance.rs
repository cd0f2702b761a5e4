//! `vellum importance`.

use crate::args::*;
use crate::commands::{context, report_validation};
use anyhow::{Context as _, Result};
use serde_json::json;

pub(crate) fn importance(
    cli: &Cli,
    input: &InputArgs,
    radius: u32,
    out: Option<&std::path::Path>,
    slices: Option<&std::path::Path>,
    json: bool,
) -> Result<()> {
    let v = input.load()?;
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
