//! Readers against the real files in `../shared/data` (checksums and statistics from each
//! dataset's SOURCE.txt), bad input that must produce one clear sentence, the NRRD writer, and the
//! phantoms.

use std::collections::HashMap;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use flate2::write::GzEncoder;
use vellum::volume::io::{load, write_nrrd, RawSpec};
use vellum::volume::phantom::{self, NESTED_CORE, NESTED_LOW, NESTED_MEDIUM};
use vellum::volume::stats::stats;
use vellum::volume::{Volume, VoxelData, VoxelType};

/// `../shared/data` beside the checkout. Missing data fails under CI and skips elsewhere.
fn shared_data() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    if dir.is_dir() {
        return Some(dir);
    }
    if std::env::var("CI").as_deref() == Ok("true") {
        panic!("../shared/data is missing; CI requires it");
    }
    eprintln!("note: {} is missing; skipping this test", dir.display());
    None
}

/// `key: value` lines of a SOURCE.txt.
fn source_fields(path: &Path) -> HashMap<String, String> {
    fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
        .collect()
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut gz = GzEncoder::new(Vec::new(), flate2::Compression::default());
    gz.write_all(bytes).unwrap();
    gz.finish().unwrap()
}

/// The error text of loading `path`, which must fail.
fn load_err(path: &Path) -> String {
    match load(path, None) {
        Ok(v) => panic!(
            "{} loaded as {:?} but should have failed",
            path.display(),
            v.dims
        ),
        Err(e) => e.to_string(),
    }
}

fn assert_contains(text: &str, phrase: &str) {
    assert!(
        text.contains(phrase),
        "error '{text}' does not contain '{phrase}'"
    );
}

