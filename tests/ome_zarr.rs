//! OME-Zarr stores (issue 26): NGFF 0.5 written and read back voxel for voxel with its pyramid;
//! an NGFF 0.4 (Zarr v2) store written by hand, byte by byte from the specs, read; missing chunks
//! read as the fill value; bad stores refused with one sentence and nothing left behind.

mod common;

use std::path::Path;
use vellum::volume::geometry::Geometry;
use vellum::volume::io::ome_zarr::{auto_levels, halve, write, Multiscale, WriteOptions};
use vellum::volume::{phantom, Volume, VoxelData};

/// Shepp–Logan as u16, cropped to n × (n − 4) × (n − 2), with anisotropic spacing and an origin.
fn sample(n: usize) -> Volume {
    let cube = phantom::shepp_logan(n);
    let dims = [n, n - 4, n - 2];
    let mut data = Vec::with_capacity(dims.iter().product());
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                data.push((cube.data.get_f64(x + n * (y + n * z)) * 1000.0).round() as u16);
            }
        }
    }
    Volume::new(dims, [0.5, 0.75, 1.25], VoxelData::U16(data))
        .unwrap()
        .with_geometry(Geometry {
            origin: [10.0, -4.0, 2.5],
            ..Geometry::default()
        })
        .unwrap()
}

#[test]
fn a_written_store_reads_back_voxel_for_voxel_with_its_pyramid() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sample.ome.zarr");
    let v = sample(70);
    write(
        &path,
        &v,
        &WriteOptions {
            chunk: 16,
            levels: None,
            threads: None,
        },
    )
    .unwrap();
    let m = Multiscale::open(&path).unwrap();
    assert_eq!(m.version, "0.5");
    assert_eq!(m.levels.len(), auto_levels(v.dims));
    assert_eq!(m.levels.len(), 2, "70 voxels halve once to 35 ≤ 64");
    assert_eq!(m.levels[0].dims, v.dims);
    assert_eq!(m.levels[0].chunk, [16, 16, 16]);
    assert_eq!(m.levels[1].dims, [35, 33, 34]);
    assert_eq!(m.levels[1].spacing, [1.0, 1.5, 2.5]);
    let back = m.read_level(0).unwrap();
    assert_eq!(back.dims, v.dims);
    assert_eq!(back.spacing, v.spacing);
    assert_eq!(back.geometry.origin, v.geometry.origin);
    assert_eq!(back.data, v.data, "level 0 is the input, voxel for voxel");
    let coarse = m.read_level(1).unwrap();
    let expected = halve(&v).unwrap();
    assert_eq!(coarse.data, expected.data, "level 1 is the 2×2×2 mean");
    assert_eq!(coarse.geometry.origin, [10.25, -3.625, 3.125]);
    // The loader takes a store as an input like any volume file.
    let loaded = vellum::volume::io::load(&path, None).unwrap();
    assert_eq!(loaded.data, v.data);
}

/// The brick cache's reads (`read_box_into`, into a buffer it reuses) decode a whole chunk of a
/// store vellum wrote (the bytes codec and zstd alone) straight into that buffer, past zarrs:
/// each chunk, whole or at the store's edge, absent or present, is what zarrs' own read gives,
/// and a chunk that decodes to fewer bytes than its shape holds is named.
#[test]
fn a_chunk_read_into_a_reused_buffer_is_what_zarrs_reads() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sample.ome.zarr");
    let v = sample(40);
    let opts = WriteOptions {
        chunk: 16,
        levels: Some(1),
        threads: None,
    };
    write(&path, &v, &opts).unwrap();
    // An absent chunk reads as the fill value.
    std::fs::remove_file(path.join("0/c/1/1/1")).unwrap();
    let m = Multiscale::open(&path).unwrap();
    let mut buf = VoxelData::U16(Vec::new());
    let mut chunks = 0;
    for z in (0..v.dims[2]).step_by(16) {
        for y in (0..v.dims[1]).step_by(16) {
            for x in (0..v.dims[0]).step_by(16) {
                let lo = [x, y, z];
                let size: [usize; 3] = std::array::from_fn(|a| 16.min(v.dims[a] - lo[a]));
                let n = size.iter().product();
                if buf.len() != n {
                    buf = VoxelData::U16(vec![7; n]);
                }
                m.read_box_into(0, lo, size, &mut buf).unwrap();
                assert_eq!(
                    buf,
                    m.read_box(0, lo, size).unwrap().data,
                    "chunk at {lo:?}"
                );
                chunks += 1;
            }
        }
    }
    assert_eq!(chunks, 27);
    // The absent chunk's box holds the fill value, and a present one the input's voxels.
    let mut buf = VoxelData::U16(vec![7; 16 * 16 * 16]);
    m.read_box_into(0, [16; 3], [16; 3], &mut buf).unwrap();
    assert_eq!(buf, VoxelData::U16(vec![0; 16 * 16 * 16]));
    m.read_box_into(0, [0; 3], [16; 3], &mut buf).unwrap();
    let VoxelData::U16(got) = &buf else { panic!() };
    assert_eq!(
        got[16 * 16 * 15 + 16 * 15 + 15],
        v.data.get_f64(v.index(15, 15, 15)) as u16
    );
    // A zstd frame of a chunk too short for its shape: one sentence naming the chunk.
    let short = zstd::bulk::compress(&[1u8; 100], 1).unwrap();
    std::fs::write(path.join("0/c/0/0/0"), short).unwrap();
    let e = m
        .read_box_into(0, [0; 3], [16; 3], &mut buf)
        .expect_err("refused")
        .to_string();
    assert!(
        e.contains("chunk 0/c/0/0/0 of level 0 could not be read"),
        "{e}"
    );
}

