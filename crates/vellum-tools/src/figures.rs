//! `vellum figures importance`: the importance paper's Figures 3–9 as labelled contact sheets, on
//! the CT body (ct_chest_lidc2) and the CT head (cthead_stanford) from the shared data.
//!
//! Each figure renders one prepared scene per (volume, transfer function), with ΔD at R = 10 as in
//! every figure of the paper, and changes only the modulation between tiles: the tiles of a sheet
//! differ in nothing else.
//!
//! ## The γ scale
//! Our γ multiplies ΔD in normalised intensity units (`classify::modulation`), exactly as eq. 3 and
//! 4 are written. The paper's γ was on its own intensity scale. Measured on these volumes, the median
//! |ΔD| inside bone is 0.10 (CT head) to 0.24 (CT body), so the paper's γ = 10 taken literally
//! turns the body black, where the paper shows it darker. Figures 3 and 4 therefore use
//! γ = γ_paper / 10, and each tile says both values.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::Context;
use vellum_render::classify::modulation::{
    ColorMode, ColorModulation, ModulateLighting, Modulation, OpacityModulation, Stipple,
    DEFAULT_IMPORTANCE_RADIUS,
};
use vellum_render::classify::transfer::TransferFunction;
use vellum_render::classify::{Classification, Focus};
use vellum_render::plot::Canvas;
use vellum_render::render::camera::Camera;
use vellum_render::render::frame::Renderer;
use vellum_render::render::scene::GpuScene;
use vellum_render::render::targets::to_rgb8;
use vellum_render::render::view::{Lighting, View};
use vellum_volume::Volume;

/// One tile: its label and modulation.
struct Tile {
    label: String,
    modulation: Modulation,
}

/// One figure: a row of tiles of one volume and transfer function.
struct Figure {
    file: &'static str,
    title: &'static str,
    volume: &'static str,
    transfer: &'static str,
    camera: &'static str,
    tiles: Vec<Tile>,
}

const CT_BODY: &str = "ct_chest_lidc2";
const CT_HEAD: &str = "cthead_stanford";
const BODY_CAMERA: &str = "0,0,2.0";
const HEAD_CAMERA: &str = "0,0,2.2";

fn base() -> Modulation {
    Modulation {
        importance_radius: DEFAULT_IMPORTANCE_RADIUS,
        ..Modulation::default()
    }
}

/// Our γ for the paper's (see the module's doc).
pub const GAMMA_SCALE: f32 = 0.1;

fn color(mode: ColorMode, paper_gamma: f32, lighting: ModulateLighting) -> Tile {
    let gamma = paper_gamma * GAMMA_SCALE;
    Tile {
        label: format!("GAMMA {gamma} (PAPER {paper_gamma})"),
        modulation: Modulation {
            color: Some(ColorModulation { mode, gamma }),
            lighting,
            ..base()
        },
    }
}

fn opacity(k_low: f32) -> OpacityModulation {
    OpacityModulation {
        t_low: 1.0,
        t_high: 1.0,
        k_low,
        k_high: 1.0,
    }
}

fn opacity_tile(k_low: f32) -> Tile {
    Tile {
        label: format!("KL {k_low}"),
        modulation: Modulation {
            opacity: Some(opacity(k_low)),
            ..base()
        },
    }
}

fn stipple(t: f32, f: f32) -> Stipple {
    Stipple {
        t,
        f,
        seed: 1,
        white: [1.0; 3],
        black: [0.0; 3],
    }
}

fn stipple_tile(t: f32, f: f32) -> Tile {
    Tile {
        label: format!("T {t} F {f}"),
        modulation: Modulation {
            stipple: Some(stipple(t, f)),
            ..base()
        },
    }
}

fn original() -> Tile {
    Tile {
        label: "ORIGINAL".into(),
        modulation: base(),
    }
}

