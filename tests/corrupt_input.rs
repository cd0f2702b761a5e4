//! Robustness of the readers: truncated and byte-corrupted copies of real files in every format
//! must end in `Ok` or an `Err` with a message, never in a panic. Deterministic: the corruptions
//! come from a fixed-seed generator.

mod common;

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

/// xorshift64*, enough to pick offsets reproducibly.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545F4914F6CDD1D)
    }
}

fn must_not_panic(path: &Path, what: &str) {
    let r = catch_unwind(AssertUnwindSafe(|| vellum::volume::io::load(path, None)));
    match r {
        Ok(Ok(_)) => {}
        Ok(Err(e)) => assert!(!e.to_string().is_empty(), "{what}: empty error message"),
        Err(_) => panic!("{what}: the reader panicked"),
    }
}

/// Writes `variants` corrupted copies of `src` (plus `companions`, copied unchanged) into a temp
/// folder under the same file name and loads each.
fn corrupt_and_load(src: &Path, companions: &[&Path], rng: &mut Rng, variants: usize) {
    let bytes = std::fs::read(src).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for c in companions {
        std::fs::copy(c, dir.path().join(c.file_name().unwrap())).unwrap();
    }
    let target = dir.path().join(src.file_name().unwrap());
    let name = src.file_name().unwrap().to_string_lossy().to_string();
    for v in 0..variants {
        let mut b = bytes.clone();
        match v % 3 {
            // Truncate anywhere, header included.
            0 => b.truncate((rng.next() % bytes.len() as u64) as usize),
            // Flip a few bytes, biased towards the header.
            1 => {
                for _ in 0..4 {
                    let limit = if rng.next().is_multiple_of(2) {
                        bytes.len().min(600)
                    } else {
                        bytes.len()
                    };
                    let i = (rng.next() % limit as u64) as usize;
                    b[i] ^= (rng.next() % 255 + 1) as u8;
                }
            }
            // Overwrite a header byte with a digit, which can turn sizes absurd.
            _ => {
                let i = (rng.next() % bytes.len().min(400) as u64) as usize;
                b[i] = b'9';
            }
        }
        std::fs::write(&target, &b).unwrap();
        must_not_panic(&target, &format!("{name} variant {v}"));
    }
}

#[test]
fn corrupted_files_never_panic() {
    let Some(data) = common::shared_data() else {
        return;
    };
    let mut rng = Rng(0x5eed_1234_abcd_0001);
    let f = |p: &str| data.join(p);
    corrupt_and_load(&f("formats/nrrd/tooth.nrrd"), &[], &mut rng, 30);
    corrupt_and_load(&f("formats/nrrd/seg3d_skull_mask.nrrd"), &[], &mut rng, 30);
    corrupt_and_load(&f("formats/nifti/stroke_t1.nii.gz"), &[], &mut rng, 30);
    corrupt_and_load(
        &f("formats/metaimage/HeadMRVolume.mhd"),
        &[&f("formats/metaimage/HeadMRVolume.raw")],
        &mut rng,
        30,
    );
    corrupt_and_load(
        &f("formats/metaimage/HeadMRVolume.raw"),
        &[&f("formats/metaimage/HeadMRVolume.mhd")],
        &mut rng,
        10,
    );
    corrupt_and_load(
        &f("formats/metaimage/frogtissue.zraw"),
        &[&f("formats/metaimage/frogtissue.mhd")],
        &mut rng,
        10,
    );
    corrupt_and_load(
        &f("volumes/bucky/bucky.nhdr"),
        &[&f("volumes/bucky/bucky_32x32x32_uint8.raw.gz")],
        &mut rng,
        30,
    );
    corrupt_and_load(
        &f("volumes/bucky/bucky_32x32x32_uint8.raw.gz"),
        &[&f("volumes/bucky/bucky.nhdr")],
        &mut rng,
        20,
    );
}

#[test]
fn corrupted_dicom_slices_never_panic() {
    let Some(data) = common::shared_data() else {
        return;
    };
    let series = data.join("formats/dicom/seg3d_mr_640");
    let mut files: Vec<_> = std::fs::read_dir(&series)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    let mut rng = Rng(0xd1c0_0000_0000_0042);
    let dir = tempfile::tempdir().unwrap();
    for (v, _) in (0..12).enumerate() {
        for (i, f) in files.iter().take(4).enumerate() {
            let mut b = std::fs::read(f).unwrap();
            if i == v % 4 {
                if v % 2 == 0 {
                    b.truncate((rng.next() % b.len() as u64) as usize);
                } else {
                    let j = (rng.next() % b.len().min(2000) as u64) as usize;
                    b[j] ^= 0x5a;
                }
            }
            std::fs::write(dir.path().join(f.file_name().unwrap()), &b).unwrap();
        }
        must_not_panic(dir.path(), &format!("dicom variant {v}"));
    }
}
