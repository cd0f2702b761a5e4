//! Passes chunk by chunk (issue 26), on lavapipe with validation on:
//! - the importance map and the occlusion volume (runs, GPU FFT, CPU FFT) computed in chunks of
//!   32³ with their halos equal the in-core pass within max |Δ| ≤ 1e-5 (observed: ΔD bit for bit,
//!   O ≤ 1.3e-6), max |ΔD| and the spectrum are the whole grid's (the spectrum count for count);
//! - the Sobel normals computed in chunks with their one-voxel halo equal the in-core gradient
//!   texture bit for bit, all four channels, on a phantom and the real engine block;
//! - from the command line, a chunked importance map stays within its memory budget's order
//!   (host peak far below the in-core need, device peak below the budget), and a store input
//!   without a store output is one sentence.

mod common;

use common::Gpu;
use vellum::classify::mapping::{Neighbourhood, Visibility};
use vellum::passes::chunked::{importance_store, normals_store, occlusion_store};
use vellum::passes::importance::ImportanceMap;
use vellum::passes::occlusion::{Method, Occlusion, OcclusionParams};
use vellum::team::Solo;
use vellum::volume::io::ome_zarr::Multiscale;
use vellum::volume::{phantom, Volume};

fn max_abs_diff(a: &Volume, b: &Volume) -> f64 {
    assert_eq!(a.dims, b.dims);
    (0..a.len())
        .map(|i| (a.data.get_f64(i) - b.data.get_f64(i)).abs())
        .fold(0.0, f64::max)
}

/// Chunks of edge `chunk`, two in flight at once: one thread prepares or writes a chunk while
/// the other's passes run.
fn plan(chunk: usize) -> vellum::passes::chunked::Plan {
    vellum::passes::chunked::Plan { chunk, workers: 2 }
}

#[test]
fn chunked_importance_is_the_in_core_importance() {
    let gpu = Gpu::new();
    let v = phantom::shepp_logan(80);
    let whole = ImportanceMap::new(&gpu.ctx)
        .unwrap()
        .compute(&v, 5, false)
        .unwrap()
        .delta_d;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("dd.ome.zarr");
    let report = importance_store((&Solo, &gpu.ctx), &v, 5, &out, plan(32), &|| {}).unwrap();
    let chunked = Multiscale::open(&out).unwrap().read_level(0).unwrap();
    let d = max_abs_diff(&whole, &chunked);
    println!("importance: max |Δ| {d:e}");
    assert!(d <= 1e-5, "{d}");
    let r = vellum::volume::stats::value_range(&whole);
    assert_eq!(report.range, r, "max |ΔD| is the whole grid's");
    assert_eq!(report.chunks, 27 + 8);
}

/// The chunked normals of `v` (chunk `chunk`) against the in-core gradient texture: every
/// channel of level 0 bit for bit.
fn normals_match(gpu: &Gpu, v: &Volume, chunk: usize) {
    let normals = vellum::passes::normals::Normals::new(&gpu.ctx).unwrap();
    let range = v.normalised_range();
    let whole = normals.gradients(v, range).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("n.ome.zarr");
    let report = normals_store((&Solo, &gpu.ctx), v, range, &out, plan(chunk), &|| {}).unwrap();
    assert_eq!(
        report.levels,
        vellum::volume::io::ome_zarr::auto_levels(v.dims)
    );
    assert!(
        Multiscale::open(&out).is_err(),
        "four channels are refused as a scalar grid"
    );
    let mut moved = 0;
    for c in [0, 1, 2, 3] {
        let ms = Multiscale::open_channel(&out, c).unwrap();
        assert_eq!(ms.channels, 4);
        let got = ms.read_level(0).unwrap();
        assert_eq!(got.dims, v.dims);
        let differ = (0..got.len())
            .filter(|&i| got.data.get_f64(i) as f32 != whole[i][c])
            .count();
        assert_eq!(differ, 0, "channel {c}: {differ} voxels differ");
        moved += (0..got.len()).filter(|&i| whole[i][c] != 0.0).count();
    }
    assert!(
        moved > v.len() / 50,
        "the gradients are not all zero ({moved})"
    );
}

#[test]
fn chunked_normals_are_the_in_core_gradients() {
    let gpu = Gpu::new();
    // 70 is not a multiple of the chunk: the last chunks are partial.
    normals_match(&gpu, &phantom::shepp_logan(70), 32);
    if let Some(engine) = common::real_volume("engine") {
        normals_match(&gpu, &engine, 64);
    }
}

