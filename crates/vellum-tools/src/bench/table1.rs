//! The importance paper's Table 1 (SPEC IM6): for CT body 256×256×415, CT head 512×512×297 and
//! salmon 336×173×511, and R ∈ {1, 5, 10}, the time of each 1D filter pass, the subtract and the
//! total, beside the paper's milliseconds (CUDA, 2010).
//!
//! The volumes are real scans resampled (trilinear) to the paper's sizes when ../shared/data is
//! present: ct_chest_lidc2 for the CT body, cthead_stanford for the CT head and boston_teapot for the
//! salmon (no salmon scan is available; the filter cost depends on size, not content). Without the
//! data, the Shepp–Logan phantom resampled to the same sizes is used, and the row says so.
//!
//! Two references are measured in the same run: a plain GPU copy of one float volume (`copy`,
//! the bandwidth bound of a 1D pass, which reads and writes one volume; the subtract reads two and
//! writes one, so its bound is 1.5 copies), and scipy.ndimage.gaussian_filter with the same kernel
//! (σ = R/3, truncate 3, mode nearest) plus the subtraction, timed by benches/scipy_peer.py.

use crate::bench::{median, shared_data};
use serde::Serialize;
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::profiler::total_ms;
use vellum_gpu::Context;
use vellum_render::passes::importance::{ImportanceMap, GAUSS_PASSES};
use vellum_volume::{io, phantom, resample, Volume};

/// One volume of the paper's Table 1 with the paper's milliseconds.
pub struct PaperCase {
    pub name: &'static str,
    pub dims: [usize; 3],
    /// The dataset of ../shared/data/volumes resampled to `dims`.
    pub dataset: &'static str,
    /// 1D filter ms for R = 1, 5, 10.
    pub filter_ms: [f64; 3],
    pub subtract_ms: f64,
    /// Total ms for R = 1, 5, 10.
    pub total_ms: [f64; 3],
}

/// The paper's three volumes.
pub const CASES: [PaperCase; 3] = [
    PaperCase {
        name: "ct-body",
        dims: [256, 256, 415],
        dataset: "ct_chest_lidc2",
        filter_ms: [20.85, 52.96, 93.59],
        subtract_ms: 18.03,
        total_ms: [335.05, 438.13, 560.23],
    },
    PaperCase {
        name: "ct-head",
        dims: [512, 512, 297],
        dataset: "cthead_stanford",
        filter_ms: [57.90, 155.61, 272.77],
        subtract_ms: 51.90,
        total_ms: [928.41, 1221.18, 1570.10],
    },
    PaperCase {
        name: "salmon",
        dims: [336, 173, 511],
        dataset: "boston_teapot",
        filter_ms: [22.66, 59.03, 104.93],
        subtract_ms: 19.66,
        total_ms: [376.37, 490.04, 617.24],
    },
];

/// The radii of Table 1.
pub const RADII: [u32; 3] = [1, 5, 10];

/// Options of `vellum bench table1`.
#[derive(Clone, Debug)]
pub struct Options {
    pub repeat: usize,
    pub scipy: bool,
    /// Comma-separated `case:R` filters, e.g. `ct-body:1,salmon:10`.
    pub cases: Option<String>,
    /// Rounds of the four passes per submission for the sustained figures (0: not measured).
    pub sustained: usize,
}

/// One row of the table: medians over the repeats.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub case: String,
    pub dims: [usize; 3],
    pub data: String,
    pub radius: u32,
    pub gauss_ms: [f64; 3],
    pub subtract_ms: f64,
    pub passes_ms: f64,
    pub total_ms: f64,
    pub upload_ms: f64,
    pub readback_ms: f64,
    pub copy_ms: f64,
    /// Each 1D pass over the copy of the same bytes.
    pub gauss_over_copy: [f64; 3],
    /// Subtract over 1.5 copies (it reads two volumes and writes one).
    pub subtract_over_copy: f64,
    pub paper_filter_ms: f64,
    pub paper_subtract_ms: f64,
    pub paper_total_ms: f64,
    /// Paper total / our total.
    pub speedup_total: f64,
    /// scipy gaussian_filter + subtract, median ms, when measured.
    pub scipy_ms: Option<f64>,
    /// Our passes (3 filters + subtract) over scipy's time.
    pub vellum_over_scipy: Option<f64>,
    /// gauss_x, gauss_y, gauss_z and subtract with the device kept busy: the medians of
    /// `--sustained N` rounds recorded back to back, on the volume uploaded once.
    pub sustained_ms: Option<[f64; 4]>,
    /// A plain copy of the volume (a compute pass over the same images, `importance/copy.comp`)
    /// after each of those rounds (median ms): the yardstick of the sustained passes.
    pub sustained_copy_ms: Option<f64>,
    /// Each sustained pass's rate as a fraction of the copy's: copy ms over pass ms (the subtract
    /// against 1.5 copies, as it reads two volumes and writes one). 1 is the copy's bandwidth.
    pub sustained_of_copy: Option<[f64; 4]>,
}