#[test]
fn halving_averages_each_block_and_what_an_odd_edge_has() {
    let v = Volume::new(
        [3, 2, 1],
        [1.0; 3],
        VoxelData::F32(vec![1.0, 3.0, 10.0, 5.0, 7.0, 20.0]),
    )
    .unwrap();
    let h = halve(&v).unwrap();
    assert_eq!(h.dims, [2, 1, 1]);
    assert_eq!(h.data, VoxelData::F32(vec![4.0, 15.0]));
}

/// (t, c, z, y, x) axes, as the v2 helper's arrays have them.
const TCZYX: &str =
    r#"[{"name": "t"}, {"name": "c"}, {"name": "z"}, {"name": "y"}, {"name": "x"}]"#;

/// Writes `bytes` to `path`, making its folder.
fn put(path: &Path, bytes: &[u8]) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, bytes).unwrap();
}

/// An NGFF 0.4 store on Zarr v2 as another tool writes it: `.zgroup`, `.zattrs` with the
/// multiscales, and one uncompressed array with `/`-separated chunk keys, (t, c, z, y, x) axes.
fn v2_store(
    root: &Path,
    dims_zyx: [usize; 3],
    chunk: usize,
    axes: &str,
    shape_tc: [usize; 2],
) -> Vec<u16> {
    put(&root.join(".zgroup"), br#"{"zarr_format": 2}"#);
    let attrs = format!(
        r#"{{"multiscales": [{{"version": "0.4", "axes": {axes},
            "datasets": [{{"path": "0", "coordinateTransformations": [
                {{"type": "scale", "scale": [1.0, 1.0, 2.0, 0.5, 0.25]}},
                {{"type": "translation", "translation": [0.0, 0.0, 3.0, 2.0, 1.0]}}]}}]}}]}}"#
    );
    put(&root.join(".zattrs"), attrs.as_bytes());
    let [z, y, x] = dims_zyx;
    let zarray = format!(
        r#"{{"zarr_format": 2, "shape": [{}, {}, {z}, {y}, {x}], "chunks": [1, 1, {chunk}, {chunk}, {chunk}],
            "dtype": "<u2", "compressor": null, "fill_value": 7, "order": "C", "filters": null,
            "dimension_separator": "/"}}"#,
        shape_tc[0], shape_tc[1]
    );
    put(&root.join("0/.zarray"), zarray.as_bytes());
    let value = |i: usize, j: usize, k: usize| (i * 10_000 + j * 100 + k) as u16;
    let cells = [z, y, x].map(|n| n.div_ceil(chunk));
    for cz in 0..cells[0] {
        for cy in 0..cells[1] {
            for cx in 0..cells[2] {
                // A v2 chunk is always whole; voxels past the array's edge are ignored.
                let mut bytes = Vec::new();
                for i in 0..chunk {
                    for j in 0..chunk {
                        for k in 0..chunk {
                            let v = value(cz * chunk + i, cy * chunk + j, cx * chunk + k);
                            bytes.extend_from_slice(&v.to_le_bytes());
                        }
                    }
                }
                put(&root.join(format!("0/0/0/{cz}/{cy}/{cx}")), &bytes);
            }
        }
    }
    let mut all = Vec::new();
    for i in 0..z {
        for j in 0..y {
            for k in 0..x {
                all.push(value(i, j, k));
            }
        }
    }
    all
}

#[test]
fn an_ngff_0_4_store_on_zarr_v2_is_read_with_its_scale_and_translation() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("v2.zarr");
    let axes = r#"[{"name": "t", "type": "time"}, {"name": "c", "type": "channel"},
        {"name": "z", "type": "space"}, {"name": "y", "type": "space"}, {"name": "x", "type": "space"}]"#;
    let expected = v2_store(&root, [5, 6, 9], 4, axes, [1, 1]);
    let m = Multiscale::open(&root).unwrap();
    assert_eq!(m.version, "0.4");
    assert_eq!(m.levels[0].dims, [9, 6, 5]);
    assert_eq!(m.levels[0].spacing, [0.25, 0.5, 2.0]);
    let v = m.read_level(0).unwrap();
    assert_eq!(v.geometry.origin, [1.0, 2.0, 3.0]);
    assert_eq!(v.data, VoxelData::U16(expected.clone()));
    // A missing chunk reads as the fill value (7), as the Zarr spec says.
    std::fs::remove_file(root.join("0/0/0/0/0/0")).unwrap();
    let v = Multiscale::open(&root).unwrap().read_level(0).unwrap();
    let VoxelData::U16(d) = &v.data else { panic!() };
    assert_eq!(d[0], 7);
    assert_eq!(d[4], expected[4], "x = 4 is in the next chunk");
}

