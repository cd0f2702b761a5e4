//! `vellum bench occlusion`: ambient occlusion's cost against the radius for each method (issue
//! 16), on a 256³ volume at full resolution, beside the cost model's estimate, a plain copy of the
//! spectrum's bytes, and optionally scipy's FFT convolution as a peer.

use crate::bench::{median, shared_data};
use serde::Serialize;
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::Context;
use vellum_render::passes::occlusion::{
    estimate_ms, Method, Occlusion, OcclusionInput, OcclusionParams,
};
use vellum_render::passes::occlusion_fft::{
    cpu_bytes, denominator_entries, gpu::gpu_bytes, padded_dims,
};
use vellum_volume::reference::occlusion::Visibility;
use vellum_volume::{io, phantom, Volume, VoxelData};

pub struct Options {
    /// A volume path or phantom spec; default the bonsai (256³), else a 256³ phantom.
    pub input: Option<String>,
    pub radii: Vec<u32>,
    pub methods: Vec<Method>,
    /// A method whose estimate exceeds this is not run (its estimate is reported).
    pub max_seconds: f64,
    /// Run scipy.signal.fftconvolve on the same input (benches/ao_peer.py).
    pub scipy: bool,
}

/// One (radius, method) measurement.
#[derive(Clone, Debug, Serialize)]
pub struct Cell {
    pub method: Method,
    /// Wall milliseconds of the computation (upload excluded, readback included), or `None` when
    /// skipped because the estimate exceeded the limit.
    pub ms: Option<f64>,
    pub estimate_ms: f64,
    /// The method's working memory by its own accounting (bytes).
    pub memory_bytes: u64,
    pub passes: Vec<(String, f64)>,
}

#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub radius: u32,
    pub pad: [usize; 3],
    pub cells: Vec<Cell>,
    /// scipy.signal.fftconvolve (numerator and denominator), median ms, and its largest
    /// difference from our CPU FFT result.
    pub scipy_ms: Option<f64>,
    pub scipy_max_diff: Option<f64>,
}

#[derive(Clone, Debug, Serialize)]
pub struct Table {
    pub device: String,
    pub threads: usize,
    pub data: String,
    pub dims: [usize; 3],
    pub rows: Vec<Row>,
    /// ms of one memcpy of the largest half spectrum (the bytes every FFT pass must touch).
    pub spectrum_copy_ms: f64,
    pub spectrum_bytes: u64,
    /// The smallest radius at which the fastest FFT method beats runs (measured, else estimated).
    pub crossover_radius: Option<u32>,
    /// Per FFT method: (largest − smallest) / median of its times over R = 16…100.
    pub flatness: Vec<(Method, f64)>,
    /// Peak resident memory of this process (VmHWM), bytes.
    pub peak_rss_bytes: Option<u64>,
}

fn source(input: &Option<String>) -> Result<(Volume, String)> {
    if let Some(spec) = input {
        return Ok((vellum_volume::input::load(spec, None)?, spec.clone()));
    }
    if let Some(root) = shared_data() {
        let path = root.join("volumes/bonsai/bonsai.nhdr");
        if path.exists() {
            return Ok((io::load(&path, None)?, "bonsai (256³ u8)".into()));
        }
    }
    if std::env::var("CI").as_deref() == Ok("true") {
        return Err(Error::Invalid(
            "../shared/data is missing; bench occlusion needs the bonsai under CI".into(),
        ));
    }
    Ok((phantom::shepp_logan(256), "shepp-logan phantom 256³".into()))
}

fn peak_rss() -> Option<u64> {
    vellum_volume::memory::peak_resident_kib().map(|k| k * 1024)
}