fn figures() -> Vec<Figure> {
    use ColorMode::*;
    use ModulateLighting::*;
    vec![
        Figure {
            file: "fig3_color_raw_ambient_ct_body.png",
            title: "FIG 3  RAW COLOUR MODULATION (EQ 3)  AMBIENT  CT BODY",
            volume: CT_BODY,
            transfer: "ct-skin-bone",
            camera: BODY_CAMERA,
            tiles: [-10.0, 0.0, 10.0, 20.0]
                .map(|g| color(Raw, g, Ambient))
                .into(),
        },
        Figure {
            file: "fig4_color_abs_phong_ct_body.png",
            title: "FIG 4  ABSOLUTE COLOUR MODULATION (EQ 4)  PHONG  CT BODY",
            volume: CT_BODY,
            transfer: "ct-skin-bone",
            camera: BODY_CAMERA,
            tiles: [-5.0, 0.0, 5.0, 10.0].map(|g| color(Abs, g, Phong)).into(),
        },
        Figure {
            file: "fig5_opacity_ct_head.png",
            title: "FIG 5  OPACITY MODULATION (EQ 5)  TL=1 TH=1 KH=1  CT HEAD",
            volume: CT_HEAD,
            transfer: "ct-skin-bone",
            camera: HEAD_CAMERA,
            tiles: std::iter::once(original())
                .chain([0.5, 1.0, 2.0, 5.0].map(opacity_tile))
                .collect(),
        },
        Figure {
            file: "fig6_opacity_linear_tf_ct_head.png",
            title: "FIG 6  OPACITY MODULATION  DEFAULT LINEAR TF  CT HEAD",
            volume: CT_HEAD,
            transfer: "grey",
            camera: HEAD_CAMERA,
            tiles: std::iter::once(original())
                .chain([0.5, 1.0, 2.0, 5.0].map(opacity_tile))
                .collect(),
        },
        Figure {
            file: "fig7_stipple_ct_head.png",
            title: "FIG 7  STIPPLING (EQ 6)  CT HEAD",
            volume: CT_HEAD,
            transfer: "ct-skin-bone",
            camera: HEAD_CAMERA,
            tiles: [5.0, 10.0, 15.0, 20.0].map(|f| stipple_tile(0.1, f)).into(),
        },
        Figure {
            file: "fig8_stipple_ct_body.png",
            title: "FIG 8  STIPPLING (EQ 6)  CT BODY",
            volume: CT_BODY,
            transfer: "ct-skin-bone",
            camera: BODY_CAMERA,
            tiles: [(0.03, 10.0), (0.03, 20.0), (0.1, 10.0), (0.1, 20.0)]
                .map(|(t, f)| stipple_tile(t, f))
                .into(),
        },
        Figure {
            file: "fig9_stipple_and_opacity_ct_body.png",
            title: "FIG 9  STIPPLING T=1 F=1 WITH OPACITY MODULATION 1 1 1 1  CT BODY",
            volume: CT_BODY,
            transfer: "ct-skin-bone",
            camera: BODY_CAMERA,
            tiles: vec![
                Tile {
                    label: "OPACITY".into(),
                    modulation: Modulation {
                        opacity: Some(opacity(1.0)),
                        ..base()
                    },
                },
                Tile {
                    label: "STIPPLE".into(),
                    modulation: Modulation {
                        stipple: Some(stipple(1.0, 1.0)),
                        ..base()
                    },
                },
                Tile {
                    label: "BOTH".into(),
                    modulation: Modulation {
                        opacity: Some(opacity(1.0)),
                        stipple: Some(stipple(1.0, 1.0)),
                        ..base()
                    },
                },
            ],
        },
    ]
}

fn load(data: &Path, name: &str) -> Result<Volume> {
    let path = data.join("volumes").join(name).join(format!("{name}.nhdr"));
    vellum_volume::io::load(&path, None)
}

/// Renders the importance paper's figures at `size`² per tile and writes them to `out_dir`,
/// all or nothing: every sheet is rendered before the first is written. Returns the files.
pub fn importance(ctx: &Arc<Context>, out_dir: &Path, size: u32) -> Result<Vec<PathBuf>> {
    let sheets = importance_sheets(ctx, size)?;
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    let mut written = Vec::new();
    for (file, c) in sheets {
        let path = out_dir.join(file);
        vellum_volume::output::write_png_rgb(&path, c.width as u32, c.height as u32, &c.rgb)?;
        written.push(path);
    }
    Ok(written)
}

