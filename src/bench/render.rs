//! `vellum bench render` (SPEC TL8, two-level paper Fig. 9): frames per second of the slice
//! renderer at several sizes, one pass against two levels, and the two-level overhead in percent
//! (the paper measured 16–40 %). Frame time is the sum of the GPU passes of one frame (`one_pass`,
//! or `focus` + `context` + `composite`), without readback, after one warm-up frame.
//!
//! Data: the CT head (cthead_stanford, 256×256×113, iso 1300 with ct-skin-bone) and the engine
//! (256×256×128, iso 180 with grey) from ../shared/data; without the data, the Shepp–Logan
//! phantom stands in and the row says so.

use crate::bench::{median, shared_data};
use crate::classify::transfer::TransferFunction;
use crate::error::{Error, Result};
use crate::gpu::{Context, PassTime, Profiler};
use crate::passes::normals::Normals;
use crate::render::camera::Camera;
use crate::render::slicer::{Focus, RenderParams, Renderer};
use crate::volume::{io, phantom, Volume};
use serde::Serialize;
use std::sync::Arc;

/// Options of `vellum bench render`.
#[derive(Clone, Debug)]
pub struct Options {
    pub repeat: usize,
    pub sizes: Vec<u32>,
}

/// One row: a volume at one size.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub data: String,
    pub size: u32,
    pub slices: u32,
    pub one_pass_ms: f64,
    pub two_level_ms: f64,
    pub one_pass_fps: f64,
    pub two_level_fps: f64,
    /// Median over frame pairs of (two-level − one-pass) / one-pass, in percent; the frames of a
    /// pair run back to back.
    pub overhead_percent: f64,
    /// Median ms of each pass of the two-level frame.
    pub focus_ms: f64,
    pub context_ms: f64,
    pub composite_ms: f64,
}

/// The table.
#[derive(Clone, Debug, Serialize)]
pub struct Table {
    pub device: String,
    pub repeat: usize,
    /// ms of `sobel_normals` per volume, computed once before the frames.
    pub normals_ms: Vec<(String, f64)>,
    pub rows: Vec<Row>,
}

fn volume(name: &str) -> Result<(Volume, String)> {
    if let Some(root) = shared_data() {
        let path = root.join("volumes").join(name).join(format!("{name}.nhdr"));
        if path.exists() {
            return Ok((io::load(&path, None)?, name.to_string()));
        }
    }
    if std::env::var("CI").as_deref() == Ok("true") {
        return Err(Error::Invalid(format!(
            "../shared/data is missing; the render bench needs {name} under CI"
        )));
    }
    Ok((
        phantom::shepp_logan(256),
        format!("shepp-logan 256 (standing in for {name})"),
    ))
}

fn frame_ms(passes: &[PassTime]) -> f64 {
    passes
        .iter()
        .filter(|p| p.name != "readback")
        .map(|p| p.ms)
        .sum()
}

/// Runs the benchmark.
pub fn run(ctx: &Arc<Context>, opts: &Options) -> Result<Table> {
    let renderer = Renderer::new(ctx)?;
    let normals = Normals::new(ctx)?;
    let mut rows = Vec::new();
    let mut normals_ms = Vec::new();
    for (name, iso, tf) in [
        ("cthead_stanford", 1300.0, "ct-skin-bone"),
        ("engine", 180.0, "grey"),
    ] {
        let (v, label) = volume(name)?;
        let mut profiler = Profiler::new(ctx, 2)?;
        let textures = normals.prepare(&v, &mut profiler)?;
        normals_ms.push((
            label.clone(),
            crate::gpu::profiler::total_ms(&profiler.results()?, "sobel_normals"),
        ));
        let focus = if label == name {
            Focus::Iso(iso)
        } else {
            Focus::Iso(0.9)
        };
        for &size in &opts.sizes {
            let params = |one_pass| RenderParams {
                camera: Camera::parse("30,20,2.5").expect("valid camera"),
                size: [size, size],
                slices: None,
                focus,
                one_pass,
                transfer: TransferFunction::preset(tf).expect("preset exists"),
                occlusion_tf: None,
            };
            // One pass and two levels alternate frame by frame, so that both see the same
            // machine: CPU devices drift in speed over seconds.
            let (p1, p2) = (params(true), params(false));
            let slices = renderer.render(&textures, &p1, false)?.slices;
            renderer.render(&textures, &p2, false)?;
            let (mut one, mut two) = (Vec::new(), Vec::new());
            for _ in 0..opts.repeat {
                one.push(renderer.render(&textures, &p1, false)?.passes);
                two.push(renderer.render(&textures, &p2, false)?.passes);
            }
            // The overhead as the median of per-pair ratios, robust to drift between pairs.
            let ratios: Vec<f64> = one
                .iter()
                .zip(&two)
                .map(|(o, t)| frame_ms(t) / frame_ms(o))
                .collect();
            let one_ms = median(&one.iter().map(|p| frame_ms(p)).collect::<Vec<_>>());
            let two_ms = median(&two.iter().map(|p| frame_ms(p)).collect::<Vec<_>>());
            let pass = |n: &str| {
                median(
                    &two.iter()
                        .map(|p| crate::gpu::profiler::total_ms(p, n))
                        .collect::<Vec<_>>(),
                )
            };
            log::info!("bench render: {label} {size}² one {one_ms:.1} ms, two {two_ms:.1} ms");
            rows.push(Row {
                data: label.clone(),
                size,
                slices,
                one_pass_ms: one_ms,
                two_level_ms: two_ms,
                one_pass_fps: 1000.0 / one_ms,
                two_level_fps: 1000.0 / two_ms,
                overhead_percent: 100.0 * (median(&ratios) - 1.0),
                focus_ms: pass("focus"),
                context_ms: pass("context"),
                composite_ms: pass("composite"),
            });
        }
    }
    Ok(Table {
        device: ctx.info.name.clone(),
        repeat: opts.repeat,
        normals_ms,
        rows,
    })
}

impl Table {
    /// The table as text.
    pub fn to_text(&self) -> String {
        let mut s = format!(
            "Slice renderer frame rate on {}, median of {} frame(s)\n",
            self.device, self.repeat
        );
        for (d, ms) in &self.normals_ms {
            s += &format!("sobel_normals {d}: {ms:.1} ms (once per volume)\n");
        }
        s += "data                 size  slices | one pass ms   fps | two levels ms   fps | overhead | focus  context  composite ms\n";
        for r in &self.rows {
            s += &format!(
                "{:<20} {:>4}² {:>6} | {:>11.1} {:>5.2} | {:>13.1} {:>5.2} | {:>7.1}% | {:>6.1} {:>8.1} {:>10.1}\n",
                r.data, r.size, r.slices, r.one_pass_ms, r.one_pass_fps, r.two_level_ms, r.two_level_fps, r.overhead_percent, r.focus_ms, r.context_ms, r.composite_ms
            );
        }
        s
    }
}
