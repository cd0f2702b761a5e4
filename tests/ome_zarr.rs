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
        e.contains("2 channels") && e.contains("expected one"),
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
    // Two time points.
    let root = dir.path().join("times.zarr");
    v2_store(&root, [2, 2, 2], 2, TCZYX, [2, 1]);
    let e = Multiscale::open(&root).err().expect("refused").to_string();
    assert!(e.contains("2 time points"), "{e}");
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
        e.contains("expected (z, y, x), (c, z, y, x) or (t, c, z, y, x)"),
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
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/support/write_ome_zarr.py"
    );
    for version in ["0.4", "0.5"] {
        let store = dir.path().join(format!("python-{version}.zarr"));
        let out = std::process::Command::new("python3")
            .arg(script)
            .arg(&store)
            .arg(version)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
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