/// The importance paper's figures as (file name, sheet), `size`² pixels per tile.
pub fn importance_sheets(ctx: &Arc<Context>, size: u32) -> Result<Vec<(&'static str, Canvas)>> {
    if !(32..=2048).contains(&size) {
        return Err(Error::Invalid(format!(
            "tile size {size} is invalid; expected 32..=2048 pixels"
        )));
    }
    let data = crate::bench::shared_data().ok_or_else(|| {
        Error::Invalid(
            "the figures need ../shared/data (or VELLUM_DATA) with ct_chest_lidc2 and cthead_stanford"
                .into(),
        )
    })?;
    let mut renderer = Renderer::new(ctx)?;
    let mut sheets = Vec::new();
    let mut prepared: Option<((&str, &str), GpuScene)> = None;
    for fig in figures() {
        let key = (fig.volume, fig.transfer);
        if prepared.as_ref().map(|p| p.0) != Some(key) {
            let v = load(&data, fig.volume)?;
            let tf = TransferFunction::preset(fig.transfer)?;
            // Any active modulation attaches ΔD; the tiles then only swap parameters.
            let with_delta = Modulation {
                opacity: Some(opacity(1.0)),
                ..base()
            };
            let scene = GpuScene::prepare(
                ctx,
                &v,
                &Classification::Transfer(tf),
                Focus::None,
                &with_delta,
            )?;
            prepared = Some((key, scene));
        }
        let scene = &mut prepared.as_mut().expect("prepared above").1;
        let view = View {
            camera: Camera::parse(fig.camera)?,
            size: [size, size],
            slices: None,
            one_pass: true,
            lighting: Lighting::default(),
            style: None,
            fit: false,
            raycast: None,
        };
        let mut tiles = Vec::new();
        for tile in &fig.tiles {
            scene.classify.modulation = tile.modulation.clone();
            let frame = renderer.render_frame(&scene.volume, &mut scene.classify, &view, true)?;
            tiles.push((tile.label.clone(), to_rgb8(&frame.composite, [0.0; 3])));
        }
        sheets.push((fig.file, sheet(fig.title, &tiles, size as usize)));
    }
    Ok(sheets)
}

/// A row of tiles under a title, each with its label below it.
fn sheet(title: &str, tiles: &[(String, Vec<u8>)], size: usize) -> Canvas {
    const PAD: usize = 8;
    const SCALE: i64 = 2;
    let text_h = 5 * SCALE as usize + 2 * PAD;
    let title_w = Canvas::text_width(title, SCALE) as usize + 2 * PAD;
    let width = (PAD + tiles.len() * (size + PAD)).max(title_w);
    let height = text_h + size + text_h;
    let mut c = Canvas::new(width, height, [24, 24, 24]);
    let white = [235, 235, 235];
    c.text(PAD as i64, PAD as i64, title, SCALE, white);
    for (i, (label, rgb)) in tiles.iter().enumerate() {
        let x0 = PAD + i * (size + PAD);
        for y in 0..size {
            for x in 0..size {
                let p = 3 * (y * size + x);
                c.set(
                    (x0 + x) as i64,
                    (text_h + y) as i64,
                    [rgb[p], rgb[p + 1], rgb[p + 2]],
                );
            }
        }
        // Small tiles take the label at half size, so that it stays under its own tile.
        let scale = if Canvas::text_width(label, SCALE) as usize <= size {
            SCALE
        } else {
            1
        };
        let lw = Canvas::text_width(label, scale) as usize;
        c.text(
            (x0 + size.saturating_sub(lw) / 2) as i64,
            (text_h + size + PAD) as i64,
            label,
            scale,
            white,
        );
    }
    c
}

/// One tile of a style gallery.
pub struct GalleryTile {
    pub def: &'static vellum_render::render::style::StyleDef,
    /// The rendered frame (with its layers), or `None` for a style this build cannot render.
    pub frame: Option<vellum_render::render::targets::FrameImage>,
    /// Mean saliency inside the focus (where the focus depth is finite) and outside it.
    pub saliency: Option<(f64, f64)>,
}