#[test]
fn bad_stores_are_one_sentence() {
    let dir = tempfile::tempdir().unwrap();
    // Two channels.
    let root = dir.path().join("channels.zarr");
    v2_store(&root, [2, 2, 2], 2, TCZYX, [1, 2]);
    let e = Multiscale::open(&root).err().expect("refused").to_string();
    assert!(
        e.contains("2 channels") && e.contains("pick one with `channels` (0 to 1)"),
        "{e}"
    );
    // Read one channel at a time, it opens: channel 1 has no chunks, so it is the fill value.
    let c1 = Multiscale::open_channel(&root, 1).unwrap();
    assert_eq!(c1.channels, 2);
    assert_eq!(c1.read_level(0).unwrap().data, VoxelData::U16(vec![7; 8]));
    let e = Multiscale::open_channel(&root, 2)
        .err()
        .expect("refused")
        .to_string();
    assert!(e.contains("channel 2 does not exist"), "{e}");
    // Two time points: one is picked, and one that does not exist is named.
    let root = dir.path().join("times.zarr");
    v2_store(&root, [2, 2, 2], 2, TCZYX, [2, 1]);
    let e = Multiscale::open(&root).err().expect("refused").to_string();
    assert!(e.contains("2 time points; pick one with `time`"), "{e}");
    let pick = |time| vellum::volume::io::ome_zarr::Pick {
        time: Some(time),
        channel: None,
    };
    let t1 = Multiscale::open_picked(&root, pick(1)).unwrap();
    assert_eq!((t1.times, t1.channels), (2, 1));
    assert_eq!(t1.read_level(0).unwrap().data, VoxelData::U16(vec![7; 8]));
    let e = Multiscale::open_picked(&root, pick(2))
        .err()
        .expect("refused")
        .to_string();
    assert!(e.contains("time point 2 does not exist (`time`)"), "{e}");
    // Axes that are not z, y, x.
    let root = dir.path().join("axes.zarr");
    v2_store(
        &root,
        [2, 2, 2],
        2,
        r#"[{"name": "t"}, {"name": "c"}, {"name": "x"}, {"name": "y"}, {"name": "z"}]"#,
        [1, 1],
    );
    let e = Multiscale::open(&root).err().expect("refused").to_string();
    assert!(
        e.contains("expected (z, y, x), (c, z, y, x), (t, z, y, x) or (t, c, z, y, x)"),
        "{e}"
    );
    // No multiscales metadata.
    let root = dir.path().join("plain.zarr");
    put(&root.join(".zgroup"), br#"{"zarr_format": 2}"#);
    let e = Multiscale::open(&root).err().expect("refused").to_string();
    assert!(e.contains("no OME-NGFF multiscales metadata"), "{e}");
    // A corrupt chunk is named by its key.
    let root = dir.path().join("corrupt.zarr");
    v2_store(&root, [4, 4, 4], 4, TCZYX, [1, 1]);
    put(&root.join("0/0/0/0/0/0"), b"short");
    let e = Multiscale::open(&root)
        .unwrap()
        .read_level(0)
        .expect_err("refused")
        .to_string();
    assert!(
        e.contains("chunk 0/0/0/0/0/0 of level 0 could not be read"),
        "{e}"
    );
    // Writing over an existing folder is refused and leaves it as it was.
    let v = sample(8);
    let e = write(&root, &v, &WriteOptions::default())
        .expect_err("refused")
        .to_string();
    assert!(e.contains("already exists"), "{e}");
    assert!(root.join("0/.zarray").exists());
}

/// A store written by Python's ome-zarr package (the peer: its default pyramid and codecs, zstd
/// on Zarr v2 for NGFF 0.4, Zarr v3 for 0.5) opens, reads voxel for voxel, and works in `info`.
/// Needs python3 with ome-zarr; under CI its absence fails.
#[test]
fn stores_written_by_python_ome_zarr_are_read() {
    if !common::python_with("ome_zarr, zarr, numpy") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for version in ["0.4", "0.5"] {
        let store = dir.path().join(format!("python-{version}.zarr"));
        common::support_script("write_ome_zarr.py", &[store.as_os_str(), version.as_ref()]);
        let raw = std::fs::read(store.with_extension("zarr.raw")).unwrap();
        let expected: Vec<u16> = raw
            .chunks_exact(2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .collect();
        let m = Multiscale::open(&store).unwrap();
        assert_eq!(m.version, version);
        assert_eq!(m.levels[0].dims, [14, 10, 12]);
        assert!(m.levels.len() > 1, "the package writes a pyramid");
        let v = m.read_level(0).unwrap();
        assert_eq!(v.data, VoxelData::U16(expected), "NGFF {version}");
        for l in 1..m.levels.len() {
            let coarse = m.read_level(l).unwrap();
            assert_eq!(coarse.dims, m.levels[l].dims);
        }
        let info = std::process::Command::new(env!("CARGO_BIN_EXE_vellum"))
            .arg("info")
            .arg(&store)
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&info.stdout);
        assert!(
            info.status.success() && text.contains("14 x 10 x 12"),
            "{text}"
        );
    }
}

// ---- Stores under hostile input (issue 40): each class the issue lists, as a user meets it on
// the command line: one sentence, nothing written, no temporary folder left behind.

/// `convert phantom:shepp-logan:32 NAME --chunk 16 --levels 2` into `dir`: 32³ and 16³ f32.
fn phantom_store(dir: &Path, name: &str) -> std::path::PathBuf {
    common::phantom_store(dir, name, "shepp-logan:32", 16)
}

/// Rewrites the JSON document at `path` through `f`.
fn edit_json(path: &Path, f: impl FnOnce(&mut serde_json::Value)) {
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(path, serde_json::to_vec_pretty(&v).unwrap()).unwrap();
}

/// The multiscale of a vellum store's root `zarr.json`.
fn multiscale(v: &mut serde_json::Value) -> &mut serde_json::Value {
    &mut v["attributes"]["ome"]["multiscales"][0]
}

/// Every command that reads `store` (info, render, importance and convert to a store) refuses
/// it in one sentence holding `phrases`, and writes nothing.
fn every_command_refuses(dir: &Path, store: &Path, phrases: &[&str]) {
    let s = store.to_str().unwrap();
    let out = |name: &str| dir.join(name).to_string_lossy().into_owned();
    let runs: [Vec<String>; 4] = [
        vec!["info".into(), s.into()],
        vec![
            "render".into(),
            s.into(),
            "--size".into(),
            "32x32".into(),
            "--out".into(),
            out("r.png"),
        ],
        vec![
            "importance".into(),
            s.into(),
            "--radius".into(),
            "2".into(),
            "--out".into(),
            out("dd.ome.zarr"),
        ],
        vec!["convert".into(), s.into(), out("c.ome.zarr")],
    ];
    for args in runs {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        common::fails_with_all(&common::vellum(&args), phrases);
    }
}

#[test]
fn declared_shapes_beyond_the_limits_are_one_sentence_before_anything_is_allocated() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (name, shape0, phrase) in [
        ("big.ome.zarr", 1u64 << 40, "expected at most 1048576"),
        ("huge.ome.zarr", 1u64 << 63, "expected at most 1048576"),
        ("empty.ome.zarr", 0, "empty along z"),
    ] {
        let root = phantom_store(d, name);
        edit_json(&root.join("0/zarr.json"), |v| v["shape"][0] = shape0.into());
        every_command_refuses(d, &root, &["level 0", phrase]);
        common::only(d, &[name]);
        std::fs::remove_dir_all(&root).unwrap();
    }
    // Zarr v2 alike.
    let root = d.join("v2.zarr");
    v2_store(&root, [4, 4, 4], 2, TCZYX, [1, 1]);
    edit_json(&root.join("0/.zarray"), |v| {
        v["shape"][2] = (1u64 << 40).into()
    });
    every_command_refuses(d, &root, &["level 0", "expected at most 1048576"]);
    // A scene whose input is such a store says the same.
    edit_json(&root.join("0/.zarray"), |v| v["shape"][2] = 0.into());
    let scene = d.join("scene.json");
    let text = format!(
        r#"{{"version": 1, "input": {{"path": "{}"}}}}"#,
        root.display()
    );
    std::fs::write(&scene, text).unwrap();
    let png = d.join("s.png");
    let out = common::vellum(&[
        "render",
        "--scene",
        scene.to_str().unwrap(),
        "--out",
        png.to_str().unwrap(),
    ]);
    common::fails_with(&out, "empty along z");
    common::only(d, &["v2.zarr", "scene.json"]);
}

