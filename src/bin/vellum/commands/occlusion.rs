//! `vellum occlusion`.

use crate::args::*;
use crate::commands::{context, passes_json, report_validation, together};
use crate::flags::*;
use anyhow::{Context as _, Result};
use serde_json::json;
use vellum::team::Team;

pub(crate) fn occlusion((cli, team): (&Cli, &dyn Team), a: &OcclusionArgs) -> Result<()> {
    let (input, radius, mapping, stride) = (&a.input, a.radius, a.mapping.as_str(), a.stride);
    let (out, spectrum_png, spectrum_csv) = (
        a.out.as_deref(),
        a.spectrum.as_deref(),
        a.spectrum_data.as_deref(),
    );
    let (bins, method, json) = (a.bins, a.method.as_str(), a.json);
    use vellum::passes::occlusion::{parse_mapping, Method, Occlusion, OcclusionParams};
    let (visibility, neighbourhood) = parse_mapping(mapping)?;
    let method = Method::parse(method)?;
    let want_spectrum = spectrum_png.is_some() || spectrum_csv.is_some() || json;
    let params = OcclusionParams {
        radius,
        visibility,
        neighbourhood,
        stride,
        spectrum_bins: want_spectrum.then_some([bins, bins]),
        method,
        pad: None,
    };
    use super::chunked::{plan, Plan};
    let bytes = vellum::passes::chunked::OCCLUSION_BYTES;
    let v = match plan(team, input, out, &a.chunking, radius as usize, bytes, &[])? {
        Plan::InCore(_) if !team.is_root() => return Ok(()),
        Plan::InCore(v) => v,
        Plan::Chunked { source, plan } => {
            return occlusion_chunked((cli, team), a, &source, &params, plan);
        }
    };
    let ctx = context(cli)?;
    let start = std::time::Instant::now();
    let r = Occlusion::new(&ctx)?.compute(&v, &params)?;
    let wall_ms = start.elapsed().as_secs_f64() * 1e3;
    report_validation(&ctx);
    if let Some(path) = out {
        vellum::volume::io::write(path, &r.occlusion)
            .with_context(|| format!("writing the occlusion volume to {}", path.display()))?;
    }
    if let Some(s) = &r.spectrum {
        write_spectrum(s, spectrum_png, spectrum_csv)?;
    }
    let stats = vellum::volume::stats::stats(&r.occlusion, 0);
    let passes = passes_json(&r.passes);
    if json {
        let out = json!({
            "device": ctx.info.name, "radius": radius, "mapping": mapping, "stride": stride, "dims": v.dims,
            "occlusion_dims": r.occlusion.dims, "occlusion_range": [stats.min, stats.max], "passes": passes, "total_ms": wall_ms,
            "method": r.method.name(),
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!(
            "occlusion of {} (R = {radius}, {mapping}, stride {stride}, method {}) on {}",
            input.input,
            r.method.name(),
            ctx.info.name
        );
        println!(
            "  occlusion {}x{}x{}, range {:.4} .. {:.4}",
            r.occlusion.dims[0], r.occlusion.dims[1], r.occlusion.dims[2], stats.min, stats.max
        );
        for p in &r.passes {
            println!("  {:<18} {:>10.3} ms", p.name, p.ms);
        }
        println!("  {:<18} {wall_ms:>10.3} ms", "total");
    }
    Ok(())
}

/// `occlusion` chunk by chunk into a store, with the whole grid's spectrum.
fn occlusion_chunked(
    (cli, team): (&Cli, &dyn Team),
    a: &OcclusionArgs,
    source: &super::convert::Source,
    params: &vellum::passes::occlusion::OcclusionParams,
    plan: vellum::passes::chunked::Plan,
) -> Result<()> {
    let ctx = together(team, context(cli))?;
    let out = a
        .out
        .as_deref()
        .ok_or_else(|| anyhow::anyhow!("a chunked pass needs --out"))?;
    let range = together(team, source.range())?;
    let boxes = source.boxes()?;
    let grid = (boxes.dims(), plan.chunk);
    let ((store, spectrum), secs) =
        super::chunked::run_with_bar(team, &ctx, grid, "occlusion chunks", |on_chunk| {
            vellum::passes::chunked::occlusion_store(
                (team, &ctx),
                &*boxes,
                params,
                range,
                out,
                plan,
                on_chunk,
            )
        })?;
    if !team.is_root() {
        return Ok(());
    }
    if let Some(s) = &spectrum {
        write_spectrum(s, a.spectrum.as_deref(), a.spectrum_data.as_deref())?;
    }
    let mut r = super::chunked::report(team, &ctx, &store, plan, params.radius as usize, secs);
    r["intensity_range"] = json!(range);
    r["spectrum_total"] =
        json!(spectrum
            .as_ref()
            .map(|s| s.counts.iter().map(|&c| c as u64).sum::<u64>()));
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "occlusion of {} (R = {}) on {}, chunk by chunk: {r}",
            a.input.input, params.radius, ctx.info.name
        );
    }
    Ok(())
}