/// The paper's Fig. 11 for any scene: every style of the table rendered from `view` (a two-level
/// view; its own style is ignored) with `params`, and a labelled contact sheet of them. Styles that
/// need object-space lines get a dark tile that says so. With `saliency`, each rendered style's
/// mean saliency inside and outside the focus.
pub fn style_gallery(
    ctx: &Arc<Context>,
    scene: &mut GpuScene,
    view: &View,
    params: vellum_render::render::style::StyleParams,
    background: [f32; 3],
    saliency: bool,
) -> Result<(Canvas, Vec<GalleryTile>)> {
    use vellum_render::render::style::{Style, STYLES};
    params.validate()?;
    let mut renderer = Renderer::new(ctx)?;
    let [w, h] = view.size.map(|s| s as usize);
    // The levels are drawn once; each style's passes run over them.
    let styles: Vec<Style> = STYLES
        .iter()
        .filter(|d| d.available())
        .map(|def| Style { def, params })
        .collect();
    let mut frames = renderer
        .render_styles(&scene.volume, &mut scene.classify, view, &styles)?
        .into_iter();
    let mut tiles = Vec::new();
    for def in STYLES.iter() {
        let frame = match def.available() {
            true => frames.next(),
            false => None,
        };
        let sal = match (&frame, saliency) {
            (Some(f), true) => Some(focus_saliency(f, background)?),
            _ => None,
        };
        tiles.push(GalleryTile {
            def,
            frame,
            saliency: sal,
        });
    }
    const COLUMNS: usize = 5;
    const PAD: usize = 8;
    // Labels grow with the tiles: 10 px letters at 256², 15 px at 384², and so on.
    let scale = (w / 128).clamp(2, 4) as i64;
    let label_h = 5 * scale as usize + 2 * PAD;
    let rows = tiles.len().div_ceil(COLUMNS);
    let mut c = Canvas::new(
        PAD + COLUMNS * (w + PAD),
        PAD + rows * (h + label_h),
        [24, 24, 24],
    );
    for (i, t) in tiles.iter().enumerate() {
        let (x0, y0) = (
            PAD + (i % COLUMNS) * (w + PAD),
            PAD + (i / COLUMNS) * (h + label_h),
        );
        match &t.frame {
            Some(f) => {
                let rgb = to_rgb8(&f.composite, background);
                for y in 0..h {
                    for x in 0..w {
                        let p = 3 * (y * w + x);
                        c.set(
                            (x0 + x) as i64,
                            (y0 + y) as i64,
                            [rgb[p], rgb[p + 1], rgb[p + 2]],
                        );
                    }
                }
            }
            None => {
                c.rect(x0 as i64, y0 as i64, w as i64, h as i64, [48, 48, 48]);
                c.text(
                    x0 as i64 + 6,
                    (y0 + h / 2) as i64 - 5,
                    "NEEDS LINES",
                    scale,
                    [150, 150, 150],
                );
                c.text(
                    x0 as i64 + 6,
                    (y0 + h / 2) as i64 + 8,
                    "NOT BUILT YET",
                    scale,
                    [150, 150, 150],
                );
            }
        }
        // The largest letters that fit the tile's width, the name shortened ("suggestive" for
        // "suggestive-contours") rather than printed below twice the small size.
        let full = format!("{} {}", t.def.number, t.def.name);
        let short = full.replace("suggestive-contours", "suggestive");
        let fits = |l: &str, s: i64| Canvas::text_width(l, s) as usize <= w;
        let (label, scale) = (2..=scale)
            .rev()
            .flat_map(|s| [(full.clone(), s), (short.clone(), s)])
            .find(|(l, s)| fits(l, *s))
            .unwrap_or((full, 1));
        c.text(
            x0 as i64,
            (y0 + h + PAD / 2) as i64,
            &label,
            scale,
            [235, 235, 235],
        );
    }
    Ok((c, tiles))
}

/// Mean saliency of a frame's picture (over `background`) inside and outside its focus.
pub fn focus_saliency(
    frame: &vellum_render::render::targets::FrameImage,
    background: [f32; 3],
) -> Result<(f64, f64)> {
    let layers = frame.layers.as_ref().ok_or_else(|| {
        Error::Invalid("saliency against the focus needs a two-level frame".into())
    })?;
    let [w, h] = frame.size.map(|s| s as usize);
    let rgb: Vec<[f32; 3]> = to_rgb8(&frame.composite, background)
        .chunks(3)
        .map(|p| [p[0], p[1], p[2]].map(|c| c as f32 / 255.0))
        .collect();
    let map = vellum_render::imaging::saliency::saliency(&rgb, w, h);
    let mask: Vec<bool> = layers.focus_depth.iter().map(|d| d.is_finite()).collect();
    Ok(vellum_render::imaging::saliency::inside_outside(
        &map, &mask,
    ))
}