/// Runs vellum with `args`, killing it after a minute: a read that blocks fails the test
/// rather than hanging it.
fn vellum_within_a_minute(args: &[&str]) -> std::process::Output {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_vellum"))
        .args(args)
        .env("VELLUM_VALIDATION", "1")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > std::time::Duration::from_secs(60) {
            child.kill().unwrap();
            panic!("vellum {args:?} was still running after a minute");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

#[test]
fn chunks_that_would_block_or_decode_beyond_their_size_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let root = phantom_store(d, "s.ome.zarr");
    let s = root.to_str().unwrap();
    let chunk = root.join("0/c/0/0/0");
    // A zstd bomb: a few KB that would decode to 256 MiB, where the chunk holds 16 KiB.
    let zeros = vec![0u8; 256 << 20];
    std::fs::write(&chunk, zstd::bulk::compress(&zeros, 1).unwrap()).unwrap();
    drop(zeros);
    common::fails_with_all(
        &vellum_within_a_minute(&["info", s]),
        &["0/c/0/0/0", "decodes to more than 16384 bytes"],
    );
    // A FIFO as a chunk, and as the array's metadata: refused at once, never opened.
    std::fs::remove_file(&chunk).unwrap();
    let fifo = |p: &Path| {
        assert!(std::process::Command::new("mkfifo")
            .arg(p)
            .status()
            .unwrap()
            .success());
    };
    fifo(&chunk);
    common::fails_with_all(
        &vellum_within_a_minute(&["info", s]),
        &["0/c/0/0/0", "a FIFO"],
    );
    let meta = root.join("0/zarr.json");
    std::fs::rename(&meta, d.join("zarr.json.kept")).unwrap();
    common::mkfifo(&meta);
    common::fails_with(&vellum_within_a_minute(&["info", s]), "a FIFO");
    std::fs::remove_file(&meta).unwrap();
    std::fs::rename(d.join("zarr.json.kept"), &meta).unwrap();
    // A link to nothing is not read as a missing chunk (the fill value) without a word.
    std::fs::remove_file(&chunk).unwrap();
    std::os::unix::fs::symlink(d.join("nowhere"), &chunk).unwrap();
    common::fails_with_all(
        &vellum_within_a_minute(&["info", s]),
        &["0/c/0/0/0", "link to nothing"],
    );
}

#[test]
fn scales_ranges_and_levels_that_do_not_hold_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scale_of = |level: usize| format!("/datasets/{level}/coordinateTransformations/0/scale");
    for (i, (scale, phrase)) in [
        ([-1.0, 1.0, 1.0], "expected voxel sizes"),
        ([1e308, 1.0, 1.0], "expected voxel sizes"),
        ([1e-308, 1.0, 1.0], "expected voxel sizes"),
        ([1.0, 1.0, 1e5], "times longer"),
    ]
    .into_iter()
    .enumerate()
    {
        let root = phantom_store(d, &format!("scale{i}.ome.zarr"));
        edit_json(&root.join("zarr.json"), |v| {
            *multiscale(v).pointer_mut(&scale_of(0)).unwrap() = serde_json::json!(scale);
        });
        common::fails_with_all(
            &common::vellum(&["info", root.to_str().unwrap()]),
            &["level 0's scale", phrase],
        );
    }
    // The multiscale's own transformations apply to every level.
    let root = phantom_store(d, "ms.ome.zarr");
    edit_json(&root.join("zarr.json"), |v| {
        multiscale(v)["coordinateTransformations"] =
            serde_json::json!([{"type": "scale", "scale": [0.5, 2.0, 3.0]}]);
    });
    let m = Multiscale::open(&root).unwrap();
    assert_eq!(m.levels[0].spacing, [3.0, 2.0, 0.5]);
    assert_eq!(m.levels[1].spacing, [6.0, 4.0, 1.0]);
    // Levels that are not what they say: level 0 listed again, an array at another scale.
    let root = phantom_store(d, "levels.ome.zarr");
    edit_json(&root.join("zarr.json"), |v| {
        multiscale(v)["datasets"][1]["path"] = "0".into();
    });
    common::fails_with(
        &common::vellum(&["info", root.to_str().unwrap()]),
        "level 0 twice",
    );
    edit_json(&root.join("zarr.json"), |v| {
        multiscale(v)["datasets"][1]["path"] = "1".into();
        *multiscale(v).pointer_mut(&scale_of(1)).unwrap() = serde_json::json!([3.0, 3.0, 3.0]);
    });
    common::fails_with(
        &common::vellum(&["info", root.to_str().unwrap()]),
        "same extent",
    );
    // A recorded range the store's own values contradict, or not finite: refused where the
    // bricked render would have drawn black (96³: its intensity alone, 1.7 MiB, exceeds the
    // budget, so the store is bricked).
    for (i, range) in [[0.0, 0.0], [-1e308, 1e308]].into_iter().enumerate() {
        let name = format!("range{i}.ome.zarr");
        let root = common::phantom_store(d, &name, "shepp-logan:96", 32);
        edit_json(&root.join("zarr.json"), |v| {
            v["attributes"]["vellum"]["range"] = serde_json::json!(range);
        });
        let png = d.join("r.png");
        let out = common::vellum(&[
            "render",
            root.to_str().unwrap(),
            "--renderer",
            "raycast",
            "--gpu-budget",
            "1",
            "--size",
            "32x32",
            "--out",
            png.to_str().unwrap(),
        ]);
        common::fails_with(&out, "recorded range");
        assert!(!png.exists());
    }
}

