//! Passes chunk by chunk (issue 26): the importance map, the occlusion volume and the Sobel
//! normals of a grid too large to hold, written as an OME-Zarr store.
//!
//! Each output chunk is computed from its box of the input widened by the filter's reach (R for
//! the Gaussian of ΔD and for the occlusion's ball or Gaussian neighbourhood), as far as the
//! grid goes, and the widened part is dropped (overlap–save, for the FFT method too): every kept
//! voxel sees exactly the neighbours it sees on the whole grid, and the grid's own borders are
//! where the in-core pass has them. The occlusion normalises every chunk over the whole grid's
//! value range, as the in-core pass does, and the spectrum is summed over the kept voxels of
//! every chunk. The output store's pyramid and value range (so max |ΔD|) come with it.
//!
//! Chunks run as a pipeline on [`Plan::workers`] threads: each reads and decodes its box,
//! prepares it for the GPU (normalising, packing, allocating), records its passes behind the one
//! lock a context allows, and turns the result back into voxels, crops and compresses it while
//! the others use the GPU; host memory holds that many chunks with their halos, whatever the
//! grid's size, and the plan sizes them from the memory budget. The ranks of a team (an MPI job) share the chunks, each its own boxes of the
//! grid, and reduce the spectrum; the store is the one a process alone writes.

use crate::passes::importance::ImportanceMap;
use crate::passes::normals::Normals;
use crate::passes::occlusion::{Occlusion, OcclusionInput, OcclusionParams, Spectrum};
use std::path::Path;
use std::sync::{Arc, Mutex};
use vellum_error::{Error, Result};
use vellum_gpu::Context;
use vellum_volume::io::ome_zarr::{
    write_channels_in, write_source_in, Channels, WriteOptions, WriteReport,
};
use vellum_volume::source::{read_widened, BoxSource, Halo};
use vellum_volume::team::Team;
use vellum_volume::{Volume, VoxelData, VoxelType};

/// Chunk edges tried, largest first.
const CHUNKS: [usize; 6] = [256, 192, 128, 96, 64, 32];

/// Host bytes per voxel of a chunk's box while its pass runs (input, staging, work and output
/// copies): importance, occlusion and normals.
pub const IMPORTANCE_BYTES: u64 = 24;
/// Host bytes per voxel of a chunk's box while the occlusion pass runs.
pub const OCCLUSION_BYTES: u64 = 40;
/// Host bytes per voxel of a chunk's box while the normals pass runs.
pub const NORMALS_BYTES: u64 = 56;

/// How a chunked pass runs: its chunk edge, and how many chunks are in flight at once.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct Plan {
    /// Edge of an output chunk in voxels, the same along every axis.
    pub chunk: usize,
    /// How many chunks are in flight at once: at least one, at most one per core.
    pub workers: usize,
}

impl Plan {
    /// `chunk` (or the largest edge of which as many boxes fit `budget` as there are cores, two
    /// to eight: a large chunk wastes less on its halo, several keep the cores decoding and
    /// compressing), with as many workers as boxes of that edge with `halo` at
    /// `bytes_per_voxel` fit `budget`, at least one and at most one per core.
    pub fn new(
        dims: [usize; 3],
        (halo, bytes_per_voxel): (usize, u64),
        chunk: Option<usize>,
        budget: u64,
    ) -> Result<Self> {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let chunk = match chunk {
            Some(c) => c,
            None => {
                let wanted = cores.clamp(2, 8) as u64;
                let longest = dims.into_iter().max().unwrap_or(1);
                let fits = |c: usize| wanted * box_bytes(dims, c, halo, bytes_per_voxel) <= budget;
                match CHUNKS.iter().map(|&c| c.min(longest)).find(|&c| fits(c)) {
                    Some(c) => c,
                    None => chunk_for(dims, halo, bytes_per_voxel, budget)?,
                }
            }
        };
        let workers = (budget / box_bytes(dims, chunk, halo, bytes_per_voxel).max(1)) as usize;
        Ok(Plan {
            chunk,
            workers: workers.clamp(1, cores),
        })
    }
}

/// Host bytes of one chunk's box of edge `c` with `halo` at `bytes_per_voxel`.
fn box_bytes(dims: [usize; 3], c: usize, halo: usize, bytes_per_voxel: u64) -> u64 {
    let edge: [u64; 3] = std::array::from_fn(|a| (c.min(dims[a]) + 2 * halo).min(dims[a]) as u64);
    edge.iter().product::<u64>() * bytes_per_voxel
}

