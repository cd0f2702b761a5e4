//! `vellum convert`: to NRRD or NIfTI in memory, or to an OME-Zarr store chunk by chunk.

use crate::args::InputArgs;
use anyhow::Result;
use std::path::Path;
use vellum::volume::io::ome_zarr::{self, WriteOptions};
use vellum::volume::phantom::{Phantom, MAX_STREAMED_SIZE};
use vellum::volume::source::BoxSource;

/// `--levels`: `auto` (or absent) picks by size; otherwise a count of 1 or more.
fn parse_levels(levels: Option<&str>) -> Result<Option<usize>> {
    match levels {
        None | Some("auto") => Ok(None),
        Some(n) => match n.parse::<usize>() {
            Ok(n) if n > 0 => Ok(Some(n)),
            _ => anyhow::bail!("--levels {n:?} is invalid; expected auto or a number of 1 or more"),
        },
    }
}

pub(crate) fn convert(
    input: &InputArgs,
    output: &Path,
    (chunk, levels): (Option<usize>, Option<&str>),
    add_channel: &[String],
    json: bool,
) -> Result<()> {
    let store = output
        .file_name()
        .is_some_and(|n| n.to_string_lossy().to_lowercase().ends_with(".zarr"));
    anyhow::ensure!(
        store || (chunk.is_none() && levels.is_none() && add_channel.is_empty()),
        "--chunk, --levels and --add-channel shape an OME-Zarr store; expected an output folder ending .zarr"
    );
    if !store {
        let v = input.load()?;
        vellum::volume::io::write(output, &v)?;
        return done(output, v.dims, v.voxel_type().name());
    }
    let opts = WriteOptions {
        chunk: chunk.unwrap_or(64),
        levels: parse_levels(levels)?,
        threads: None,
    };
    let source = Source::open(input)?;
    let boxes = source.boxes()?;
    if !add_channel.is_empty() {
        return write_channels(output, &*boxes, add_channel, &opts, json);
    }
    write_store(output, &*boxes, &opts, json)
}

