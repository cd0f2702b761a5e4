//! `vellum bench lines`: object-space line extraction (issue 11) per kind, full against the
//! interactive mode (every other cell), on the GPU pass and on the CPU reference, with segment
//! counts. The GPU figure is the `lines` pass's timestamp; the upload is not counted. Beside it,
//! the same extraction with the Hessian precomputed (issue 11: measure both), whose one-off
//! `lines_hessian` pass is reported apart. And the seeded traversal, the interactive mode: one
//! frame after a full one, the camera turned 3°.

use crate::bench::shared_data;
use serde::Serialize;
use std::sync::Arc;
use vellum_error::Result;
use vellum_gpu::Context;
use vellum_render::passes::lines::{HessianSource, LineExtractor, DEFAULT_CAPACITY};
use vellum_volume::lines::{extract, Eye, LineParams};
use vellum_volume::{io, phantom, Volume};

pub struct Options {
    /// A volume path or phantom spec with its isovalue; default the CT head (iso 1300) and a
    /// 128³ torus.
    pub input: Option<(String, f64)>,
    /// Resample every volume trilinearly to this many voxels per side first.
    pub resample: Option<usize>,
}

#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub data: String,
    pub dims: [usize; 3],
    pub kind: &'static str,
    /// "all" (every cell), "stride 2" (every other cell) or "seeded" (the seeded traversal, one
    /// frame after a full frame 3° of azimuth before, against the full set at its own view).
    pub mode: &'static str,
    /// 1 = every cell, 2 = every other; 1 for the seeded traversal.
    pub stride: u32,
    pub gpu_ms: f64,
    pub gpu_segments: u64,
    /// The extraction with the Hessian read from a precomputed volume, its segments, and the
    /// precomputation; None where the 32 bytes a voxel do not fit the device.
    pub precomputed_ms: Option<f64>,
    pub precomputed_segments: Option<u64>,
    pub hessian_ms: Option<f64>,
    /// The seeded frame's total segment length as a fraction of the full set's at its view.
    pub length_fraction: Option<f64>,
    pub cpu_ms: f64,
    pub cpu_segments: usize,
}

#[derive(Clone, Debug, Serialize)]
pub struct Table {
    pub device: String,
    pub threads: usize,
    pub rows: Vec<Row>,
}

fn cases(input: &Option<(String, f64)>) -> Result<Vec<(Volume, String, f64)>> {
    if let Some((spec, iso)) = input {
        return Ok(vec![(
            vellum_volume::input::load(spec, None)?,
            spec.clone(),
            *iso,
        )]);
    }
    let mut v = Vec::new();
    if let Some(root) = shared_data() {
        let path = root.join("volumes/cthead_stanford/cthead_stanford.nhdr");
        if path.exists() {
            v.push((io::load(&path, None)?, "CT head, iso 1300".into(), 1300.0));
        }
    }
    v.push((
        phantom::smooth_torus(128),
        "torus 128³, iso 0.5".into(),
        0.5,
    ));
    Ok(v)
}