#[test]
fn a_written_store_has_a_sane_number_of_levels_and_chunks() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = |name: &str| d.join(name).to_string_lossy().into_owned();
    let o = out("o.ome.zarr");
    let p = "phantom:shepp-logan:32";
    common::fails_with(
        &common::vellum(&["convert", p, &o, "--levels", "99"]),
        "expected 1 to 6",
    );
    common::fails_with(
        &common::vellum(&["convert", p, &o, "--chunk", "1"]),
        "too small",
    );
    common::only(d, &[]);
    let ok = common::vellum(&["convert", p, &o, "--levels", "6"]);
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    let m = Multiscale::open(Path::new(&o)).unwrap();
    assert_eq!(m.levels.last().unwrap().dims, [1, 1, 1]);
    assert_eq!(m.levels.last().unwrap().spacing, [32.0; 3]);
}

/// SIGINT or SIGTERM at 20 moments of a store's writing: each time the command ends with 130 and
/// nothing (or, when it finished first, the whole store) is there, never a temporary folder.
#[test]
fn an_interrupted_store_write_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut interrupted = 0;
    for i in 0..20u64 {
        let store = d.join(format!("x{i}.ome.zarr"));
        let child = std::process::Command::new(env!("CARGO_BIN_EXE_vellum"))
            .args([
                "convert",
                "phantom:shepp-logan:160",
                store.to_str().unwrap(),
                "--chunk",
                "16",
            ])
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // Moments spread over the write (a few hundred milliseconds on two cores).
        let wait = 20 + (i * 7919 % 20) * 25;
        std::thread::sleep(std::time::Duration::from_millis(wait));
        let signal = if i % 2 == 0 { "-INT" } else { "-TERM" };
        let _ = std::process::Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status();
        let out = child.wait_with_output().unwrap();
        match out.status.code() {
            Some(130) => {
                interrupted += 1;
                assert!(!store.exists(), "{} left after a signal", store.display());
            }
            Some(0) => {
                Multiscale::open(&store).unwrap();
                std::fs::remove_dir_all(&store).unwrap();
            }
            // Killed by the signal's default action: it came before the handler was set, so
            // before anything was written.
            None => assert!(!store.exists()),
            other => panic!(
                "exit {other:?} after {signal} at {wait} ms: {}",
                String::from_utf8_lossy(&out.stderr)
            ),
        }
        common::only(d, &[]);
    }
    assert!(
        interrupted > 0,
        "no write was interrupted: the moments are too late"
    );
}

