//! OME-Zarr stores over HTTP (issue 42): a store served by a local server, started here, reads
//! voxel for voxel as it reads from disk and renders the same picture; requests run in
//! parallel and land in the chunk cache; a server that adds 50 ms to every answer, answers 404
//! and 500, cuts its bodies short or stalls partway is tried again, and when it never mends,
//! the command fails in one sentence and leaves no output behind.

mod common;
#[path = "common/http_server.rs"]
mod http_server;

use http_server::{Fault, Server};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;

/// A Shepp–Logan store of 48³ in chunks of 16 (27 chunks at level 0) with two levels, in `dir`.
fn store(dir: &Path) -> PathBuf {
    common::phantom_store(dir, "s.ome.zarr", "shepp-logan:48", 16)
}

/// `vellum convert INPUT out` with `flags`, read back; or the error.
fn convert(input: &str, out: &Path, flags: &[&str]) -> Result<vellum::volume::Volume, String> {
    let mut args = vec!["convert", input, out.to_str().unwrap()];
    args.extend_from_slice(flags);
    let o = common::vellum(&args);
    if !o.status.success() {
        return Err(String::from_utf8_lossy(&o.stderr).into_owned());
    }
    Ok(vellum::volume::io::load(out, None).unwrap())
}

fn is_chunk(path: &str) -> bool {
    path.contains("/c/")
}

#[test]
fn a_store_on_a_slow_server_reads_voxel_for_voxel_in_parallel_and_lands_in_the_cache() {
    let dir = tempfile::tempdir().unwrap();
    let local = store(dir.path());
    let cache = dir.path().join("cache");
    let server = Server::start(dir.path(), 50, |_, _| Fault::None);
    let url = server.url("s.ome.zarr");
    let want = vellum::volume::io::load(&local, None).unwrap();
    let flags = ["--cache-dir", cache.to_str().unwrap()];
    let got = convert(&url, &dir.path().join("a.nrrd"), &flags).unwrap();
    assert_eq!(got.dims, want.dims);
    assert_eq!(got.spacing, want.spacing);
    assert_eq!(
        got.data, want.data,
        "the voxels read over HTTP are the store's"
    );
    let chunks = server.asked("/0/c/");
    assert_eq!(chunks, 27, "every chunk of level 0 asked once");
    let most = server.state.max_in_flight.load(Ordering::SeqCst);
    // A level read whole goes chunk by chunk on 16 readers (`Multiscale::read_box`), not on
    // the decoders' pool of one thread a core, which kept 2 in flight on a 2-core machine.
    assert!(
        most >= 8,
        "requests ran a few at a time ({most} at most in flight)"
    );
    // Again, through the cache: no chunk is asked again, and the voxels are the same.
    let again = convert(&url, &dir.path().join("b.nrrd"), &flags).unwrap();
    assert_eq!(again.data, want.data);
    assert_eq!(
        server.asked("/0/c/"),
        chunks,
        "the cache served every chunk"
    );
    let files = std::fs::read_dir(&cache).unwrap().count();
    assert_eq!(files, 27, "one cache file per chunk");
    // Without a cache, every chunk is asked again.
    let none = convert(&url, &dir.path().join("c.nrrd"), &["--cache-mib", "0"]).unwrap();
    assert_eq!(none.data, want.data);
    assert_eq!(server.asked("/0/c/"), 2 * chunks);
}

#[test]
fn a_server_that_fails_once_per_chunk_is_tried_again_and_reads_right() {
    let dir = tempfile::tempdir().unwrap();
    let local = store(dir.path());
    let want = vellum::volume::io::load(&local, None).unwrap();
    // The first answer for each chunk: 500, a body cut in half, a stall, or a 404 of the
    // store's metadata (which no retry mends: the store is then not there).
    let faults = [Fault::Error, Fault::Truncate, Fault::Stall];
    for fault in faults {
        let server = Server::start(dir.path(), 0, move |path, seen| {
            // The stall is met by one chunk only: each costs a time-out.
            let chunk = if fault == Fault::Stall {
                path.ends_with("/0/c/1/1/1")
            } else {
                is_chunk(path)
            };
            if chunk && seen == 0 {
                fault
            } else {
                Fault::None
            }
        });
        let out = dir.path().join(format!("{fault:?}.nrrd"));
        let flags = ["--cache-mib", "0", "--http-timeout", "1"];
        let got = convert(&server.url("s.ome.zarr"), &out, &flags)
            .unwrap_or_else(|e| panic!("{fault:?} once per chunk: {e}"));
        assert_eq!(got.data, want.data, "{fault:?} once per chunk");
    }
}