pub fn run(ctx: &Arc<Context>, opts: &Options) -> Result<Table> {
    let mut lines = LineExtractor::new(ctx)?;
    let mut pipelines = vellum_gpu::PipelineCache::new(ctx);
    // Azimuth 30°, elevation 20°: the renderer's default view of an unoriented volume.
    let eye_at = |azimuth: f32| {
        let (a, e) = (azimuth.to_radians(), 20f32.to_radians());
        Eye::Direction([a.sin() * e.cos(), -a.cos() * e.cos(), e.sin()])
    };
    let eye = eye_at(30.0);
    let mut rows = Vec::new();
    for (v, data, iso) in cases(&opts.input)? {
        let (v, data) = match opts.resample {
            Some(n) => (
                vellum_volume::resample::trilinear(&v, [n; 3])?,
                format!("{data}, resampled to {n}³"),
            ),
            None => (v, data),
        };
        let (values, [lo, hi]) = vellum_render::passes::occlusion::normalised_f32(&v);
        let iso_n = if hi > lo {
            ((iso - lo) / (hi - lo)) as f32
        } else {
            0.5
        };
        let spacing = v.spacing.map(|s| s as f32);
        // The R32F volume and the Hessian's two RGBA32F images.
        let precompute = ctx.check_image_3d(v.dims, 36, 1).is_ok();
        for (kind, sil, sc) in [
            ("silhouettes", true, false),
            ("suggestive", false, true),
            ("both", true, true),
        ] {
            for stride in [1, 2] {
                let p = LineParams {
                    iso: iso as f32,
                    silhouettes: sil,
                    suggestive: sc,
                    stride,
                    ..LineParams::default()
                };
                // Each measured extraction runs once before, untimed: llvmpipe compiles a
                // shader variant on its first dispatch with a given texture format, for seconds.
                lines.extract(&mut pipelines, &v, eye, &p, DEFAULT_CAPACITY)?;
                let gpu = lines.extract(&mut pipelines, &v, eye, &p, DEFAULT_CAPACITY)?;
                if precompute {
                    lines.extract_with(
                        &mut pipelines,
                        &v,
                        eye,
                        &p,
                        DEFAULT_CAPACITY,
                        HessianSource::Precomputed,
                    )?;
                }
                let pre = match precompute {
                    true => Some(lines.extract_with(
                        &mut pipelines,
                        &v,
                        eye,
                        &p,
                        DEFAULT_CAPACITY,
                        HessianSource::Precomputed,
                    )?),
                    false => None,
                };
                let start = std::time::Instant::now();
                let cpu = extract(
                    &values,
                    v.dims,
                    spacing,
                    eye,
                    &LineParams { iso: iso_n, ..p },
                );
                rows.push(Row {
                    data: data.clone(),
                    dims: v.dims,
                    kind,
                    mode: if stride == 1 { "all" } else { "stride 2" },
                    stride,
                    gpu_ms: gpu.ms,
                    gpu_segments: gpu.found,
                    precomputed_ms: pre.as_ref().map(|l| l.ms),
                    precomputed_segments: pre.as_ref().map(|l| l.found),
                    hessian_ms: pre.as_ref().map(|l| l.hessian_ms),
                    cpu_ms: start.elapsed().as_secs_f64() * 1e3,
                    cpu_segments: cpu.len(),
                    length_fraction: None,
                });
            }
            // The interactive mode of the viewer: a full frame, then the camera turns 3°.
            let p = LineParams {
                iso: iso as f32,
                silhouettes: sil,
                suggestive: sc,
                ..LineParams::default()
            };
            let turned = eye_at(33.0);
            let sequence = [(eye, p), (turned, LineParams { seeded: true, ..p })];
            lines.extract_frames(&mut pipelines, &v, &sequence, DEFAULT_CAPACITY)?;
            let frames = lines.extract_frames(&mut pipelines, &v, &sequence, DEFAULT_CAPACITY)?;
            let full = lines.extract(&mut pipelines, &v, turned, &p, DEFAULT_CAPACITY)?;
            let length = |s: &[vellum_volume::lines::Segment]| -> f64 {
                s.iter().map(|s| s.length() as f64).sum()
            };
            let start = std::time::Instant::now();
            let cpu = extract(
                &values,
                v.dims,
                spacing,
                turned,
                &LineParams { iso: iso_n, ..p },
            );
            rows.push(Row {
                data: data.clone(),
                dims: v.dims,
                kind,
                mode: "seeded",
                stride: 1,
                gpu_ms: frames[1].ms,
                gpu_segments: frames[1].found,
                precomputed_ms: None,
                precomputed_segments: None,
                hessian_ms: None,
                cpu_ms: start.elapsed().as_secs_f64() * 1e3,
                cpu_segments: cpu.len(),
                length_fraction: Some(
                    length(&frames[1].segments) / length(&full.segments).max(1e-9),
                ),
            });
        }
    }
    Ok(Table {
        device: ctx.info.name.clone(),
        threads: rayon::current_num_threads(),
        rows,
    })
}

impl Table {
    pub fn to_text(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "object-space lines on {} (CPU reference on {} threads)",
            self.device, self.threads
        );
        let _ = writeln!(
            s,
            "{:<22} {:<12} {:>8} {:>10} {:>10} {:>14} {:>10} {:>10} {:>10} {:>10}",
            "data",
            "kind",
            "mode",
            "GPU ms",
            "segments",
            "precomp. H ms",
            "segments",
            "H once ms",
            "CPU ms",
            "segments"
        );
        let or_dash = |x: Option<String>| x.unwrap_or_else(|| "-".into());
        for r in &self.rows {
            let _ = writeln!(
                s,
                "{:<22} {:<12} {:>8} {:>10.1} {:>10} {:>14} {:>10} {:>10} {:>10.1} {:>10}{}",
                r.data,
                r.kind,
                r.mode,
                r.gpu_ms,
                r.gpu_segments,
                or_dash(r.precomputed_ms.map(|m| format!("{m:.1}"))),
                or_dash(r.precomputed_segments.map(|n| n.to_string())),
                or_dash(r.hessian_ms.map(|m| format!("{m:.1}"))),
                r.cpu_ms,
                r.cpu_segments,
                r.length_fraction
                    .map(|f| format!("  ({:.1} % of the full length)", 100.0 * f))
                    .unwrap_or_default()
            );
        }
        let _ = writeln!(
            s,
            "seeded: one frame of the seeded traversal after a full frame 3° of azimuth before; \
             CPU: the full set at its view"
        );
        if self.rows.iter().any(|r| r.precomputed_ms.is_none()) {
            let _ = writeln!(
                s,
                "-: the precomputed Hessian (32 bytes a voxel) does not fit {}",
                self.device
            );
        }
        s
    }
}