/// The largest chunk edge whose box with `halo`, at `bytes_per_voxel`, fits `budget` twice (one
/// chunk in its pass, one being written), at most the grid's longest axis; one sentence when
/// not even the smallest fits.
pub(crate) fn chunk_for(
    dims: [usize; 3],
    halo: usize,
    bytes_per_voxel: u64,
    budget: u64,
) -> Result<usize> {
    let need = |c: usize| 2 * box_bytes(dims, c, halo, bytes_per_voxel);
    let longest = dims.into_iter().max().unwrap_or(1);
    CHUNKS
        .iter()
        .map(|&c| c.min(longest))
        .find(|&c| need(c) <= budget)
        .ok_or_else(|| {
            Error::Invalid(format!(
                "a memory budget of {} MiB is smaller than two chunks of {} voxels with their halo of {halo} ({} MiB); raise --memory-budget",
                mib(budget),
                CHUNKS[CHUNKS.len() - 1],
                mib(need(CHUNKS[CHUNKS.len() - 1]))
            ))
        })
}

/// Bytes as MiB for a sentence: whole above 10, with significant digits below (a budget of
/// half a MiB is not "0 MiB").
fn mib(bytes: u64) -> String {
    let m = bytes as f64 / (1 << 20) as f64;
    match m >= 10.0 {
        true => format!("{m:.0}"),
        false => format!("{}", (m * 1000.0).round() / 1000.0),
    }
}

fn locked<T>(m: &Mutex<T>) -> Result<std::sync::MutexGuard<'_, T>> {
    m.lock()
        .map_err(|_| Error::Invalid("a chunk's pass failed on another thread".into()))
}

/// ΔD = G∗V − V of `src` (Gaussian radius `radius`), chunk by chunk, into a new store at `out`.
pub fn importance_store(
    (team, ctx): (&dyn Team, &Arc<Context>),
    src: &dyn BoxSource,
    radius: u32,
    out: &Path,
    plan: Plan,
    on_chunk: &(dyn Fn() + Sync),
) -> Result<WriteReport> {
    let map = Mutex::new(team.together(ImportanceMap::new(ctx))?);
    let f = |v: &Volume, offset: [usize; 3], size: [usize; 3]| -> Result<Volume> {
        let staged = ImportanceMap::stage(ctx, v)?;
        locked(&map)?.run(&staged, radius)?;
        // Read back outside the lock, so that another chunk's passes run meanwhile. Dropped
        // while the lock is held no recording is open, so the chunk's images and staging are
        // freed now rather than deferred to another worker's submission: the memory budget
        // counts the chunks being worked on, not garbage waiting on a serial.
        let dd = staged.delta_d_in((offset, size));
        let pass = locked(&map)?;
        drop(staged);
        drop(pass);
        dd
    };
    let halo = Halo {
        src,
        halo: radius as usize,
        f: &f,
    };
    write_source_in(team, out, &halo, &options(plan), on_chunk)
}

/// The store's options for a pass run by `plan`.
fn options(plan: Plan) -> WriteOptions {
    WriteOptions {
        chunk: plan.chunk,
        levels: None,
        threads: Some(plan.workers),
    }
}

/// The occlusion volume of `src` under `p` (stride 1), chunk by chunk, into a new store at
/// `out`, every chunk normalised over `range` (the whole grid's); with the spectrum of the
/// whole grid when `p` asks for one.
pub fn occlusion_store(
    (team, ctx): (&dyn Team, &Arc<Context>),
    src: &dyn BoxSource,
    p: &OcclusionParams,
    range: [f64; 2],
    out: &Path,
    plan: Plan,
    on_chunk: &(dyn Fn() + Sync),
) -> Result<(WriteReport, Option<Spectrum>)> {
    if p.stride != 1 {
        return Err(Error::Invalid(format!(
            "a chunked occlusion runs at stride 1, not {}; drop --stride or write a volume file",
            p.stride
        )));
    }
    let occlusion = Mutex::new(team.together(Occlusion::new(ctx))?);
    let params = OcclusionParams {
        spectrum_bins: None,
        ..p.clone()
    };
    let bins = p.spectrum_bins.map(|b| b.map(|n| n as usize));
    let counts = Mutex::new(vec![0u64; bins.map_or(0, |[x, y]| x * y)]);
    let f = |v: &Volume, offset: [usize; 3], size: [usize; 3]| -> Result<Volume> {
        // One recording at a time on the context: the upload goes under the lock, its staging
        // is made before.
        let (input, staging) = OcclusionInput::stage_in_range(ctx, v, Some(range))?;
        let mut pass = locked(&occlusion)?;
        input.upload_staged(ctx, &staging)?;
        let kept = pass
            .compute_within(&input, &params, Some((offset, size)))?
            .occlusion;
        // Freed under the lock, with no recording open (see `importance_store`).
        drop(staging);
        let host = input.host.clone();
        drop(input);
        drop(pass);
        if let (Some(b), Some(host)) = (bins, &host) {
            let s = super::box_rows(host, (v.dims[0], v.dims[1]), (offset, size));
            let s = Volume::new(size, v.spacing, VoxelData::F32(s))?;
            add_to_spectrum(&mut locked(&counts)?, b, &s, &kept);
        }
        Ok(kept)
    };
    let halo = Halo {
        src,
        halo: p.radius as usize,
        f: &f,
    };
    let report = write_source_in(team, out, &halo, &options(plan), on_chunk)?;
    let mut counts = counts
        .into_inner()
        .map_err(|_| Error::Invalid("a chunk's pass failed on another thread".into()))?;
    // Every rank counted its own chunks' voxels.
    team.sum(&mut counts);
    let spectrum = p.spectrum_bins.map(|b| -> Result<Spectrum> {
        Ok(Spectrum {
            bins: b,
            counts: counts
                .iter()
                .map(|&c| c.min(u32::MAX as u64) as u32)
                .collect(),
            intensity_range: range,
        })
    });
    Ok((report, spectrum.transpose()?))
}