#[test]
fn every_shared_volume_matches_its_source() {
    let Some(data) = shared_data() else { return };
    let mut checked = 0;
    let mut dirs: Vec<_> = fs::read_dir(data.join("volumes"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    dirs.sort();
    for dir in dirs {
        let src = source_fields(&dir.join("SOURCE.txt"));
        let name = dir.file_name().unwrap().to_string_lossy().into_owned();
        let v =
            load(&dir.join(format!("{name}.nhdr")), None).unwrap_or_else(|e| panic!("{name}: {e}"));
        let dims: Vec<usize> = src["dims_xyz"]
            .trim_matches(['[', ']'])
            .split(',')
            .map(|s| s.trim().parse().unwrap())
            .collect();
        assert_eq!(v.dims.to_vec(), dims, "{name} dims");
        assert_eq!(v.sha256_hex(), src["sha256_raw"], "{name} sha256");
        let s = stats(&v, 16);
        let num = |k: &str| src[k].parse::<f64>().unwrap();
        assert_eq!(s.min, num("min"), "{name} min");
        assert_eq!(s.max, num("max"), "{name} max");
        let mean = num("mean");
        assert!(
            (s.mean - mean).abs() <= (0.01 * mean.abs()).max(0.001),
            "{name} mean {} vs {mean}",
            s.mean
        );
        assert_eq!(s.histogram.iter().sum::<u64>(), v.len() as u64);
        checked += 1;
    }
    assert!(checked >= 25, "only {checked} volumes checked");
}

#[test]
fn skull_mask_is_binary_and_aligned_with_head() {
    let Some(data) = shared_data() else { return };
    let dir = data.join("volumes/mri_head_seg3d");
    let mask = load(&dir.join("mri_head_seg3d_skull_mask.nhdr"), None).unwrap();
    assert_eq!(mask.dims, [160, 232, 160]);
    let VoxelData::U8(m) = &mask.data else {
        panic!("mask is {:?}", mask.voxel_type())
    };
    assert!(m.iter().all(|&x| x <= 1));
    assert!(m.contains(&1) && m.contains(&0));

    // The mask as its segmentation tool saved it runs along x the other way.
    let original = load(&data.join("formats/nrrd/seg3d_skull_mask.nrrd"), None).unwrap();
    assert_eq!(original.dims, mask.dims);
    let [nx, ny, nz] = mask.dims;
    let flipped = (0..nz)
        .flat_map(|z| (0..ny).flat_map(move |y| (0..nx).map(move |x| (x, y, z))))
        .all(|(x, y, z)| {
            original.data.get_f64(original.index(nx - 1 - x, y, z))
                == mask.data.get_f64(mask.index(x, y, z))
        });
    assert!(
        flipped,
        "formats/nrrd/seg3d_skull_mask.nrrd mirrored in x should equal the aligned mask"
    );
}

#[test]
fn format_files_load_with_documented_dims() {
    let Some(data) = shared_data() else { return };
    let f = data.join("formats");
    let cases: [(&str, [usize; 3]); 10] = [
        ("nifti/stroke_t1.nii.gz", [124, 160, 140]),
        ("nifti/mr_gd.nii.gz", [176, 188, 144]),
        ("nifti/ct_avm.nii.gz", [256, 242, 154]),
        ("nifti/seg3d_mr_head.nii.gz", [160, 232, 160]),
        ("nrrd/seg3d_skull_mask.nrrd", [160, 232, 160]),
        ("nrrd/tooth.nrrd", [103, 94, 161]),
        ("metaimage/HeadMRVolume.mhd", [48, 62, 42]),
        ("metaimage/frogtissue.mhd", [500, 470, 136]),
        ("dicom/seg3d_mr_640", [640, 640, 44]),
        ("dicom/vs_seg001_t1", [512, 512, 120]),
    ];
    for (rel, dims) in cases {
        let v = load(&f.join(rel), None).unwrap_or_else(|e| panic!("{rel}: {e}"));
        assert_eq!(v.dims, dims, "{rel}");
        let s = stats(&v, 0);
        eprintln!(
            "{rel}: {:?} {:?} spacing {:?} min {} max {} mean {:.3}",
            v.dims,
            v.voxel_type(),
            v.spacing,
            s.min,
            s.max,
            s.mean
        );
    }
}

#[test]
fn nifti_copies_match_the_volumes() {
    let Some(data) = shared_data() else { return };
    let (f, vol) = (data.join("formats/nifti"), data.join("volumes"));

    // stroke_t1 is uint8 without scaling: the very same voxels.
    let nii = load(&f.join("stroke_t1.nii.gz"), None).unwrap();
    let nhdr = load(&vol.join("mri_stroke_t1/mri_stroke_t1.nhdr"), None).unwrap();
    assert_eq!(nii.voxel_type(), VoxelType::U8);
    assert_eq!(nii.sha256_hex(), nhdr.sha256_hex());
    assert_eq!(nii.spacing, nhdr.spacing);

    // seg3d_mr_head and mr_gd store the same uint8 voxels as the volumes' copies, but with
    // scl_slope 512/255 and 6.48235 (intercept 0), so the reader returns f32 = stored * slope.
    for (nii, nhdr, slope) in [
        (
            "seg3d_mr_head.nii.gz",
            "mri_head_seg3d/mri_head_seg3d.nhdr",
            2.007843255996704,
        ),
        (
            "mr_gd.nii.gz",
            "mri_gd_brain/mri_gd_brain.nhdr",
            6.4823527336120605,
        ),
    ] {
        let nii = load(&f.join(nii), None).unwrap();
        let nhdr = load(&vol.join(nhdr), None).unwrap();
        assert_eq!((nii.voxel_type(), nii.dims), (VoxelType::F32, nhdr.dims));
        let expected: Vec<f32> = nhdr
            .data
            .to_f32()
            .iter()
            .map(|&x| (x as f64 * slope) as f32)
            .collect();
        assert!(
            nii.data.to_f32() == expected,
            "{:?} is not the volume copy times {slope}",
            nii.dims
        );
        assert_eq!(nii.spacing, nhdr.spacing.map(|s| s as f32 as f64));
    }
}

#[test]
fn metaimage_and_nrrd_format_details() {
    let Some(data) = shared_data() else { return };
    let f = data.join("formats");
    let head = load(&f.join("metaimage/HeadMRVolume.mhd"), None).unwrap();
    assert_eq!(head.spacing, [4.0; 3]);
    assert_eq!(head.voxel_type(), VoxelType::U8);
    let frog = load(&f.join("metaimage/frogtissue.mhd"), None).unwrap();
    assert_eq!(frog.spacing, [1.0, 1.0, 1.5]);
    let tooth = load(&f.join("nrrd/tooth.nrrd"), None).unwrap();
    assert_eq!(
        (tooth.voxel_type(), tooth.spacing),
        (VoxelType::U8, [1.0; 3])
    );
    let mask = load(&f.join("nrrd/seg3d_skull_mask.nrrd"), None).unwrap();
    assert!((mask.spacing[1] - 0.898437).abs() < 1e-9 && mask.spacing[0] == 1.0);
}

#[test]
fn dicom_series_are_sorted_and_spaced() {
    let Some(data) = shared_data() else { return };
    for series in ["seg3d_mr_640", "vs_seg001_t1"] {
        let v = load(&data.join("formats/dicom").join(series), None).unwrap();
        assert!(
            v.spacing.iter().all(|s| s.is_finite() && *s > 0.0),
            "{series} spacing {:?}",
            v.spacing
        );
        // Sorted slices change smoothly: neighbouring slices differ less than slices far apart.
        let slice =
            |z: usize| (0..v.dims[0] * v.dims[1]).map(move |i| i + z * v.dims[0] * v.dims[1]);
        let diff = |a: usize, b: usize| {
            slice(a)
                .zip(slice(b))
                .map(|(i, j)| (v.data.get_f64(i) - v.data.get_f64(j)).abs())
                .sum::<f64>()
        };
        let mid = v.dims[2] / 2;
        assert!(
            diff(mid, mid + 1) < diff(mid, mid + v.dims[2] / 4),
            "{series} slices look unsorted"
        );
    }
}

// ---- bad input ----

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let path = dir.join(name);
    fs::write(&path, bytes).unwrap();
    path
}

fn nrrd_header(ty: &str, sizes: &str, encoding: &str) -> String {
    format!("NRRD0004\ntype: {ty}\ndimension: 3\nsizes: {sizes}\nendian: little\nencoding: {encoding}\n\n")
}

#[test]
fn missing_file_says_it_does_not_exist() {
    let dir = tempfile::tempdir().unwrap();
    assert_contains(&load_err(&dir.path().join("nope.nrrd")), "does not exist");
}

#[test]
fn unknown_extension_lists_formats() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "volume.xyz", b"hello world, not a volume");
    assert_contains(&load_err(&path), "unknown format; expected .nrrd");
}