#[test]
fn chunked_occlusion_is_the_in_core_occlusion_with_its_spectrum() {
    let gpu = Gpu::new();
    let v = phantom::nested(72);
    let range = v.normalised_range();
    let mut occ = Occlusion::new(&gpu.ctx).unwrap();
    for method in [Method::Runs, Method::FftGpu, Method::FftCpu] {
        let p = OcclusionParams {
            radius: 7,
            visibility: Visibility::Ramp,
            neighbourhood: Neighbourhood::Ball,
            stride: 1,
            spectrum_bins: Some([64, 32]),
            method,
            pad: None,
        };
        let whole = occ.compute(&v, &p).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("o.ome.zarr");
        let (_, spectrum) =
            occlusion_store((&Solo, &gpu.ctx), &v, &p, range, &out, plan(32), &|| {}).unwrap();
        let chunked = Multiscale::open(&out).unwrap().read_level(0).unwrap();
        let d = max_abs_diff(&whole.occlusion, &chunked);
        println!("occlusion {}: max |Δ| {d:e}", method.name());
        assert!(d <= 1e-5, "{}: {d}", method.name());
        let (a, b) = (whole.spectrum.unwrap(), spectrum.unwrap());
        assert_eq!(a.intensity_range, b.intensity_range);
        let differ = a
            .counts
            .iter()
            .zip(&b.counts)
            .filter(|(x, y)| x != y)
            .count();
        // A voxel whose O lies within rounding of a bin edge may fall on the other side.
        assert!(differ <= 2, "{}: {differ} bins differ", method.name());
        assert_eq!(b.counts.iter().map(|&c| c as usize).sum::<usize>(), v.len());
    }
    let strided = OcclusionParams {
        stride: 2,
        ..OcclusionParams::ball(7, Method::Runs)
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s.ome.zarr");
    let refused = occlusion_store(
        (&Solo, &gpu.ctx),
        &v,
        &strided,
        range,
        &out,
        plan(32),
        &|| {},
    );
    assert!(refused.unwrap_err().to_string().contains("stride 1"));
    assert!(!out.exists());
}

#[test]
fn a_chunked_pass_keeps_to_its_memory_budget() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("dd.ome.zarr");
    let o = out.to_str().unwrap();
    // 288³: the in-core pass needs about 550 MiB of host memory; the chunked one a few chunks.
    let args = [
        "importance",
        "phantom:shepp-logan:288",
        "--radius",
        "5",
        "--out",
        o,
        "--memory-budget",
        "64",
        "--json",
    ];
    let r = common::ok_json(&common::vellum(&args));
    let (host, device) = (
        r["peak_rss_mib"].as_f64().unwrap(),
        r["peak_device_mib"].as_f64().unwrap(),
    );
    println!(
        "chunk {}: host peak {host:.0} MiB, device peak {device:.0} MiB",
        r["chunk"]
    );
    assert!(device <= 64.0, "device peak {device} MiB");
    // The process itself (lavapipe, shaders, validation) takes about 110 MiB before any chunk.
    assert!(host < 110.0 + 3.0 * 64.0, "host peak {host} MiB");
    assert!(Multiscale::open(&out).unwrap().levels.len() >= 3);
    // A store input needs a store output.
    let store = dir.path().join("in.ome.zarr");
    let s = store.to_str().unwrap();
    common::ok_json(&common::vellum(&[
        "convert",
        "phantom:nested:40",
        s,
        "--json",
    ]));
    common::fails_with(
        &common::vellum(&["importance", s, "--out", "dd.nrrd"]),
        "expected --out x.ome.zarr",
    );
    // The normals from the command line: a store of four channels that `info` describes, and
    // a file output refused in one sentence.
    let normals = dir.path().join("n.ome.zarr");
    let n = normals.to_str().unwrap();
    let r = common::ok_json(&common::vellum(&["normals", s, "--out", n, "--json"]));
    assert_eq!(r["halo"], 1);
    let info = common::ok_json(&common::vellum(&["info", n, "--json"]));
    assert_eq!(info["channels"], 4);
    common::fails_with(
        &common::vellum(&["normals", s, "--out", "n.nrrd"]),
        "expected --out x.ome.zarr",
    );
    assert!(!std::path::Path::new("n.nrrd").exists());
}