/// The issue's smaller items, each as a user meets it: a mistake on the command line is one
/// sentence and status 1; a small memory budget is said as it is; a file named `.zarr` is not
/// taken for an unknown format; a scene's unknown field is named as the scene's key.
#[test]
fn small_mistakes_are_one_clear_sentence() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let p = "phantom:shepp-logan:16";
    let png = d.join("x.png");
    let png = png.to_str().unwrap();
    for bad in [
        ["--gpu-budget", "abc"],
        ["--max-wait-ms", "1e30"],
        ["--slices", "x"],
    ] {
        let out = common::vellum(&["render", p, bad[0], bad[1], "--out", png]);
        assert_eq!(out.status.code(), Some(1), "{bad:?}");
        common::fails_with_all(&out, &[bad[0], "--help"]);
    }
    let dd = d.join("dd.ome.zarr");
    let out = common::vellum(&[
        "importance",
        p,
        "--radius",
        "2",
        "--memory-budget",
        "0.001",
        "--out",
        dd.to_str().unwrap(),
    ]);
    common::fails_with(&out, "a memory budget of 0.001 MiB");
    let file = d.join("plain.ome.zarr");
    std::fs::write(&file, b"not a folder").unwrap();
    common::fails_with(
        &common::vellum(&["info", file.to_str().unwrap()]),
        "expected an OME-Zarr store to be a folder",
    );
    let scene = d.join("s.json");
    std::fs::write(&scene, r#"{"version": 1, "radius": 3}"#).unwrap();
    let out = common::vellum(&["render", "--scene", scene.to_str().unwrap(), "--out", png]);
    common::fails_with(&out, "`radius`");
    // An occlusion TF whose radius the pass refuses is named, inside the scene that names it.
    let otf = d.join("o.json");
    std::fs::write(
        &otf,
        r#"{"radius": 0, "mapping": "ramp", "transfer": "grey"}"#,
    )
    .unwrap();
    let text = format!(
        r#"{{"version": 1, "input": {{"path": "{p}"}}, "classification": {{"occlusion": "{}"}}}}"#,
        otf.display()
    );
    std::fs::write(&scene, text).unwrap();
    let out = common::vellum(&["render", "--scene", scene.to_str().unwrap(), "--out", png]);
    common::fails_with_all(&out, &["o.json", "`radius` 0"]);
    // A store whose folder cannot take it is named, not its temporary (a file stands in for a
    // read-only folder, which root may still write into).
    let inside = file.join("x.ome.zarr");
    let out = common::vellum(&["convert", p, inside.to_str().unwrap()]);
    common::fails_with_all(&out, &["x.ome.zarr cannot be written", "plain.ome.zarr"]);
    assert!(
        !out.stderr.windows(8).any(|w| w == b".vellum."),
        "names its temporary"
    );
    common::only(d, &["plain.ome.zarr", "s.json", "o.json"]);
}

/// A (t, c, z, y, x) store of 3 time points and 2 channels of 24³ u16, one chunk per (t, c):
/// channel 0 at time t is a ball of radius 4 + 3t, channel 1 is a slab of its lower half.
fn time_series(root: &Path) {
    put(&root.join(".zgroup"), br#"{"zarr_format": 2}"#);
    let axes = r#"[{"name": "t", "type": "time"}, {"name": "c", "type": "channel"},
        {"name": "z", "type": "space"}, {"name": "y", "type": "space"}, {"name": "x", "type": "space"}]"#;
    let attrs = format!(
        r#"{{"multiscales": [{{"version": "0.4", "axes": {axes}, "datasets": [{{"path": "0",
            "coordinateTransformations": [{{"type": "scale", "scale": [1.0, 1.0, 1.0, 1.0, 1.0]}}]}}]}}]}}"#
    );
    put(&root.join(".zattrs"), attrs.as_bytes());
    let n = 24;
    put(
        &root.join("0/.zarray"),
        format!(
            r#"{{"zarr_format": 2, "shape": [3, 2, {n}, {n}, {n}], "chunks": [1, 1, {n}, {n}, {n}],
            "dtype": "<u2", "compressor": null, "fill_value": 0, "order": "C", "filters": null,
            "dimension_separator": "/"}}"#
        )
        .as_bytes(),
    );
    for t in 0..3 {
        for c in 0..2 {
            let r = 4.0 + 3.0 * t as f64;
            let mut bytes = Vec::new();
            for i in 0..n * n * n {
                let (x, y, z) = (i % n, (i / n) % n, i / (n * n));
                let d = |v: usize| v as f64 - 11.5;
                let inside = match c {
                    0 => d(x).powi(2) + d(y).powi(2) + d(z).powi(2) <= r * r,
                    _ => z < n / 2,
                };
                bytes.extend(u16::from(inside).to_le_bytes());
            }
            put(&root.join(format!("0/{t}/{c}/0/0/0")), &bytes);
        }
    }
}

