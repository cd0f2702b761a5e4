use vellum::gpu::{Context, ContextDesc};
use vellum::render::scene::Scene;
use vellum::render::session::{Session, SessionOptions};
use vellum::render::targets::to_rgb8;

fn main() -> vellum::Result<()> {
    // Any input the command line takes: a file, a DICOM folder, an OME-Zarr store, a phantom.
    let scene = Scene::from_json_str(
        r#"{"version": 1, "input": {"path": "phantom:torus:96"}, "focus": {"iso": 0.5},
            "style": {"style": "silhouettes"}, "raycast": {}, "background": [1, 1, 1],
            "camera": {"azimuth": 30, "elevation": 40}, "size": [256, 256]}"#,
    )?;
    let ctx = Context::new(&ContextDesc::default())?;
    // The session puts the volume in core or behind the brick cache, within the GPU budget.
    let mut session = Session::open(&ctx, &scene, None, &SessionOptions::default())?;
    let oriented = session.prepared.volume().geometry().is_oriented();
    let (view, _) = session.view(scene.view(oriented)?);
    let (frame, _) = session.still(&view, Default::default())?;
    let rgb = to_rgb8(&frame.composite, scene.background);
    let out = std::env::temp_dir().join("vellum-example.png");
    vellum::output::write_png_rgb(&out, frame.size[0], frame.size[1], &rgb)?;
    assert!(ctx.messages().is_clean(), "{:?}", ctx.messages().messages);
    Ok(())
}
