//! The image-space style passes on lavapipe (validation on) against their CPU references in
//! `imaging/`, on the layers of a phantom render and of the CT head's focus (skull, iso 1300).
//! Each pass is checked on the GPU's own input, read back, so that one pass's rounding does not
//! count against the next. Tolerances:
//! - luminance, saturation, the style composite: |Δ| ≤ 1e-5;
//! - Sobel: the magnitude within 1e-5; edge pixels equal but for ties at the threshold
//!   (≤ 0.1 % of the pixels);
//! - DoG: |Δ| ≤ 2e-3 (tanh at φ = 100 magnifies the blur's 1e-6 rounding);
//! - Canny: the hysteresis converges, and the edge set equals the CPU's but for ≤ 0.5 % of its
//!   pixels (non-maximum suppression flips on near-equal magnitudes);
//! - Kuwahara: |Δ| ≤ 1e-4 on all but ≤ 0.1 % of the pixels (near-equal quadrant variances).
//!
//! Also: reference images of styles 1, 2, 3, 13, 14 and 15 on the CT head in tests/reference/styles/
//! (mean ≤ 1/255, max ≤ 24/255; regenerate with `VELLUM_UPDATE_REFERENCES=1 cargo test --test
//! styles` and look at each one).

mod common;

use common::Gpu;
use vellum::classify::transfer::TransferFunction;
use vellum::classify::{Classification, Focus};
use vellum::gpu::transfer::readback;
use vellum::gpu::Image;
use vellum::imaging::{edges, stylise, Plane};
use vellum::render::style::{Style, StyleParams};
use vellum::render::targets::FrameTargets;
use vellum::volume::{phantom, Volume};

fn plane(gpu: &Gpu, image: &Image) -> Plane {
    let [w, h, _] = image.desc.extent;
    Plane {
        width: w as usize,
        height: h as usize,
        data: bytemuck::pod_collect_to_vec(&readback(&gpu.ctx, image).unwrap()),
    }
}

fn rgba(gpu: &Gpu, image: &Image) -> Vec<[f32; 4]> {
    bytemuck::pod_collect_to_vec(&readback(&gpu.ctx, image).unwrap())
}