/// Writes the spectrum as a PNG and as CSV, where asked.
fn write_spectrum(
    s: &vellum::passes::occlusion::Spectrum,
    png: Option<&std::path::Path>,
    csv: Option<&std::path::Path>,
) -> Result<()> {
    let b = [s.bins[0] as usize, s.bins[1] as usize];
    if let Some(path) = png {
        let c = vellum::plot::histogram_2d(
            &s.counts,
            b,
            "INTENSITY",
            s.intensity_range,
            "OCCLUSION",
            [0.0, 1.0],
        );
        vellum::output::write_png_rgb(path, c.width as u32, c.height as u32, &c.rgb)?;
    }
    if let Some(path) = csv {
        s.write_csv(path)?;
    }
    Ok(())
}

pub(crate) fn occlusion_select(
    cli: &Cli,
    input: &InputArgs,
    interval: &str,
    radius: u32,
    stride: u32,
    method: &str,
    json: bool,
) -> Result<()> {
    let interval = parse_interval(interval)?;
    let method = vellum::passes::occlusion::Method::parse(method)?;
    let v = input.load()?;
    let ctx = context(cli)?;
    let mut occ = vellum::passes::occlusion::Occlusion::new(&ctx)?;
    let start = std::time::Instant::now();
    let sel =
        vellum::passes::occlusion_analysis::select(&mut occ, &v, interval, radius, stride, method)?;
    report_validation(&ctx);
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(
                &json!({ "device": ctx.info.name, "selection": sel, "total_ms": start.elapsed().as_secs_f64() * 1e3 })
            )?
        );
        return Ok(());
    }
    let b = &sel.best;
    println!(
        "adaptive mapping for {}:{} ({} voxels, R = {radius}, stride {stride}) on {}",
        interval[0], interval[1], sel.voxels_in_interval, ctx.info.name
    );
    println!(
        "  best: --mapping truncated:{},{}  (data {:.1}..{:.1}), score {:.3e}, k = {}, means {:?}",
        b.t0,
        b.t1,
        b.t0_value,
        b.t1_value,
        b.score,
        b.k,
        b.means
            .iter()
            .map(|m| format!("{m:.3}"))
            .collect::<Vec<_>>()
    );
    println!("  every candidate (t0, t1 as fractions of the range), best first:");
    for c in &sel.candidates {
        println!(
            "    {:.3} {:.3}  score {:.4e}  k {}",
            c.t0, c.t1, c.score, c.k
        );
    }
    println!("  took {:.0} ms", start.elapsed().as_secs_f64() * 1e3);
    Ok(())
}

pub(crate) fn occlusion_sensitivity(cli: &Cli, a: &SensitivityArgs) -> Result<()> {
    let (input, radii, bands, stride) = (&a.input, a.radii.as_slice(), a.bands, a.stride);
    let (method, out, csv) = (a.method.as_str(), a.out.as_path(), a.csv.as_deref());
    use vellum::passes::occlusion::{Method, OcclusionParams};
    anyhow::ensure!(
        !radii.is_empty() && bands > 0,
        "give at least one radius and one band"
    );
    let method = Method::parse(method)?;
    let v = input.load()?;
    let ctx = context(cli)?;
    let mut occ = vellum::passes::occlusion::Occlusion::new(&ctx)?;
    let largest = radii.iter().copied().max().unwrap_or(16);
    let stride = if stride == 0 {
        // Full resolution when an FFT method serves the largest radius there (its cost does not
        // grow with R); otherwise the runs method's cost calls for a coarser output.
        let p = OcclusionParams::ball(largest, method);
        match occ.choose(v.dims, &p, false)? {
            Method::FftCpu | Method::FftGpu => 1,
            _ => (largest / 16).max(1),
        }
    } else {
        stride
    };
    let rows = vellum::passes::occlusion_analysis::sensitivity(
        &mut occ, &v, radii, bands, stride, method,
    )?;
    report_validation(&ctx);
    let c = vellum::passes::occlusion_analysis::sensitivity_plot(&rows);
    vellum::output::write_png_rgb(out, c.width as u32, c.height as u32, &c.rgb)?;
    if let Some(path) = csv {
        vellum::passes::occlusion_analysis::write_sensitivity_csv(&rows, path)?;
    }
    println!(
        "sensitivity of {} over radii {radii:?} (stride {stride}, {bands} bands) written to {}",
        input.input,
        out.display()
    );
    Ok(())
}
