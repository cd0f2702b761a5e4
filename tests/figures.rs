//! The importance paper's Figures 3–9 (`vellum figures importance`) against stored reference
//! sheets in tests/reference/importance/, at 96² pixels per tile, within a mean of 1/255 and a
//! max of 24/255 per channel (the render tests' tolerance). Regenerate them with
//! `VELLUM_UPDATE_REFERENCES=1 cargo test --test figures` and look at every one before committing.

mod common;

use common::Gpu;

#[test]
fn importance_figures_match_their_references() {
    if common::shared_data().is_none() {
        return;
    }
    let gpu = Gpu::new();
    let sheets = vellum_tools::figures::importance_sheets(&gpu.ctx, 96).unwrap();
    assert_eq!(sheets.len(), 7, "Figures 3 to 9");
    for (file, c) in sheets {
        common::check_reference(
            &format!("importance/{file}"),
            c.width as u32,
            c.height as u32,
            &c.rgb,
        );
        // Each tile shows something: not one flat colour.
        let distinct: std::collections::HashSet<&[u8]> = c.rgb.chunks(3).collect();
        assert!(distinct.len() > 50, "{file}: flat");
    }
}