/// A (t, z, y, x) store of 3 time points of 24³ u16: a slab (x < 8) of 300 at every time
/// point, and a cube in the middle of 1000 (t + 1), which makes each time point's largest value
/// different. With `channels` > 1, (t, c, z, y, x) with that volume in every channel.
fn brightening_series(root: &Path, channels: usize) {
    put(&root.join(".zgroup"), br#"{"zarr_format": 2}"#);
    let (axes, scale, c) = match channels {
        1 => (
            r#"["t", "z", "y", "x"]"#,
            "1.0, 1.0, 1.0, 1.0",
            String::new(),
        ),
        k => (
            r#"["t", "c", "z", "y", "x"]"#,
            "1.0, 1.0, 1.0, 1.0, 1.0",
            format!("{k}, "),
        ),
    };
    let attrs = format!(
        r#"{{"multiscales": [{{"version": "0.4", "axes": {axes}, "datasets": [{{"path": "0",
            "coordinateTransformations": [{{"type": "scale", "scale": [{scale}]}}]}}]}}]}}"#
    );
    put(&root.join(".zattrs"), attrs.as_bytes());
    let n = 24;
    let ones = "1, ".repeat(usize::from(channels > 1));
    put(
        &root.join("0/.zarray"),
        format!(
            r#"{{"zarr_format": 2, "shape": [3, {c}{n}, {n}, {n}], "chunks": [1, {ones}{n}, {n}, {n}],
            "dtype": "<u2", "compressor": null, "fill_value": 0, "order": "C", "filters": null,
            "dimension_separator": "/"}}"#
        )
        .as_bytes(),
    );
    for t in 0..3u16 {
        let mut bytes = Vec::new();
        for i in 0..n * n * n {
            let (x, y, z) = (i % n, (i / n) % n, i / (n * n));
            let inner = |v: usize| (8..16).contains(&v);
            let v: u16 = match x {
                _ if x < 8 && (4..20).contains(&y) && (4..20).contains(&z) => 300,
                _ if (12..20).contains(&x) && inner(y) && inner(z) => 1000 * (t + 1),
                _ => 0,
            };
            bytes.extend(v.to_le_bytes());
        }
        match channels {
            1 => put(&root.join(format!("0/{t}/0/0/0")), &bytes),
            k => (0..k).for_each(|c| put(&root.join(format!("0/{t}/{c}/0/0/0")), &bytes)),
        }
    }
}

/// The frames of a series share one intensity scale and one `auto` transfer function, time
/// point 0's: the slab, the same at every time point, draws the same pixels in every frame,
/// though each time point's largest value differs; and `--time 2` alone draws frame 2.
#[test]
fn the_frames_of_a_series_share_one_scale() {
    series_shares_one_scale(1, &["--renderer", "raycast"]);
}

/// The same for two channels mixed by `add`: each channel keeps time point 0's range and
/// transfer function through the series.
#[test]
fn the_channels_of_a_series_share_one_scale() {
    series_shares_one_scale(2, &["--channels", "0,1", "--mix", "add"]);
}

/// Renders every time point of a brightening series of `channels` with `flags`, and `--time 2`
/// alone: the slab's pixels are the same in every frame, and `--time 2` draws frame 2.
fn series_shares_one_scale(channels: usize, flags: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("series.ome.zarr");
    brightening_series(&store, channels);
    let (s, out) = (store.to_str().unwrap(), dir.path().join("frames"));
    let args = [&["render", s, "--size", "64x64"], flags].concat();
    let o = out.to_str().unwrap();
    let all = common::vellum(&[&args[..], &["--out", o, "--time", "all"]].concat());
    assert!(
        all.status.success(),
        "{}",
        String::from_utf8_lossy(&all.stderr)
    );
    let frame = |p: &Path| image::open(p).unwrap().to_rgb8();
    let frames: Vec<_> = (0..3)
        .map(|t| frame(&out.join(format!("t{t:04}.png"))))
        .collect();
    // The slab's side of the image (x to the right; the cube starts at column 29).
    let left = |im: &image::RgbImage| -> Vec<[u8; 3]> {
        im.enumerate_pixels()
            .filter(|(x, ..)| *x < 26)
            .map(|(.., p)| p.0)
            .collect()
    };
    let lit = left(&frames[0])
        .iter()
        .filter(|p| p.iter().any(|&v| v > 20))
        .count();
    assert!(lit > 100, "the slab shows ({lit} lit pixels)");
    for t in 1..3 {
        assert_eq!(left(&frames[t]), left(&frames[0]), "frame {t}'s slab");
    }
    let one = dir.path().join("two.png");
    let o = one.to_str().unwrap();
    let single = common::vellum(&[&args[..], &["--out", o, "--time", "2"]].concat());
    assert!(single.status.success());
    assert_eq!(frame(&one), frames[2], "--time 2 draws frame 2");
}