#[test]
fn sniffing_finds_nrrd_without_extension() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = nrrd_header("uint8", "2 2 2", "raw").into_bytes();
    bytes.extend(0..8u8);
    let v = load(&write(dir.path(), "noext", &bytes), None).unwrap();
    assert_eq!(v.data, VoxelData::U8((0..8).collect()));
}

#[test]
fn nrrd_size_mismatch_raw_and_gzip() {
    let dir = tempfile::tempdir().unwrap();
    let mut raw = nrrd_header("uint16", "4 4 4", "raw").into_bytes();
    raw.extend([0u8; 100]);
    assert_contains(
        &load_err(&write(dir.path(), "short.nrrd", &raw)),
        "data holds 100 bytes but the header needs 128",
    );
    let mut raw = nrrd_header("uint16", "4 4 4", "raw").into_bytes();
    raw.extend([0u8; 130]);
    assert_contains(
        &load_err(&write(dir.path(), "long.nrrd", &raw)),
        "data holds 130 bytes but the header needs 128",
    );
    let mut gz = nrrd_header("uint16", "4 4 4", "gzip").into_bytes();
    gz.extend(gzip(&[0u8; 100]));
    assert_contains(
        &load_err(&write(dir.path(), "short_gz.nrrd", &gz)),
        "gzip stream holds 100 bytes but the header needs 128",
    );
}