/// scipy's FFT occlusion of `mapped` at `r`: (ms, result).
fn scipy_peer(mapped: &[f32], dims: [usize; 3], r: u32) -> Option<(f64, Vec<f32>)> {
    let dir = std::env::temp_dir().join(format!("vellum-ao-peer-{}", std::process::id()));
    std::fs::create_dir_all(&dir).ok()?;
    let (input, output) = (dir.join("mapped.f32"), dir.join("ao.f32"));
    std::fs::write(&input, bytemuck::cast_slice::<f32, u8>(mapped)).ok()?;
    let mut args: Vec<std::ffi::OsString> = vec![input.into()];
    args.extend(dims.iter().map(|d| d.to_string().into()));
    args.push(r.to_string().into());
    args.push(output.clone().into());
    let result = crate::bench::python_peer("ao_peer.py", &args).and_then(|json| {
        let bytes = std::fs::read(&output).ok()?;
        Some((
            json["median_ms"].as_f64()?,
            bytemuck::pod_collect_to_vec(&bytes),
        ))
    });
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// The working memory of `method` on `dims` at `radius`, by its own accounting.
fn memory(method: Method, dims: [usize; 3], radius: u32) -> u64 {
    let (pad, entries) = (padded_dims(dims, radius), denominator_entries(dims, radius));
    let volume = dims.iter().map(|&d| d as u64).product::<u64>() * 4;
    match method {
        Method::Runs => 3 * volume,
        Method::FftGpu => gpu_bytes(dims, pad, 1, entries) + 2 * volume,
        _ => cpu_bytes(dims, pad, 1, entries),
    }
}

/// One untimed computation per GPU method at the smallest radius, so that building pipelines
/// (the FFT's are made on first use) and the driver's first touches of memory stay out of the
/// figures, as the render benches keep their first frames out.
fn warm_up(ctx: &Arc<Context>, input: &OcclusionInput, opts: &Options) -> Result<()> {
    let Some(&radius) = opts.radii.iter().min() else {
        return Ok(());
    };
    for &method in &opts.methods {
        let p = OcclusionParams::ball(radius, method);
        let estimate = estimate_ms(method, &ctx.info.device_type, input.dims, &p);
        if method != Method::FftCpu && estimate <= opts.max_seconds * 1e3 {
            Occlusion::new(ctx)?.compute_on(input, &p)?;
        }
    }
    Ok(())
}

pub fn run(ctx: &Arc<Context>, opts: &Options) -> Result<Table> {
    let (v, data) = source(&opts.input)?;
    let dims = v.dims;
    let ty = ctx.info.device_type.clone();
    let input = OcclusionInput::upload(ctx, &v)?;
    let mapped: Vec<f32> = input
        .host
        .as_ref()
        .map(|h| h.iter().map(|&s| Visibility::Ramp.apply(s)).collect())
        .unwrap_or_default();
    let mut rows = Vec::new();
    let progress = vellum_render::progress::bar(
        (opts.radii.len() * opts.methods.len()) as u64,
        "radius × method",
    );
    warm_up(ctx, &input, opts)?;
    for &radius in &opts.radii {
        let pad = padded_dims(dims, radius);
        let p = OcclusionParams::ball(radius, Method::Auto);
        let mut cells = Vec::new();
        let mut cpu_result: Option<Vec<f32>> = None;
        for &method in &opts.methods {
            progress.inc(1);
            let estimate = estimate_ms(method, &ty, dims, &p);
            let memory_bytes = memory(method, dims, radius);
            if estimate > opts.max_seconds * 1e3 {
                cells.push(Cell {
                    method,
                    ms: None,
                    estimate_ms: estimate,
                    memory_bytes,
                    passes: vec![],
                });
                continue;
            }
            // A fresh pass object: no kernel or data spectrum carried over from another radius.
            let mut occ = Occlusion::new(ctx)?;
            let start = std::time::Instant::now();
            let out = occ.compute_on(
                &input,
                &OcclusionParams {
                    method,
                    ..p.clone()
                },
            )?;
            let ms = start.elapsed().as_secs_f64() * 1e3;
            if method == Method::FftCpu {
                if let VoxelData::F32(o) = out.occlusion.data {
                    cpu_result = Some(o);
                }
            }
            cells.push(Cell {
                method,
                ms: Some(ms),
                estimate_ms: estimate,
                memory_bytes,
                passes: out.passes.iter().map(|t| (t.name.clone(), t.ms)).collect(),
            });
        }
        let (scipy_ms, scipy_max_diff) = match opts
            .scipy
            .then(|| scipy_peer(&mapped, dims, radius))
            .flatten()
        {
            Some((ms, theirs)) => (
                Some(ms),
                cpu_result.as_ref().map(|ours| {
                    ours.iter()
                        .zip(&theirs)
                        .map(|(a, b)| (a - b).abs() as f64)
                        .fold(0.0, f64::max)
                }),
            ),
            None => (None, None),
        };
        rows.push(Row {
            radius,
            pad,
            cells,
            scipy_ms,
            scipy_max_diff,
        });
    }
    progress.finish_and_clear();
    // A plain copy of the largest half spectrum.
    let largest = opts.radii.iter().copied().max().unwrap_or(1);
    let pad = padded_dims(dims, largest);
    let n = (pad[0] / 2 + 1) * pad[1] * pad[2] * 2;
    let src = vec![1f32; n];
    let mut dst = vec![0f32; n];
    let copies: Vec<f64> = (0..3)
        .map(|_| {
            let t = std::time::Instant::now();
            dst.copy_from_slice(&src);
            std::hint::black_box(&dst);
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    let time = |c: &Cell| c.ms.unwrap_or(c.estimate_ms);
    let crossover_radius = rows.iter().find_map(|r| {
        let runs = r
            .cells
            .iter()
            .find(|c| c.method == Method::Runs)
            .map(time)?;
        let fft = r
            .cells
            .iter()
            .filter(|c| c.method != Method::Runs)
            .map(time)
            .fold(f64::INFINITY, f64::min);
        (fft < runs).then_some(r.radius)
    });
    let flatness = opts
        .methods
        .iter()
        .filter(|&&m| m != Method::Runs)
        .filter_map(|&m| {
            let ts: Vec<f64> = rows
                .iter()
                .filter(|r| r.radius >= 16)
                .filter_map(|r| r.cells.iter().find(|c| c.method == m)?.ms)
                .collect();
            if ts.len() < 2 {
                return None;
            }
            let (lo, hi) = ts
                .iter()
                .fold((f64::INFINITY, 0f64), |(a, b), &t| (a.min(t), b.max(t)));
            Some((m, (hi - lo) / median(&ts)))
        })
        .collect();
    Ok(Table {
        device: ctx.info.name.clone(),
        threads: rayon::current_num_threads(),
        data,
        dims,
        rows,
        spectrum_copy_ms: median(&copies),
        spectrum_bytes: n as u64 * 4,
        crossover_radius,
        flatness,
        peak_rss_bytes: peak_rss(),
    })
}

impl Table {
    pub fn to_text(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "ambient occlusion (ball, ramp, full resolution) of {} {:?} on {} ({} CPU threads)",
            self.data, self.dims, self.device, self.threads
        );
        let methods: Vec<Method> = self
            .rows
            .first()
            .map(|r| r.cells.iter().map(|c| c.method).collect())
            .unwrap_or_default();
        let _ = write!(s, "{:>5} {:>16}", "R", "padded");
        for m in &methods {
            let _ = write!(
                s,
                " {:>12} {:>11} {:>9}",
                format!("{} ms", m.name()),
                "model ms",
                "MiB"
            );
        }
        let _ = writeln!(s, " {:>10} {:>10}", "scipy ms", "scipy Δ");
        for r in &self.rows {
            let _ = write!(s, "{:>5} {:>16}", r.radius, format!("{:?}", r.pad));
            for c in &r.cells {
                let ms = c.ms.map_or("skipped".to_string(), |m| format!("{m:.0}"));
                let _ = write!(
                    s,
                    " {:>12} {:>11.0} {:>9.0}",
                    ms,
                    c.estimate_ms,
                    c.memory_bytes as f64 / 1048576.0
                );
            }
            let _ = writeln!(
                s,
                " {:>10} {:>10}",
                r.scipy_ms.map_or("-".into(), |m| format!("{m:.0}")),
                r.scipy_max_diff.map_or("-".into(), |d| format!("{d:.1e}"))
            );
        }
        let _ = writeln!(
            s,
            "copy of the largest half spectrum ({:.0} MiB): {:.1} ms",
            self.spectrum_bytes as f64 / 1048576.0,
            self.spectrum_copy_ms
        );
        let _ = writeln!(
            s,
            "crossover (an FFT method beats runs from): {}",
            self.crossover_radius
                .map_or("none in these radii".into(), |r| format!("R = {r}"))
        );
        for (m, f) in &self.flatness {
            let _ = writeln!(
                s,
                "{} spread over R = 16..: {:.0} % of its median",
                m.name(),
                f * 100.0
            );
        }
        if let Some(b) = self.peak_rss_bytes {
            let _ = writeln!(s, "peak resident memory: {:.0} MiB", b as f64 / 1048576.0);
        }
        s
    }
}