/// The whole table.
#[derive(Clone, Debug, Serialize)]
pub struct Table {
    pub device: String,
    pub driver: String,
    pub repeat: usize,
    pub rows: Vec<Row>,
}

fn source_volume(case: &str, dims: [usize; 3], dataset: &str) -> Result<(Volume, String)> {
    if let Some(root) = shared_data() {
        let path = root
            .join("volumes")
            .join(dataset)
            .join(format!("{dataset}.nhdr"));
        if path.exists() {
            let v = io::load(&path, None)?;
            return Ok((
                resample::trilinear(&v, dims)?,
                format!("{dataset} resampled"),
            ));
        }
    }
    if std::env::var("CI").as_deref() == Ok("true") {
        return Err(Error::Invalid(format!(
            "../shared/data is missing; the {case} case needs {dataset} under CI"
        )));
    }
    let v = phantom::shepp_logan(128);
    Ok((
        resample::trilinear(&v, dims)?,
        "shepp-logan phantom resampled".into(),
    ))
}

fn wanted(filter: &Option<String>, case: &str, r: u32) -> bool {
    match filter {
        None => true,
        Some(f) => f
            .split(',')
            .map(str::trim)
            .any(|c| c == case || c == format!("{case}:{r}")),
    }
}

/// Runs scipy on `v` with radius `r`; `None` (with a warning) when python3 or scipy is missing.
fn scipy_ms(v: &Volume, r: u32, repeat: usize) -> Option<f64> {
    let dir = std::env::temp_dir().join(format!("vellum-scipy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).ok()?;
    let raw = dir.join("volume.f32");
    let floats = v.data.to_f32();
    std::fs::write(&raw, bytemuck::cast_slice::<f32, u8>(&floats)).ok()?;
    let mut args: Vec<std::ffi::OsString> = vec![raw.clone().into()];
    args.extend(v.dims.iter().map(|d| d.to_string().into()));
    args.push(r.to_string().into());
    args.push(repeat.to_string().into());
    let out = crate::bench::python_peer("scipy_peer.py", &args);
    let _ = std::fs::remove_dir_all(&dir);
    out?["median_ms"].as_f64()
}

/// Runs the table.
pub fn run(ctx: &Arc<Context>, opts: &Options) -> Result<Table> {
    let mut map = ImportanceMap::new(ctx)?;
    let mut rows = Vec::new();
    let total = CASES
        .iter()
        .flat_map(|c| RADII.iter().map(move |&r| (c.name, r)))
        .filter(|&(c, r)| wanted(&opts.cases, c, r))
        .count();
    if total == 0 {
        return Err(vellum_error::Error::Invalid(format!(
            "--cases {:?} selects no case; expected names among {} with an optional :R (R in {:?}), e.g. ct-head:10",
            opts.cases.as_deref().unwrap_or(""),
            CASES.iter().map(|c| c.name).collect::<Vec<_>>().join(", "),
            RADII
        )));
    }
    let progress = vellum_render::progress::bar(total as u64, "table 1");
    for PaperCase {
        name: case,
        dims,
        dataset,
        filter_ms: paper_filter,
        subtract_ms: paper_subtract,
        total_ms: paper_total,
    } in CASES
    {
        if !RADII.iter().any(|&r| wanted(&opts.cases, case, r)) {
            continue;
        }
        let (v, data) = source_volume(case, dims, dataset)?;
        for (ri, &r) in RADII.iter().enumerate() {
            if !wanted(&opts.cases, case, r) {
                continue;
            }
            log::info!("table1: {case} R={r}");
            progress.set_message(format!("table 1 {case} R={r}"));
            progress.inc(1);
            let runs = (0..opts.repeat)
                .map(|_| map.compute(&v, r, true))
                .collect::<Result<Vec<_>>>()?;
            let med = |name: &str| {
                median(
                    &runs
                        .iter()
                        .map(|o| total_ms(&o.passes, name))
                        .collect::<Vec<_>>(),
                )
            };
            let gauss_ms = GAUSS_PASSES.map(med);
            let subtract_ms = med("subtract");
            let copy_ms = med("copy");
            let total_ms = median(&runs.iter().map(|o| o.total_ms).collect::<Vec<_>>());
            let passes_ms = gauss_ms.iter().sum::<f64>() + subtract_ms;
            let scipy = if opts.scipy {
                scipy_ms(&v, r, opts.repeat)
            } else {
                None
            };
            let sustained = match opts.sustained {
                0 => None,
                n => Some(map.sustained(&v, r, n, 3)?),
            };
            rows.push(Row {
                case: case.into(),
                dims,
                data: data.clone(),
                radius: r,
                gauss_ms,
                subtract_ms,
                passes_ms,
                total_ms,
                upload_ms: med("upload"),
                readback_ms: med("readback"),
                copy_ms,
                gauss_over_copy: gauss_ms.map(|g| g / copy_ms),
                subtract_over_copy: subtract_ms / (1.5 * copy_ms),
                paper_filter_ms: paper_filter[ri],
                paper_subtract_ms: paper_subtract,
                paper_total_ms: paper_total[ri],
                speedup_total: paper_total[ri] / total_ms,
                scipy_ms: scipy,
                vellum_over_scipy: scipy.map(|s| passes_ms / s),
                sustained_ms: sustained.map(|m| [m[0], m[1], m[2], m[3]]),
                sustained_copy_ms: sustained.map(|m| m[4]),
                sustained_of_copy: sustained
                    .map(|m| [m[4] / m[0], m[4] / m[1], m[4] / m[2], 1.5 * m[4] / m[3]]),
            });
            drop(runs);
        }
    }
    Ok(Table {
        device: ctx.info.name.clone(),
        driver: ctx.info.driver.clone(),
        repeat: opts.repeat,
        rows,
    })
}

impl Table {
    /// The table as text a person reads.
    pub fn to_text(&self) -> String {
        let mut s = format!(
            "Table 1 (importance map) on {} ({}), median of {} run(s)\n",
            self.device, self.driver, self.repeat
        );
        s += "case     R   gauss_x  gauss_y  gauss_z  subtract |   total | paper 1D  sub   total | speedup | pass/copy x,y,z,sub   | scipy ms  vellum/scipy\n";
        for r in &self.rows {
            s += &format!(
                "{:<8} {:>2} {:>8.2} {:>8.2} {:>8.2} {:>9.2} | {:>7.1} | {:>7.2} {:>5.2} {:>7.1} | {:>6.1}x | {:.2} {:.2} {:.2} {:.2} | {:>9} {:>8}\n",
                r.case,
                r.radius,
                r.gauss_ms[0],
                r.gauss_ms[1],
                r.gauss_ms[2],
                r.subtract_ms,
                r.total_ms,
                r.paper_filter_ms,
                r.paper_subtract_ms,
                r.paper_total_ms,
                r.speedup_total,
                r.gauss_over_copy[0],
                r.gauss_over_copy[1],
                r.gauss_over_copy[2],
                r.subtract_over_copy,
                r.scipy_ms.map(|x| format!("{x:.1}")).unwrap_or_else(|| "-".into()),
                r.vellum_over_scipy.map(|x| format!("{x:.2}")).unwrap_or_else(|| "-".into()),
            );
        }
        for r in self.rows.iter().filter(|r| r.sustained_ms.is_some()) {
            let ms = r.sustained_ms.unwrap_or_default();
            // Bytes each pass must move: a float volume read and one written (subtract reads two),
            // counted as voxels × 4 bytes, as BENCHMARKS.md's GPU tables count them.
            let n = (r.dims[0] * r.dims[1] * r.dims[2] * 4) as f64;
            let gbs = |ms: f64, volumes: f64| volumes * n / (ms * 1e-3) / 1e9;
            s += &format!(
                "sustained {:<8} R={:<2} x {:.3} ms ({:.0} GB/s), y {:.3} ({:.0}), z {:.3} ({:.0}), subtract {:.3} ({:.0})\n",
                r.case,
                r.radius,
                ms[0],
                gbs(ms[0], 2.0),
                ms[1],
                gbs(ms[1], 2.0),
                ms[2],
                gbs(ms[2], 2.0),
                ms[3],
                gbs(ms[3], 3.0),
            );
            if let (Some(c), Some(f)) = (r.sustained_copy_ms, r.sustained_of_copy) {
                s += &format!(
                    "          copy {c:.3} ms ({:.0} GB/s); each pass at {:.0} %, {:.0} %, {:.0} %, {:.0} % of the copy's rate\n",
                    gbs(c, 2.0),
                    100.0 * f[0],
                    100.0 * f[1],
                    100.0 * f[2],
                    100.0 * f[3],
                );
            }
        }
        s += "data: ";
        s += &self
            .rows
            .iter()
            .map(|r| format!("{} = {}", r.case, r.data))
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .collect::<Vec<_>>()
            .join("; ");
        s += "\n";
        s
    }
}