#[test]
fn truncated_gzip_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let payload: Vec<u8> = (0..4096u32).map(|i| (i * 7 % 251) as u8).collect();
    let compressed = gzip(&payload);
    let mut bytes = nrrd_header("uint8", "16 16 16", "gzip").into_bytes();
    bytes.extend(&compressed[..compressed.len() / 2]);
    assert_contains(
        &load_err(&write(dir.path(), "trunc.nrrd", &bytes)),
        "gzip stream is truncated",
    );

    // A reserved deflate block type right after the 10-byte gzip header is corrupt, not truncated.
    let mut corrupt = compressed.clone();
    corrupt[10] = 0xff;
    let mut bytes = nrrd_header("uint8", "16 16 16", "gzip").into_bytes();
    bytes.extend(&corrupt);
    assert_contains(
        &load_err(&write(dir.path(), "corrupt.nrrd", &bytes)),
        "gzip stream is corrupt",
    );

    // The same for a detached header, whose data file is the truncated part.
    write(
        dir.path(),
        "trunc.raw.gz",
        &compressed[..compressed.len() - 5],
    );
    let header = "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 16 16 16\nencoding: gzip\ndata file: trunc.raw.gz\n";
    assert_contains(
        &load_err(&write(dir.path(), "trunc.nhdr", header.as_bytes())),
        "gzip stream is truncated",
    );

    // And for a NIfTI whose gzip stream ends early.
    let nii = gzip(&nifti(2, [4, 4, 4], &[0u8; 64]));
    assert_contains(
        &load_err(&write(dir.path(), "trunc.nii.gz", &nii[..nii.len() - 12])),
        "gzip stream is truncated",
    );
}

#[test]
fn unsupported_types_name_the_type() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = nrrd_header("block", "2 2 2", "raw").into_bytes();
    bytes.extend([0u8; 8]);
    let e = load_err(&write(dir.path(), "block.nrrd", &bytes));
    assert_contains(&e, "type 'block' is not supported");
    assert_contains(&e, "uint16");
    let e = load_err(&write(
        dir.path(),
        "rgb.nii",
        &nifti(128, [2, 2, 2], &[0u8; 24]),
    ));
    assert_contains(&e, "datatype 128 (RGB24) is not supported");
    let e = load_err(&write(
        dir.path(),
        "enc.nrrd",
        nrrd_header("uint8", "2 2 2", "bzip2").as_bytes(),
    ));
    assert_contains(&e, "encoding 'bzip2' is not supported");
    let mhd = "NDims = 3\nDimSize = 2 2 2\nElementType = MET_LONG_LONG\nElementDataFile = LOCAL\n";
    assert_contains(
        &load_err(&write(dir.path(), "ll.mha", mhd.as_bytes())),
        "ElementType MET_LONG_LONG is not supported",
    );
}

#[test]
fn zero_and_absurd_dims_fail_before_reading() {
    let dir = tempfile::tempdir().unwrap();
    let e = load_err(&write(
        dir.path(),
        "zero.nrrd",
        nrrd_header("uint8", "4 0 4", "raw").as_bytes(),
    ));
    assert_contains(&e, "contain a zero");
    let e = load_err(&write(
        dir.path(),
        "huge.nrrd",
        nrrd_header("float", "100000 100000 100000", "raw").as_bytes(),
    ));
    assert_contains(&e, "voxels; expected at most");
    // Within the voxel limit but far beyond the data: fails on the byte count without allocating it all.
    let e = load_err(&write(
        dir.path(),
        "big.nrrd",
        nrrd_header("float", "2048 2048 2048", "raw").as_bytes(),
    ));
    assert_contains(&e, "data holds 0 bytes but the header needs 34359738368");
    let e = load_err(&write(
        dir.path(),
        "big_gz.nrrd",
        nrrd_header("float", "2048 2048 2048", "gzip").as_bytes(),
    ));
    assert_contains(&e, "gzip stream is truncated");
    let e = load_err(&write(dir.path(), "huge.nii", &nifti(2, [0, 4, 4], &[])));
    assert_contains(&e, "contain a zero");
}

#[test]
fn nan_voxels_are_counted() {
    let dir = tempfile::tempdir().unwrap();
    let values = [
        1.0f32,
        f32::NAN,
        2.0,
        f32::INFINITY,
        0.0,
        0.5,
        3.0,
        f32::NAN,
    ];
    let mut bytes = nrrd_header("float", "2 2 2", "raw").into_bytes();
    bytes.extend(values.iter().flat_map(|v| v.to_le_bytes()));
    let e = load_err(&write(dir.path(), "nan.nrrd", &bytes));
    assert_contains(&e, "has 3 NaN or infinite voxels");
}