/// Halo of the Sobel normals: one voxel.
pub const NORMALS_HALO: usize = 1;

/// The Sobel normals of `src` normalised over `range` (the whole grid's), chunk by chunk, into
/// a new store at `out` of four float32 channels: the gradient's x, y and z in world units and
/// its length, bit for bit the half floats of the renderer's in-core gradient texture.
pub fn normals_store(
    (team, ctx): (&dyn Team, &Arc<Context>),
    src: &dyn BoxSource,
    range: [f64; 2],
    out: &Path,
    plan: Plan,
    on_chunk: &(dyn Fn() + Sync),
) -> Result<WriteReport> {
    let normals = Mutex::new(team.together(Normals::new(ctx))?);
    let read = |lo: [usize; 3], size: [usize; 3]| -> Result<Vec<Volume>> {
        let (v, offset) = read_widened(src, NORMALS_HALO, lo, size)?;
        let staged = Normals::stage(ctx, &v, range)?;
        locked(&normals)?.run(&staged)?;
        // Read back outside the lock, so that another chunk's passes run meanwhile; freed under
        // it, with no recording open (see `importance_store`).
        let g = staged.channels_in(v.dims, (offset, size));
        let pass = locked(&normals)?;
        drop(staged);
        drop(pass);
        g?.into_iter()
            .map(|one| Volume::new(size, v.spacing, VoxelData::F32(one)))
            .collect()
    };
    let channels = Channels::over(src, (4, VoxelType::F32), &read);
    write_channels_in(team, out, &channels, &options(plan), on_chunk)
}

/// Adds the (intensity, occlusion) pairs of one chunk to the spectrum's counts, binned as
/// `glsl/occlusion/spectrum.comp` bins them.
fn add_to_spectrum(counts: &mut [u64], [bx, by]: [usize; 2], s: &Volume, o: &Volume) {
    for i in 0..s.len() {
        let (si, oi) = (s.data.get_f64(i) as f32, o.data.get_f64(i) as f32);
        let x = ((si * bx as f32) as i64).clamp(0, bx as i64 - 1) as usize;
        let y = ((oi * by as f32) as i64).clamp(0, by as i64 - 1) as usize;
        counts[y * bx + x] += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plan_holds_as_many_chunks_as_the_budget() {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        // 276³ boxes of 24 bytes a voxel are 481 MiB: two fit 1 GiB; 148³ ones are 74 MiB,
        // and eight of them fit.
        let p = Plan::new([512; 3], (10, 24), None, 1 << 30).unwrap();
        assert!(p.workers as u64 * box_bytes([512; 3], p.chunk, 10, 24) <= 1 << 30);
        assert!(p.workers >= cores.min(8), "{p:?} on {cores} cores");
        if cores <= 2 {
            assert_eq!(p.chunk, 256);
        }
        // 84³ boxes of 64³ chunks: one per core.
        let p = Plan::new([512; 3], (10, 24), Some(64), 1 << 30).unwrap();
        assert_eq!((p.chunk, p.workers), (64, cores.min(75)));
        // Never fewer than one.
        assert_eq!(
            Plan::new([512; 3], (10, 24), Some(256), 1).unwrap().workers,
            1
        );
    }

    #[test]
    fn chunks_fit_the_budget_twice() {
        let mib = 1u64 << 20;
        assert_eq!(chunk_for([512; 3], 5, 24, 4096 * mib).unwrap(), 256);
        let c = chunk_for([512; 3], 16, 24, 64 * mib).unwrap();
        assert!(2 * ((c + 32) as u64).pow(3) * 24 <= 64 * mib, "{c}");
        assert_eq!(chunk_for([40; 3], 5, 24, 64 * mib).unwrap(), 40);
        let refused = chunk_for([512; 3], 64, 40, mib).unwrap_err().to_string();
        assert!(refused.contains("raise --memory-budget"), "{refused}");
    }
}