/// Renders `v` with `style` into persistent targets and returns them.
fn styled(
    gpu: &Gpu,
    v: &Volume,
    tf: &str,
    focus: Focus,
    camera: &str,
    size: u32,
    style: &str,
) -> FrameTargets {
    let (targets, passes) = common::styled_frame(
        &gpu.ctx,
        v,
        &Classification::Transfer(TransferFunction::preset(tf).unwrap()),
        focus,
        camera,
        size,
        Style::new(style, StyleParams::default()).unwrap(),
    );
    let names: Vec<&str> = passes.iter().map(|p| p.name.as_str()).collect();
    let plain = style == "15" || style == "none";
    assert_eq!(names.contains(&"style_composite"), !plain, "{names:?}");
    targets
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

fn count_over(a: &[f32], b: &[f32], tol: f32) -> usize {
    a.iter()
        .zip(b)
        .filter(|(x, y)| (*x - *y).abs() > tol)
        .count()
}

fn cases() -> Vec<(&'static str, Volume, &'static str, Focus, &'static str, u32)> {
    let mut v = vec![(
        "nested",
        phantom::nested(48),
        "grey",
        Focus::Iso(0.4),
        "20,30,2.5",
        96,
    )];
    if let Some(head) = common::real_volume("cthead_stanford") {
        v.push((
            "cthead",
            head,
            "ct-skin-bone",
            Focus::Iso(1300.0),
            "0,0,2.4",
            160,
        ));
    }
    v
}

#[test]
fn edge_passes_match_the_cpu() {
    let gpu = Gpu::new();
    let p = StyleParams::default();
    for (name, v, tf, focus, camera, size) in cases() {
        for style in ["sobel", "dog", "canny"] {
            let t = styled(&gpu, &v, tf, focus, camera, size, style);
            let images = t.images().unwrap();
            let layers = images.layers.as_ref().unwrap();
            let post = images.post.as_ref().unwrap();
            let (w, h) = (size as usize, size as usize);
            let diffuse = rgba(&gpu, &layers.focus_diffuse);
            let lum = plane(&gpu, &post.luminance);
            let want_lum = vellum::imaging::luminance_plane(&diffuse, w, h);
            assert!(
                max_diff(&lum.data, &want_lum.data) <= 1e-5,
                "{name} luminance"
            );
            assert!(
                lum.data.iter().any(|&l| l > 0.05),
                "{name}: the focus layer shows something"
            );
            let got = plane(&gpu, &post.edges);
            match style {
                "sobel" => {
                    let grad: Vec<[f32; 4]> = rgba(&gpu, &post.gradient);
                    let mag: Vec<f32> = grad.iter().map(|g| g[2]).collect();
                    let want_mag = edges::sobel_magnitude(&lum);
                    assert!(
                        max_diff(&mag, &want_mag.data) <= 1e-5,
                        "{name} sobel magnitude"
                    );
                    let want = edges::sobel_edges(&lum, p.sobel_threshold);
                    let off = count_over(&got.data, &want.data, 0.5);
                    assert!(off * 1000 <= w * h, "{name} sobel: {off} pixels differ");
                    assert!(want.data.iter().sum::<f32>() > 50.0, "{name}: edges found");
                }
                "dog" => {
                    let want = edges::dog_edges(
                        &lum,
                        &edges::DogParams {
                            sigma: p.dog_sigma,
                            k: p.dog_k,
                            tau: p.dog_tau,
                            threshold: p.dog_threshold,
                            phi: p.dog_phi,
                        },
                    );
                    let d = max_diff(&got.data, &want.data);
                    assert!(d <= 2e-3, "{name} dog: max |Δ| {d}");
                    assert!(want.data.iter().sum::<f32>() > 20.0, "{name}: edges found");
                }
                _ => {
                    assert!(
                        post.hysteresis_converged(&gpu.ctx).unwrap(),
                        "{name}: hysteresis did not converge"
                    );
                    let edges_gpu: Vec<f32> =
                        got.data.iter().map(|c| (c - 1.0).clamp(0.0, 1.0)).collect();
                    let want = edges::canny_edges(
                        &lum,
                        &edges::CannyParams {
                            sigma: p.canny_sigma,
                            high: p.canny_high,
                            low_ratio: p.canny_low_ratio,
                        },
                    );
                    let n = want.data.iter().filter(|&&e| e == 1.0).count();
                    let off = count_over(&edges_gpu, &want.data, 0.5);
                    assert!(n > 50, "{name}: canny found {n} pixels");
                    assert!(
                        off * 200 <= n,
                        "{name} canny: {off} of {n} edge pixels differ"
                    );
                }
            }
            // The composite: edges over the focus, the context over that.
            let edge_plane = if style == "canny" {
                Plane {
                    data: got.data.iter().map(|c| (c - 1.0).clamp(0.0, 1.0)).collect(),
                    ..got.clone()
                }
            } else {
                got.clone()
            };
            let look = stylise::EdgeLook {
                color: p.edge_color,
                opacity: p.edge_opacity,
                width: p.edge_width,
            };
            let want = stylise::composite(
                &rgba(&gpu, &layers.focus_phong),
                &rgba(&gpu, &layers.context),
                Some((&edge_plane, &look)),
            );
            let got = rgba(&gpu, &images.composite);
            let d = max_diff(
                &got.iter().flatten().copied().collect::<Vec<_>>(),
                &want.iter().flatten().copied().collect::<Vec<_>>(),
            );
            assert!(d <= 1e-5, "{name} {style} composite: {d}");
        }
    }
}

#[test]
fn abstraction_passes_match_the_cpu() {
    let gpu = Gpu::new();
    let p = StyleParams::default();
    for (name, v, tf, focus, camera, size) in cases() {
        for style in ["kuwahara", "saturation"] {
            let t = styled(&gpu, &v, tf, focus, camera, size, style);
            let images = t.images().unwrap();
            let layers = images.layers.as_ref().unwrap();
            let post = images.post.as_ref().unwrap();
            let context = rgba(&gpu, &layers.context);
            assert!(context.iter().any(|c| c[3] > 0.05), "{name}: context shows");
            let got: Vec<f32> = rgba(&gpu, &post.context).into_iter().flatten().collect();
            let want: Vec<f32> = if style == "kuwahara" {
                stylise::kuwahara(
                    &context,
                    size as usize,
                    size as usize,
                    p.kuwahara_radius as usize,
                )
            } else {
                context
                    .iter()
                    .map(|&c| stylise::saturate(c, p.saturation))
                    .collect()
            }
            .into_iter()
            .flatten()
            .collect();
            if style == "kuwahara" {
                let off = count_over(&got, &want, 1e-4);
                assert!(
                    off * 1000 <= got.len(),
                    "{name} kuwahara: {off} values differ"
                );
            } else {
                assert!(max_diff(&got, &want) <= 1e-5, "{name} saturation");
            }
        }
    }
}

#[test]
fn style_references() {
    let Some(head) = common::real_volume("cthead_stanford") else {
        return;
    };
    let gpu = Gpu::new();
    for style in [1, 2, 3, 13, 14, 15] {
        let t = styled(
            &gpu,
            &head,
            "ct-skin-bone",
            Focus::Iso(1300.0),
            "0,0,2.4",
            128,
            &style.to_string(),
        );
        let pixels = rgba(&gpu, &t.images().unwrap().composite);
        let rgb = vellum::render::targets::to_rgb8(&pixels, [0.0; 3]);
        common::check_reference(
            &format!("styles/cthead_style{style:02}.png"),
            128,
            128,
            &rgb,
        );
    }
}

/// Every style over levels drawn once (`Renderer::render_styles`, the gallery's way) equals
/// that style's own whole frame (`render_frame`) exactly, on the Shepp–Logan phantom: the style
/// passes read only the layers, so styling the same layers again leaves no trace of the style
/// before. The first frame has the levels' passes; the others only the style's.
#[test]
fn styles_over_levels_drawn_once_equal_their_own_frames() {
    use vellum::render::frame::Renderer;
    use vellum::render::style::STYLES;
    use vellum::render::view::{Lighting, View};
    let gpu = Gpu::new();
    let v = phantom::shepp_logan(48);
    let c = Classification::Transfer(TransferFunction::preset("grey").unwrap());
    let focus = Focus::Iso(0.25);
    let mut scene =
        vellum::render::scene::GpuScene::prepare(&gpu.ctx, &v, &c, focus, &Default::default())
            .unwrap();
    let view = View {
        camera: vellum::render::camera::Camera::parse("30,20").unwrap(),
        size: [96, 96],
        slices: None,
        one_pass: false,
        lighting: Lighting::default(),
        style: None,
        fit: true,
        raycast: None,
    };
    let styles: Vec<Style> = STYLES
        .iter()
        .filter(|d| d.available())
        .map(|def| Style {
            def,
            params: StyleParams::default(),
        })
        .collect();
    let mut renderer = Renderer::new(&gpu.ctx).unwrap();
    let once = renderer
        .render_styles(&scene.volume, &mut scene.classify, &view, &styles)
        .unwrap();
    assert_eq!(once.len(), styles.len());
    for (style, got) in styles.iter().zip(&once) {
        let v = View {
            style: Some(*style),
            ..view.clone()
        };
        let own = renderer
            .render_frame(&scene.volume, &mut scene.classify, &v, true)
            .unwrap();
        assert!(
            own.composite == got.composite,
            "style {} differs over shared levels",
            style.def.number
        );
    }
    let levels =
        |f: &vellum::render::targets::FrameImage| f.passes.iter().any(|p| p.name == "focus");
    assert!(levels(&once[0]) && once[1..].iter().filter(|f| levels(f)).count() <= 1);
}