#[test]
fn raw_reader_checks_file_size() {
    let dir = tempfile::tempdir().unwrap();
    let spec = RawSpec {
        dims: [4, 4, 4],
        voxel_type: VoxelType::I16,
        big_endian: true,
        offset: 16,
        spacing: [1.0, 2.0, 3.0],
    };
    let values: Vec<i16> = (0..64).map(|i| i * 100 - 3000).collect();
    let mut bytes = vec![0xAB; 16];
    bytes.extend(values.iter().flat_map(|v| v.to_be_bytes()));
    let v = load(&write(dir.path(), "ok.raw", &bytes), Some(&spec)).unwrap();
    assert_eq!(
        (v.data.clone(), v.spacing),
        (VoxelData::I16(values.clone()), [1.0, 2.0, 3.0])
    );
    let v = load(&write(dir.path(), "ok.raw.gz", &gzip(&bytes)), Some(&spec)).unwrap();
    assert_eq!(v.data, VoxelData::I16(values));

    let e = load(&write(dir.path(), "short.raw", &bytes[..100]), Some(&spec))
        .unwrap_err()
        .to_string();
    assert_contains(
        &e,
        "file holds 100 bytes but 4x4x4 voxels of i16 after an offset of 16 need exactly 144",
    );
    let e = load(
        &write(
            dir.path(),
            "long.raw.gz",
            &gzip(&[bytes.as_slice(), &[0]].concat()),
        ),
        Some(&spec),
    )
    .unwrap_err()
    .to_string();
    assert_contains(&e, "gzip stream holds 145 bytes but the header needs 144");
}

#[test]
fn nifti_scaling_endianness_and_dims() {
    let dir = tempfile::tempdir().unwrap();
    // Big-endian int16 with slope 2 and intercept -1: read as f32.
    let values: Vec<i16> = (0..24).map(|i| i - 12).collect();
    let payload: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
    let mut h = nifti(4, [2, 3, 4], &payload);
    be_header(&mut h);
    h[112..116].copy_from_slice(&2f32.to_be_bytes());
    h[116..120].copy_from_slice(&(-1f32).to_be_bytes());
    let v = load(&write(dir.path(), "be.nii", &h), None).unwrap();
    assert_eq!(
        v.data,
        VoxelData::F32(values.iter().map(|&x| x as f32 * 2.0 - 1.0).collect())
    );
    assert_eq!(v.spacing, [1.5, 1.0, 2.5]);

    // Four dims with dim[4] = 1 is a 3D volume; dim[4] = 3 is not.
    let mut h = nifti(512, [2, 2, 2], &[1u8; 16]);
    h[40..42].copy_from_slice(&4i16.to_le_bytes());
    h[48..50].copy_from_slice(&1i16.to_le_bytes());
    assert_eq!(
        load(&write(dir.path(), "d4.nii", &h), None).unwrap().data,
        VoxelData::U16(vec![257; 8])
    );
    h[48..50].copy_from_slice(&3i16.to_le_bytes());
    assert_contains(&load_err(&write(dir.path(), "d4b.nii", &h)), "dim[4] is 3");

    let mut h = nifti(2, [2, 2, 2], &[0u8; 8]);
    h[344..348].copy_from_slice(b"ni1\0");
    assert_contains(
        &load_err(&write(dir.path(), "pair.hdr", &h)),
        ".hdr/.img pair",
    );
    let mut h = nifti(2, [2, 2, 2], &[0u8; 8]);
    h[0..4].copy_from_slice(&540i32.to_le_bytes());
    assert_contains(&load_err(&write(dir.path(), "two.nii", &h)), "NIfTI-2");
}

#[test]
fn metaimage_local_and_compressed() {
    let dir = tempfile::tempdir().unwrap();
    let values: Vec<u16> = (0..8).map(|i| i * 1000).collect();
    let be: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
    let mut mha = b"ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementSpacing = 0.5 0.5 2\nElementType = MET_USHORT\nElementByteOrderMSB = True\nElementDataFile = LOCAL\n".to_vec();
    mha.extend(&be);
    let v = load(&write(dir.path(), "a.mha", &mha), None).unwrap();
    assert_eq!(
        (v.data, v.spacing),
        (VoxelData::U16(values.clone()), [0.5, 0.5, 2.0])
    );

    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    z.write_all(&be).unwrap();
    let z = z.finish().unwrap();
    write(dir.path(), "b.zraw", &z[..z.len() - 3]);
    let mhd = "NDims = 3\nDimSize = 2 2 2\nElementType = MET_USHORT\nBinaryDataByteOrderMSB = True\nCompressedData = True\nElementDataFile = b.zraw\n";
    assert_contains(
        &load_err(&write(dir.path(), "b.mhd", mhd.as_bytes())),
        "zlib stream is truncated",
    );
    write(dir.path(), "b.zraw", &z);
    assert_eq!(
        load(&dir.path().join("b.mhd"), None).unwrap().data,
        VoxelData::U16(values)
    );
}