#[test]
fn a_time_point_and_a_channel_of_a_store_are_picked() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("series.ome.zarr");
    time_series(&store);
    let s = store.to_str().unwrap();
    // Described whole; read one (time, channel) at a time.
    let info = common::ok_json(&common::vellum(&["info", s, "--json"]));
    assert_eq!(
        (info["times"].as_u64(), info["channels"].as_u64()),
        (Some(3), Some(2))
    );
    let ones = |t: &str, c: &str| {
        let j = common::ok_json(&common::vellum(&[
            "info",
            s,
            "--time",
            t,
            "--channel",
            c,
            "--json",
        ]));
        j["statistics"]["mean"].as_f64().unwrap() * 24f64.powi(3)
    };
    let ball = |r: f64| 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
    for t in 0..3 {
        let count = ones(&t.to_string(), "0");
        let want = ball(4.0 + 3.0 * t as f64);
        assert!(
            (count / want - 1.0).abs() < 0.2,
            "t {t}: {count} voxels, ball {want:.0}"
        );
    }
    assert_eq!(
        ones("1", "1"),
        24.0 * 24.0 * 12.0,
        "channel 1 is the lower half"
    );
    // Rendered: each time point is its own frame, and the ball grows.
    let out = dir.path().join("frames");
    let o = out.to_str().unwrap();
    let rendered = common::vellum(&[
        "render",
        s,
        "--time",
        "all",
        "--channels",
        "0",
        "--size",
        "64x64",
        "--out",
        o,
    ]);
    assert!(
        rendered.status.success(),
        "{}",
        String::from_utf8_lossy(&rendered.stderr)
    );
    let lit: Vec<usize> = (0..3)
        .map(|t| {
            let png = out.join(format!("t{t:04}.png"));
            let rgb = image::open(&png).unwrap().to_rgb8();
            rgb.pixels().filter(|p| p.0.iter().any(|&c| c > 30)).count()
        })
        .collect();
    assert!(
        lit[0] > 0 && lit[0] < lit[1] && lit[1] < lit[2],
        "lit pixels {lit:?}"
    );
    common::only(&out, &["t0000.png", "t0001.png", "t0002.png"]);
    // One time point by --time equals its frame in the series.
    let one = dir.path().join("one.png");
    let single = common::vellum(&[
        "render",
        s,
        "--time",
        "1",
        "--channels",
        "0",
        "--size",
        "64x64",
        "--out",
        one.to_str().unwrap(),
    ]);
    assert!(single.status.success());
    assert_eq!(
        std::fs::read(&one).unwrap(),
        std::fs::read(out.join("t0001.png")).unwrap()
    );
    // What is not there, or not picked, is one sentence each, and nothing is written.
    let bad = dir.path().join("bad.png");
    let b = bad.to_str().unwrap();
    let refused = [
        (
            vec!["--channels", "0"],
            "holds 3 time points; pick one with --time T (0 to 2)",
        ),
        (
            vec!["--time", "3", "--channels", "0"],
            "time point 3 does not exist (--time T)",
        ),
        (
            vec!["--time", "0"],
            "holds 2 channels; pick one with --channels C",
        ),
        (
            vec!["--time", "0", "--channels", "5"],
            "channel 5 does not exist",
        ),
        (
            vec!["--time", "0", "--channels", "0,1,0,1,0,1,0,1,0"],
            "names 9 channels; vellum mixes at most 8 in one ray",
        ),
    ];
    for (flags, phrase) in refused {
        let mut args = vec!["render", s, "--out", b];
        args.extend(flags);
        common::fails_with(&common::vellum(&args), phrase);
        assert!(!bad.exists());
    }
    let phantom = common::vellum(&["render", "phantom:sphere:16", "--time", "1", "--out", b]);
    common::fails_with(&phantom, "is a phantom");
}

/// `convert --add-channel`: the chest CT and a volume on its grid become the two channels of one
/// store, each read back voxel for voxel; the CT's flipped axes come back from vellum's own
/// attributes (NGFF's scale and translation cannot hold them), at level 0 and, turned by them,
/// at level 1. A volume on another grid, or more channels than a ray mixes, is one sentence and
/// leaves no store.
#[test]
fn added_channels_and_the_axes_directions_survive_a_store() {
    let dir = tempfile::tempdir().unwrap();
    let ct_path = "data/ct_chest/ct_chest.nhdr";
    let ct = vellum::input::load(ct_path, None).unwrap();
    let second: Vec<u8> = (0..ct.len())
        .map(|i| (ct.data.get_f64(i) as u8) / 2 + 1)
        .collect();
    let second = Volume::new(ct.dims, ct.spacing, VoxelData::U8(second))
        .unwrap()
        .with_geometry(ct.geometry)
        .unwrap();
    let half = dir.path().join("half.nrrd");
    vellum::volume::io::write(&half, &second).unwrap();
    let store = dir.path().join("two.ome.zarr");
    let o = common::vellum(&[
        "convert",
        ct_path,
        store.to_str().unwrap(),
        "--add-channel",
        half.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for (c, want) in [(0, &ct), (1, &second)] {
        let m = Multiscale::open_channel(&store, c).unwrap();
        assert_eq!(m.channels, 2);
        let back = m.read_level(0).unwrap();
        assert_eq!(back.data, want.data, "channel {c}");
        assert_eq!(back.geometry, ct.geometry, "channel {c}'s placement");
        // Level 1's first voxel sits half a level-1 voxel less half a level-0 voxel along
        // each index axis from level 0's, in the directions of the axes.
        let g1 = m.geometry_of(1);
        for r in 0..3 {
            let want: f64 = ct.geometry.origin[r]
                + (0..3)
                    .map(|a| ct.geometry.direction[r][a] * 0.5 * ct.spacing[a])
                    .sum::<f64>();
            assert!(
                (g1.origin[r] - want).abs() < 1e-9,
                "level 1 origin {:?}",
                g1.origin
            );
        }
    }
    let other = dir.path().join("other.nrrd");
    vellum::volume::io::write(&other, &sample(40)).unwrap();
    let refused = |args: &[&str], want: &str| {
        let out = dir.path().join("refused.ome.zarr");
        let mut all = vec!["convert", ct_path, out.to_str().unwrap()];
        all.extend_from_slice(args);
        let o = common::vellum(&all);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(want), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(!out.exists(), "{args:?} left a store");
    };
    refused(
        &["--add-channel", other.to_str().unwrap()],
        "expected a volume on the input's grid",
    );
    let h = half.to_str().unwrap();
    let eight: Vec<&str> = (0..8).flat_map(|_| ["--add-channel", h]).collect();
    refused(&eight, "at most 8 in one ray");
}
