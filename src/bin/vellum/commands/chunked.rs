//! Whether `importance` and `occlusion` run in core or chunk by chunk (issue 26), and the report
//! of a chunked run.

use crate::args::{ChunkArgs, InputArgs};
use crate::commands::convert::Source;
use anyhow::Result;
use std::path::Path;
use vellum::volume::Volume;

/// The input, opened by every rank before any work starts (one that cannot ends the job), with
/// its grid, after the ranks have checked that they were given the same.
pub(crate) fn open_shared(
    team: &dyn vellum::team::Team,
    input: &InputArgs,
) -> Result<(Source, [usize; 3])> {
    let source = crate::commands::together(team, Source::open(input))?;
    let dims = crate::commands::together(team, source.boxes().map(|b| b.dims()))?;
    team.same_inputs(crate::commands::inputs_key(&dims))?;
    Ok((source, dims))
}

/// Host memory a chunked pass works in by default: 1 GiB, whatever the grid's size.
pub(crate) const CHUNKED_MEMORY: u64 = 1 << 30;

/// How a chunked pass runs: `--chunk` (or the largest edge whose chunks with their `halo` fit
/// the memory budget twice), and as many chunks in flight as the budget holds (one per core at
/// most). The budget is `--memory-budget`, by default [`CHUNKED_MEMORY`].
pub(crate) fn chunk_plan(
    c: &ChunkArgs,
    dims: [usize; 3],
    halo: usize,
    bytes_per_voxel: u64,
) -> Result<vellum::passes::chunked::Plan> {
    if c.chunk == Some(0) {
        anyhow::bail!("--chunk 0 is invalid; expected a chunk edge of 1 voxel or more");
    }
    let budget = memory_budget(c, CHUNKED_MEMORY)?;
    Ok(vellum::passes::chunked::Plan::new(
        dims,
        (halo, bytes_per_voxel),
        c.chunk,
        budget,
    )?)
}

/// `--memory-budget` in bytes, or `default`.
pub(crate) fn memory_budget(c: &ChunkArgs, default: u64) -> Result<u64> {
    Ok(match c.memory_budget {
        Some(m) if m.is_finite() && m > 0.0 => (m * (1u64 << 20) as f64) as u64,
        Some(m) => {
            anyhow::bail!("--memory-budget {m} is invalid; expected a positive number of MiB")
        }
        None => default,
    })
}

/// How a pass runs: on the whole volume, or chunk by chunk from a source into a store.
pub(crate) enum Plan {
    InCore(Volume),
    Chunked {
        source: Source,
        plan: vellum::passes::chunked::Plan,
    },
}

pub(crate) fn is_store_path(p: &Path) -> bool {
    p.file_name()
        .is_some_and(|n| n.to_string_lossy().to_lowercase().ends_with(".zarr"))
}

/// Chunk by chunk when the output is a store, the input is a store, or the in-core need
/// (`bytes_per_voxel` per voxel) exceeds the memory budget (by default half the machine's
/// memory); then `--out` must be a store and `--slices`-like whole-volume outputs
/// (`whole_outputs`) are refused in one sentence.
pub(crate) fn plan(
    team: &dyn vellum::team::Team,
    input: &InputArgs,
    out: Option<&Path>,
    c: &ChunkArgs,
    halo: usize,
    bytes_per_voxel: u64,
    whole_outputs: &[(&str, bool)],
) -> Result<Plan> {
    let half = vellum::memory::total_kib().map_or(u64::MAX, |k| k * 1024 / 2);
    let budget = memory_budget(c, half)?;
    let (source, dims) = open_shared(team, input)?;
    let need = dims.iter().map(|&n| n as u64).product::<u64>() * bytes_per_voxel;
    let store_out = out.is_some_and(is_store_path);
    let store_in = matches!(source, Source::Store(_));
    let reason = if store_in {
        Some("a store input is computed chunk by chunk")
    } else if need > budget {
        Some("the pass needs more than --memory-budget in core, so it runs chunk by chunk")
    } else {
        None
    };
    if !store_out {
        if let Some(why) = reason {
            anyhow::bail!("{why}; expected --out x.ome.zarr for its result");
        }
        return Ok(Plan::InCore(match source {
            Source::Volume(v) => v,
            Source::Phantom(p) => p.volume(),
            Source::Store(ms) => ms.read_level(0)?,
        }));
    }
    for (flag, given) in whole_outputs {
        anyhow::ensure!(
            !given,
            "{flag} needs the whole result in memory; a chunked pass writes only its store"
        );
    }
    let plan = chunk_plan(c, dims, halo, bytes_per_voxel)?;
    Ok(Plan::Chunked { source, plan })
}

/// Runs a chunked pass, `run(on_chunk)`, over a grid of `dims` with a progress bar over its
/// chunks; returns its result and the seconds it took, validation reported.
pub(crate) fn run_with_bar<T>(
    team: &dyn vellum::team::Team,
    ctx: &vellum::gpu::Context,
    (dims, chunk): ([usize; 3], usize),
    what: &str,
    run: impl FnOnce(&(dyn Fn() + Sync)) -> vellum::Result<T>,
) -> Result<(T, f64)> {
    let opts = vellum::volume::io::ome_zarr::WriteOptions {
        chunk,
        levels: None,
        threads: None,
    };
    let count = vellum::volume::io::ome_zarr::chunk_count(dims, &opts) as u64;
    // Rank 0's bar counts its own chunks against the whole grid's; the others show none.
    let bar = match team.is_root() {
        true => vellum::progress::bar(count, what),
        false => indicatif::ProgressBar::hidden(),
    };
    let start = std::time::Instant::now();
    let result = run(&|| bar.inc(1))?;
    bar.finish_and_clear();
    crate::commands::report_validation(ctx);
    Ok((result, start.elapsed().as_secs_f64()))
}

/// The JSON of a chunked run.
pub(crate) fn report(
    team: &dyn vellum::team::Team,
    ctx: &vellum::gpu::Context,
    store: &vellum::volume::io::ome_zarr::WriteReport,
    plan: vellum::passes::chunked::Plan,
    halo: usize,
    secs: f64,
) -> serde_json::Value {
    let voxels = store.bytes as f64 / 4.0;
    serde_json::json!({
        "chunked": true,
        "ranks": team.size(),
        "chunk": plan.chunk,
        "workers": plan.workers,
        "halo": halo,
        "levels": store.levels,
        "chunks": store.chunks,
        "range": store.range,
        "seconds": secs,
        "voxels_per_second": voxels / secs.max(1e-9),
        "peak_rss_mib": vellum::memory::peak_resident_kib().map(|k| k as f64 / 1024.0),
        "peak_heap_mib": vellum::memory::peak_heap_mib(),
        "peak_device_mib": ctx.peak_allocated_bytes() as f64 / (1 << 20) as f64,
        "device": ctx.info.name,
    })
}