#[test]
fn dicom_folder_without_images_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "notes.txt", b"not dicom");
    assert_contains(&load_err(dir.path()), "holds no DICOM images");
    write(dir.path(), "broken.dcm", b"not dicom either");
    assert_contains(&load_err(dir.path()), "could not be parsed as DICOM");
}

/// A minimal little-endian NIfTI-1 file: datatype, dims, spacing (1.5, 1, 2.5), vox_offset 352.
fn nifti(datatype: i16, dims: [i16; 3], payload: &[u8]) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    let dim = [3, dims[0], dims[1], dims[2], 1, 1, 1, 1];
    for (i, d) in dim.iter().enumerate() {
        h[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
    }
    h[70..72].copy_from_slice(&datatype.to_le_bytes());
    for (i, p) in [1.0f32, 1.5, 1.0, 2.5].iter().enumerate() {
        h[76 + 4 * i..80 + 4 * i].copy_from_slice(&p.to_le_bytes());
    }
    h[108..112].copy_from_slice(&352f32.to_le_bytes());
    h[344..348].copy_from_slice(b"n+1\0");
    h.extend(payload);
    h
}

/// Byte-swaps the numeric header fields [`nifti`] sets, making a big-endian header.
fn be_header(h: &mut [u8]) {
    for (start, size, count) in [(0, 4, 1), (40, 2, 8), (70, 2, 1), (76, 4, 4), (108, 4, 1)] {
        for i in 0..count {
            h[start + i * size..start + (i + 1) * size].reverse();
        }
    }
}

// ---- writer ----

#[test]
fn nrrd_round_trip_every_type() {
    let dir = tempfile::tempdir().unwrap();
    let dims = [5, 3, 2];
    let spacing = [0.1, 0.898437, 3.0];
    let datas = [
        VoxelData::U8((0..30).collect()),
        VoxelData::U16((0..30).map(|i| i * 2000).collect()),
        VoxelData::I16((0..30).map(|i| i * 1000 - 15000).collect()),
        VoxelData::F32((0..30).map(|i| i as f32 * 0.37 - 4.0).collect()),
    ];
    for data in datas {
        let v = Volume::new(dims, spacing, data).unwrap();
        let path = dir.path().join(format!("{}.nrrd", v.voxel_type().name()));
        write_nrrd(&path, &v).unwrap();
        assert_eq!(load(&path, None).unwrap(), v);
    }
    // Only the written files remain: no temporary files left behind.
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 4);
}

#[test]
fn failed_write_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("missing/sub/out.nrrd");
    let v = Volume::new([2, 2, 2], [1.0; 3], VoxelData::U8(vec![0; 8])).unwrap();
    let e = write_nrrd(&path, &v).unwrap_err().to_string();
    assert_contains(&e, "out.nrrd");
    assert!(!path.exists());
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
}

// ---- phantoms ----

#[test]
fn phantom_specs_parse() {
    assert!(phantom::parse_spec("brain.nrrd").is_none());
    assert_eq!(
        phantom::parse_spec("phantom:nested:8")
            .unwrap()
            .unwrap()
            .dims,
        [8; 3]
    );
    assert_eq!(
        phantom::parse_spec("phantom:shepp-logan")
            .unwrap()
            .unwrap()
            .dims,
        [128; 3]
    );
    let e = phantom::parse_spec("phantom:nested:0")
        .unwrap()
        .unwrap_err()
        .to_string();
    assert_contains(&e, "from 1 to 1024");
    let e = phantom::parse_spec("phantom:nested:2000")
        .unwrap()
        .unwrap_err()
        .to_string();
    assert_contains(&e, "from 1 to 1024");
    let e = phantom::parse_spec("phantom:teapot:8")
        .unwrap()
        .unwrap_err()
        .to_string();
    assert_contains(&e, "unknown phantom 'teapot'");
}

