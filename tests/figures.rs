//! The importance paper's Figures 3–9 (`vellum figures importance`) against stored reference
//! sheets in tests/reference/importance/, at 96² pixels per tile, within a mean of 1/255 and a
//! max of 24/255 per channel (the render tests' tolerance). Regenerate them with
//! `VELLUM_UPDATE_REFERENCES=1 cargo test --test figures` and look at every one before committing.

mod common;

use common::Gpu;
use std::path::PathBuf;

#[test]
fn importance_figures_match_their_references() {
    if common::shared_data().is_none() {
        return;
    }
    let gpu = Gpu::new();
    let sheets = vellum::figures::importance_sheets(&gpu.ctx, 96).unwrap();
    assert_eq!(sheets.len(), 7, "Figures 3 to 9");
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/reference/importance");
    let update = std::env::var("VELLUM_UPDATE_REFERENCES").as_deref() == Ok("1");
    for (file, c) in sheets {
        let path = dir.join(file);
        if update {
            std::fs::create_dir_all(&dir).unwrap();
            vellum::output::write_png_rgb(&path, c.width as u32, c.height as u32, &c.rgb).unwrap();
            eprintln!("updated {}", path.display());
            continue;
        }
        let stored = image::open(&path)
            .unwrap_or_else(|e| {
                panic!(
                    "{}: {e}; regenerate with VELLUM_UPDATE_REFERENCES=1",
                    path.display()
                )
            })
            .to_rgb8();
        assert_eq!(
            (stored.width() as usize, stored.height() as usize),
            (c.width, c.height),
            "{file}"
        );
        let (mut sum, mut max) = (0u64, 0u8);
        for (a, b) in stored.as_raw().iter().zip(&c.rgb) {
            let d = a.abs_diff(*b);
            sum += d as u64;
            max = max.max(d);
        }
        let mean = sum as f64 / c.rgb.len() as f64;
        assert!(
            mean <= 1.0 && max <= 24,
            "{file}: mean {mean:.3}/255, max {max}/255"
        );
        // Each tile shows something: not one flat colour.
        let distinct: std::collections::HashSet<&[u8]> = c.rgb.chunks(3).collect();
        assert!(distinct.len() > 50, "{file}: flat");
    }
}
