//! `vellum styles`.

use crate::args::*;
use crate::commands::{context, report_validation};
use crate::flags::*;
use anyhow::{Context as _, Result};
use serde_json::json;
use vellum::classify::modulation::Modulation;
use vellum::classify::Focus;
use vellum::render::scene::GpuScene;

pub(crate) fn styles(cli: &Cli, a: &StylesArgs) -> Result<()> {
    use vellum::render::view::{Lighting, View};
    let focus = parse_focus(a.focus.as_deref(), a.iso)?;
    anyhow::ensure!(
        focus != Focus::None,
        "the styles work on a focus; give --iso V or --focus LO:HI"
    );
    let size = parse_size(&a.size)?;
    anyhow::ensure!(
        size.iter().all(|&s| (16..=2048).contains(&s)),
        "--size {}x{} is invalid; expected 16..=2048 pixels per side",
        size[0],
        size[1]
    );
    let background = parse_rgb("--background", &a.background)?;
    let classification = match a.tf.as_str() {
        vellum::classify::window::AUTO => vellum::classify::Classification::Auto,
        tf => vellum::classify::Classification::Transfer(
            vellum::classify::transfer::TransferFunction::from_arg(tf)?,
        ),
    };
    let view = View {
        camera: vellum::render::camera::Camera::parse(&a.camera)?,
        size,
        slices: None,
        one_pass: false,
        lighting: Lighting::default(),
        style: None,
        fit: a.camera.split(',').count() == 2,
        raycast: match a.renderer.as_deref() {
            None | Some("slicer") => None,
            Some("raycast") => Some(vellum::render::raycast::RayOptions::default()),
            Some(other) => {
                anyhow::bail!("--renderer {other:?} is unknown; expected slicer or raycast")
            }
        },
    };
    let ctx = context(cli)?;
    let budget = vellum::render::bricked::gpu_budget_bytes(&ctx, None)?;
    let input = (a.input.input.as_str(), a.input.pick());
    let v = vellum::render::session::in_core_only(input, (budget, None), "styles", || {
        a.input
            .load()
            .map_err(|e| vellum::error::Error::Invalid(format!("{e:#}")))
    })?;
    let mut scene = GpuScene::prepare(&ctx, &v, &classification, focus, &Modulation::default())?;
    let (sheet, tiles) = vellum_tools::figures::style_gallery(
        &ctx,
        &mut scene,
        &view,
        {
            let mut p = vellum::render::style::StyleParams::default();
            if let Some(c) = &a.edge_color {
                p.edge_color = parse_rgb("--edge-color", c)?;
            }
            if let Some(r) = a.line_smooth {
                p.line_smooth = r;
                p.validate()?;
            }
            p
        },
        background,
        a.saliency,
    )?;
    report_validation(&ctx);
    // Everything is rendered; now the files.
    vellum::output::write_png_rgb(&a.out, sheet.width as u32, sheet.height as u32, &sheet.rgb)?;
    if let Some(dir) = &a.out_dir {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        for t in &tiles {
            if let Some(f) = &t.frame {
                let stem = format!("style{:02}_{}", t.def.number, t.def.name.replace('+', "_"));
                vellum::output::write_png_rgb(
                    &dir.join(format!("{stem}.png")),
                    size[0],
                    size[1],
                    &vellum::render::targets::to_rgb8(&f.composite, background),
                )?;
                if a.exr {
                    f.write_exr(&dir.join(format!("{stem}.exr")))?;
                }
            }
        }
    }
    let baseline = tiles
        .iter()
        .find(|t| t.def.number == 15)
        .and_then(|t| t.saliency);
    let rows: Vec<serde_json::Value> = tiles
        .iter()
        .map(|t| {
            json!({
                "number": t.def.number, "name": t.def.name, "rendered": t.frame.is_some(),
                "reason": t.def.unavailable_reason(),
                "passes": t.frame.as_ref().map(|f| super::passes_json(&f.passes)),
                "saliency_focus": t.saliency.map(|s| s.0), "saliency_context": t.saliency.map(|s| s.1),
                "focus_share": t.saliency.map(|s| s.0 / (s.0 + s.1)),
            })
        })
        .collect();
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(
                &json!({ "device": ctx.info.name, "input": a.input.input, "styles": rows })
            )?
        );
        return Ok(());
    }
    println!(
        "styles of {} on {} written to {}",
        a.input.input,
        ctx.info.name,
        a.out.display()
    );
    for t in &tiles {
        match (&t.frame, t.saliency) {
            (None, _) => println!(
                "  {:>2} {:<34} not rendered: {}",
                t.def.number,
                t.def.name,
                t.def.unavailable_reason().unwrap_or_default()
            ),
            (Some(_), Some((i, o))) => {
                let share = i / (i + o);
                let vs = baseline.map_or(String::new(), |(bi, bo)| {
                    format!(" ({:+.3} against style 15)", share - bi / (bi + bo))
                });
                println!("  {:>2} {:<34} saliency focus {i:.4} context {o:.4} focus share {share:.3}{vs}", t.def.number, t.def.name);
            }
            (Some(_), None) => println!("  {:>2} {}", t.def.number, t.def.name),
        }
    }
    Ok(())
}

pub(crate) fn saliency(
    image: &std::path::Path,
    mask: Option<&std::path::Path>,
    out: Option<&std::path::Path>,
    json: bool,
) -> Result<()> {
    let img = image::open(image)
        .with_context(|| format!("reading the image {}", image.display()))?
        .to_rgb8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    anyhow::ensure!(
        w >= 16 && h >= 16,
        "{} is {w}x{h}; the saliency metric needs at least 16x16 pixels",
        image.display()
    );
    let rgb: Vec<[f32; 3]> = img
        .pixels()
        .map(|p| p.0.map(|c| c as f32 / 255.0))
        .collect();
    let map = vellum::imaging::saliency::saliency(&rgb, w, h);
    let inside = match mask {
        Some(m) => {
            let mimg = image::open(m)
                .with_context(|| format!("reading the mask {}", m.display()))?
                .to_rgb8();
            anyhow::ensure!(
                (mimg.width() as usize, mimg.height() as usize) == (w, h),
                "the mask {} is {}x{} but the image is {w}x{h}",
                m.display(),
                mimg.width(),
                mimg.height()
            );
            let mask: Vec<bool> = mimg.pixels().map(|p| p.0.iter().any(|&c| c > 0)).collect();
            Some(vellum::imaging::saliency::inside_outside(&map, &mask))
        }
        None => None,
    };
    if let Some(path) = out {
        let bytes: Vec<u8> = map
            .data
            .iter()
            .flat_map(|&v| vellum::plot::heat(v as f64))
            .collect();
        vellum::output::write_png_rgb(path, w as u32, h as u32, &bytes)?;
    }
    let (peak_at, _) = map
        .data
        .iter()
        .enumerate()
        .fold((0, f32::MIN), |b, (i, &v)| if v > b.1 { (i, v) } else { b });
    let peak = [peak_at % w, peak_at / w];
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({
                "image": image.display().to_string(), "size": [w, h], "most_salient": peak,
                "mean_inside": inside.map(|s| s.0), "mean_outside": inside.map(|s| s.1),
            }))?
        );
    } else {
        println!(
            "saliency of {} ({w}x{h}): most salient point at {}, {}",
            image.display(),
            peak[0],
            peak[1]
        );
        if let Some((i, o)) = inside {
            println!(
                "  mean inside the mask {i:.4}, outside {o:.4}, inside share {:.3}",
                i / (i + o)
            );
        }
    }
    Ok(())
}