/// Writes `src` and the volumes `extra` names as the channels of one store, each extra read
/// whole and checked to lie on `src`'s grid.
fn write_channels(
    output: &Path,
    src: &dyn BoxSource,
    extra: &[String],
    opts: &WriteOptions,
    json: bool,
) -> Result<()> {
    let most = vellum::classify::channels::MAX_CHANNELS;
    anyhow::ensure!(
        extra.len() < most,
        "--add-channel gives {} channels beside the input; vellum mixes at most {most} in one ray, so expected at most {}",
        extra.len() + 1,
        most - 1
    );
    let extra = extra
        .iter()
        .map(|p| {
            let v = vellum::input::load(p, None)?;
            let (a, b) = (v.dims, src.dims());
            anyhow::ensure!(
                a == b && grids_match(&v, src),
                "--add-channel {p} is {}x{}x{} voxels of spacing {:?} and the input {}x{}x{} of spacing {:?}; expected a volume on the input's grid",
                a[0], a[1], a[2], v.spacing, b[0], b[1], b[2], src.spacing()
            );
            Ok(v)
        })
        .collect::<Result<Vec<_>>>()?;
    let same = extra.iter().all(|v| v.voxel_type() == src.voxel());
    let voxel = match same {
        true => src.voxel(),
        false => vellum::volume::VoxelType::F32,
    };
    let as_voxel = |v: vellum::volume::Volume| match same {
        true => Ok(v),
        false => vellum::volume::Volume::new(
            v.dims,
            v.spacing,
            vellum::volume::VoxelData::F32(v.data.to_f32()),
        ),
    };
    let read = |lo, size| {
        let mut out = vec![as_voxel(src.read_box(lo, size)?)?];
        for v in &extra {
            out.push(as_voxel(v.read_box(lo, size)?)?);
        }
        Ok(out)
    };
    let channels = ome_zarr::Channels::over(src, (extra.len() + 1, voxel), &read);
    let chunks = ome_zarr::chunk_count(src.dims(), opts) * (extra.len() + 1);
    let bar = vellum::progress::bar(chunks as u64, "writing chunks");
    let report = ome_zarr::write_channels_in(
        &vellum::volume::team::Solo,
        output,
        &channels,
        opts,
        &|| bar.inc(1),
    )?;
    bar.finish_and_clear();
    let d = src.dims();
    if json {
        let out = serde_json::json!({
            "store": output,
            "dims": d,
            "channels": extra.len() + 1,
            "voxel": voxel.name(),
            "levels": report.levels,
            "chunks": report.chunks,
            "bytes": report.bytes,
            "range": report.range,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!(
        "wrote {} ({} channels of {}x{}x{} {}): {} levels, {} chunks",
        output.display(),
        extra.len() + 1,
        d[0],
        d[1],
        d[2],
        voxel.name(),
        report.levels,
        report.chunks
    );
    Ok(())
}

/// Whether `v` has `src`'s spacing (within a millionth, relative).
fn grids_match(v: &vellum::volume::Volume, src: &dyn BoxSource) -> bool {
    let s = src.spacing();
    (0..3).all(|a| (v.spacing[a] - s[a]).abs() <= 1e-6 * s[a].abs().max(1e-12))
}

/// An input read a box at a time: a phantom is sampled a chunk at a time and a store is read a
/// chunk at a time, so neither is ever whole in memory; any other input is read whole first.
pub(crate) enum Source {
    Phantom(Phantom),
    Store(ome_zarr::Multiscale),
    Volume(vellum::volume::Volume),
}

impl Source {
    pub(crate) fn open(input: &InputArgs) -> Result<Self> {
        let path = Path::new(&input.input);
        Ok(
            if let Some(phantom) = Phantom::parse(&input.input, MAX_STREAMED_SIZE) {
                anyhow::ensure!(
                    input.pick() == Default::default(),
                    "--time and --channel pick a time point and a channel of an OME-Zarr store; {} is a phantom",
                    input.input
                );
                Source::Phantom(phantom?)
            } else if ome_zarr::is_store(path) && input.raw.spec()?.is_none() {
                Source::Store(ome_zarr::Multiscale::open_picked(path, input.pick())?)
            } else {
                Source::Volume(input.load()?)
            },
        )
    }

    pub(crate) fn boxes(&self) -> Result<Box<dyn BoxSource + '_>> {
        Ok(match self {
            Source::Phantom(p) => Box::new(*p),
            Source::Store(ms) => Box::new(ms.level(0)?),
            Source::Volume(v) => Box::new(v),
        })
    }

    /// Level 0's value range: recorded in a store written by vellum, else read a chunk at a time.
    pub(crate) fn range(&self) -> Result<[f64; 2]> {
        if let Source::Store(ms) = self {
            if let Some(r) = ms.range {
                return Ok(r);
            }
        }
        let src = self.boxes()?;
        let d = src.dims();
        let mut r = [f64::INFINITY, f64::NEG_INFINITY];
        let step = 64;
        for z in (0..d[2]).step_by(step) {
            for y in (0..d[1]).step_by(step) {
                for x in (0..d[0]).step_by(step) {
                    let lo = [x, y, z];
                    let size: [usize; 3] = std::array::from_fn(|a| step.min(d[a] - lo[a]));
                    let b = vellum::volume::stats::value_range(&src.read_box(lo, size)?);
                    r = [r[0].min(b[0]), r[1].max(b[1])];
                }
            }
        }
        Ok(r)
    }
}

/// Writes `src` as a store with a progress bar (on a terminal), then says what it wrote.
fn write_store(output: &Path, src: &dyn BoxSource, opts: &WriteOptions, json: bool) -> Result<()> {
    let bar = vellum::progress::bar(
        ome_zarr::chunk_count(src.dims(), opts) as u64,
        "writing chunks",
    );
    let start = std::time::Instant::now();
    let report = ome_zarr::write_source(output, src, opts, &|| bar.inc(1))?;
    bar.finish_and_clear();
    let secs = start.elapsed().as_secs_f64();
    let mib = report.bytes as f64 / (1 << 20) as f64;
    let peak = vellum::memory::peak_resident_kib().map(|k| k as f64 / 1024.0);
    let d = src.dims();
    if json {
        let out = serde_json::json!({
            "store": output,
            "dims": d,
            "voxel": src.voxel().name(),
            "levels": report.levels,
            "chunks": report.chunks,
            "bytes": report.bytes,
            "seconds": secs,
            "mib_per_s": mib / secs.max(1e-9),
            "range": report.range,
            "peak_rss_mib": peak,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!(
        "wrote {} ({}x{}x{} {}): {} levels, {} chunks, {mib:.0} MiB uncompressed in {secs:.1} s ({:.0} MiB/s), peak resident set {:.0} MiB",
        output.display(),
        d[0],
        d[1],
        d[2],
        src.voxel().name(),
        report.levels,
        report.chunks,
        mib / secs.max(1e-9),
        peak.unwrap_or(0.0),
    );
    Ok(())
}

fn done(output: &Path, dims: [usize; 3], voxel: &str) -> Result<()> {
    println!(
        "wrote {} ({}x{}x{} {voxel})",
        output.display(),
        dims[0],
        dims[1],
        dims[2]
    );
    Ok(())
}