#[test]
fn a_server_that_never_mends_is_one_sentence_and_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    store(dir.path());
    let cases: [(Fault, &str, &[&str]); 4] = [
        (
            Fault::Error,
            "/0/c/0/0/0",
            &["500", "tried 4 times", "s.ome.zarr", "0/c/0/0/0"],
        ),
        (
            Fault::Truncate,
            "/0/c/0/0/0",
            &["broke off after", "tried 4 times"],
        ),
        (
            Fault::Stall,
            "/0/c/0/0/0",
            &["stalled: no byte for 0.5 s", "tried 4 times"],
        ),
        (Fault::NotFound, "/zarr.json", &["no readable Zarr group"]),
    ];
    for (fault, key, phrases) in cases {
        let key = key.to_string();
        let server = Server::start(dir.path(), 0, move |path, _| {
            if path.ends_with(&key) {
                fault
            } else {
                Fault::None
            }
        });
        let out = dir.path().join("never.nrrd");
        let flags = ["--cache-mib", "0", "--http-timeout", "0.5"];
        let e = convert(&server.url("s.ome.zarr"), &out, &flags).unwrap_err();
        let line = e.trim();
        assert!(
            line.starts_with("error: ") && !line.contains('\n'),
            "{fault:?}: {line}"
        );
        assert!(!line.contains("panicked"), "{fault:?}: {line}");
        for p in phrases {
            assert!(line.contains(p), "{fault:?}: expected `{p}` in: {line}");
        }
        assert!(!out.exists(), "{fault:?} left a partial output");
        eprintln!("{fault:?}: {line}");
    }
    // Nothing listening.
    let closed = TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}/s.ome.zarr", closed.local_addr().unwrap());
    drop(closed);
    let e = convert(&url, &dir.path().join("x.nrrd"), &["--cache-mib", "0"]).unwrap_err();
    assert!(
        e.trim().starts_with("error: ") && e.contains("s.ome.zarr"),
        "{e}"
    );
}

#[test]
fn a_store_on_a_server_renders_the_picture_it_renders_from_disk() {
    let dir = tempfile::tempdir().unwrap();
    // 96³: its intensity alone (1.7 MiB) exceeds a budget of 1 MiB, so that budget bricks it.
    let local = common::phantom_store(dir.path(), "s.ome.zarr", "shepp-logan:96", 32);
    let server = Server::start(dir.path(), 0, |_, _| Fault::None);
    let render = |input: &str, out: &str, budget: &str| {
        let out = dir.path().join(out);
        let o = common::vellum(&[
            "render",
            input,
            "--out",
            out.to_str().unwrap(),
            "--size",
            "64x64",
            "--renderer",
            "raycast",
            "--gpu-budget",
            budget,
            "--cache-mib",
            "0",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        image::open(&out).unwrap().to_rgba8()
    };
    let url = server.url("s.ome.zarr");
    let disk = render(local.to_str().unwrap(), "disk.png", "512");
    let remote = render(&url, "http.png", "512");
    assert_eq!(disk, remote, "in core: the same pixels");
    assert!(
        disk.pixels().any(|p| p[0] > 40),
        "the picture shows the phantom"
    );
    // Through the brick cache: a pool smaller than the volume.
    let before = server.asked("/0/c/");
    let disk = render(local.to_str().unwrap(), "disk_b.png", "1");
    let remote = render(&url, "http_b.png", "1");
    assert_eq!(disk, remote, "bricked: the same pixels");
    assert!(
        server.asked("/0/c/") > before,
        "the bricks were read over HTTP"
    );
}

#[test]
fn a_cache_folder_that_cannot_be_made_is_one_sentence() {
    let dir = tempfile::tempdir().unwrap();
    store(dir.path());
    let server = Server::start(dir.path(), 0, |_, _| Fault::None);
    let file = dir.path().join("a-file");
    std::fs::write(&file, b"x").unwrap();
    let bad = file.join("cache");
    let e = convert(
        &server.url("s.ome.zarr"),
        &dir.path().join("y.nrrd"),
        &["--cache-dir", bad.to_str().unwrap()],
    )
    .unwrap_err();
    assert!(e.contains("--cache-dir") && !e.trim().contains('\n'), "{e}");
}