#[test]
fn shepp_logan_has_sensible_range_and_symmetry() {
    let v = phantom::shepp_logan(64);
    let s = stats(&v, 10);
    assert_eq!((s.min, s.max), (0.0, 1.0));
    assert!(s.mean > 0.05 && s.mean < 0.3, "mean {}", s.mean);
    let VoxelData::F32(d) = &v.data else { panic!() };
    // Brain tissue (0.2) is the most common non-background value.
    let brain = d.iter().filter(|&&x| (x - 0.2).abs() < 1e-6).count();
    assert!(brain > d.len() / 10, "brain voxels {brain}");
    // Mirror symmetric in x except for the small asymmetric features.
    let n = 64;
    let same = (0..d.len()).filter(|&i| {
        let (x, rest) = (i % n, i / n);
        d[i] == d[rest * n + (n - 1 - x)]
    });
    assert!(same.count() as f64 > 0.97 * d.len() as f64);
}

#[test]
fn nested_has_equal_intensity_in_both_structures() {
    let n = 64;
    let v = phantom::nested(n);
    assert_eq!(v.spacing, [1.0; 3]);
    let c = (n - 1) / 2;
    let at = |x: f64| {
        let i = ((x + 1.0) / 2.0 * (n - 1) as f64).round() as usize;
        v.data.get_f64(v.index(i, c, c)) as f32
    };
    // Two spheres of equal intensity: left inside a low shell, right inside a medium shell.
    assert_eq!(
        (at(-0.45), at(-0.45 + 0.3), at(-0.45 - 0.3)),
        (NESTED_CORE, NESTED_LOW, NESTED_LOW)
    );
    assert_eq!(
        (at(0.45), at(0.45 + 0.3), at(0.45 - 0.3)),
        (NESTED_CORE, NESTED_MEDIUM, NESTED_MEDIUM)
    );
    assert_eq!((at(-1.0), at(0.0), at(1.0)), (0.0, 0.0, 0.0));
    // Each shell (radii 0.2..0.4) holds 7x the voxels of its sphere; the spheres are equal.
    let VoxelData::F32(d) = &v.data else { panic!() };
    let count = |val: f32| d.iter().filter(|&&x| x == val).count();
    assert!(count(NESTED_CORE) > 2000);
    assert!(
        count(NESTED_LOW) > 3 * count(NESTED_CORE) / 2
            && count(NESTED_MEDIUM) > 3 * count(NESTED_CORE) / 2
    );
}

#[test]
fn dicom_rejects_compressed_syntax_and_mixed_series() {
    let Some(data) = shared_data() else { return };
    let dicom = data.join("formats/dicom");
    let first = |series: &str| {
        let mut files: Vec<_> = fs::read_dir(dicom.join(series))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        files.remove(0)
    };
    for (series, spacing) in [
        ("seg3d_mr_640", [0.625, 0.625, 2.5]),
        ("vs_seg001_t1", [0.41015625, 0.41015625, 1.5]),
    ] {
        let v = load(&dicom.join(series), None).unwrap();
        assert!(
            v.spacing
                .iter()
                .zip(spacing)
                .all(|(a, b)| (a - b).abs() < 1e-6),
            "{series} spacing {:?}",
            v.spacing
        );
    }

    // A slice whose meta header claims RLE Lossless (same UID length as explicit VR little endian).
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = fs::read(first("seg3d_mr_640")).unwrap();
    let (from, to) = (b"1.2.840.10008.1.2.1\0", b"1.2.840.10008.1.2.5\0");
    let at = bytes[..2048]
        .windows(from.len())
        .position(|w| w == from)
        .expect("transfer syntax UID in meta header");
    bytes[at..at + to.len()].copy_from_slice(to);
    write(dir.path(), "slice.dcm", &bytes);
    assert_contains(
        &load_err(dir.path()),
        "transfer syntax 1.2.840.10008.1.2.5 is compressed or unsupported",
    );

    let dir = tempfile::tempdir().unwrap();
    for series in ["seg3d_mr_640", "vs_seg001_t1"] {
        fs::copy(first(series), dir.path().join(format!("{series}.dcm"))).unwrap();
    }
    assert_contains(&load_err(dir.path()), "expected a single series");
}
