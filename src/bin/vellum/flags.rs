//! The flag groups and value parsers that both the commands (`args.rs`) and the scene flags
//! (`scene_args.rs`) use: how to read a headerless input, the style and modulation flags, and the
//! parsers of sizes, colours, focus intervals and line smoothing.

use anyhow::Result;
use clap::Args;
use vellum::classify::Focus;
use vellum::render::overrides::{ModulationOverrides, StyleOverrides};
use vellum::render::style::LineSmooth;
use vellum::volume::io::RawSpec;
use vellum::volume::VoxelType;

/// How to read a headerless input.
#[derive(Args, Clone, Default)]
pub(crate) struct RawArgs {
    /// Raw input: dims as X,Y,Z.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    pub(crate) raw_dims: Option<String>,
    /// Raw input: voxel type.
    #[arg(long, value_name = "u8|u16|i16|f32")]
    pub(crate) raw_type: Option<String>,
    /// Raw input: multi-byte voxels are big-endian.
    #[arg(long)]
    pub(crate) big_endian: bool,
    /// Raw input: bytes to skip before the voxels.
    #[arg(long, value_name = "BYTES", default_value_t = 0)]
    pub(crate) offset: u64,
    /// Raw input: voxel spacing as SX,SY,SZ (millimetres) [default: 1,1,1].
    #[arg(long, value_name = "SX,SY,SZ", allow_hyphen_values = true)]
    pub(crate) raw_spacing: Option<String>,
    /// Raw input: the position of voxel (0,0,0) in LPS millimetres, as X,Y,Z; the volume is then
    /// taken as axis-aligned in LPS.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    pub(crate) raw_origin: Option<String>,
}

/// A perceptual style (SPEC TL4–TL7) and its parameters: each flag overrides the scene file's value.
#[derive(Args, Clone, Default)]
pub(crate) struct StyleArgs {
    /// A style of the two-level paper, by number (1-15) or name (e.g. 2 or dog; see `vellum styles`).
    #[arg(long, value_name = "N|NAME")]
    pub(crate) style: Option<String>,
    /// Edge colour as R,G,B in 0..1 [default: 0,0,0].
    #[arg(long, value_name = "R,G,B", allow_hyphen_values = true)]
    pub(crate) edge_color: Option<String>,
    /// Edge opacity in [0, 1] [default: 1].
    #[arg(long, allow_negative_numbers = true)]
    pub(crate) edge_opacity: Option<f32>,
    /// Edge width in pixels [default: 1].
    #[arg(long)]
    pub(crate) edge_width: Option<u32>,
    /// Threshold of the style's edge detector, in [0, 1]: Sobel's on the gradient magnitude
    /// [0.08], DoG's ε [0.005], Canny's high threshold [0.1].
    #[arg(long, allow_negative_numbers = true)]
    pub(crate) edge_threshold: Option<f32>,
    /// σ in pixels of the DoG's narrow Gaussian or Canny's smoothing [default: 1].
    #[arg(long, allow_negative_numbers = true)]
    pub(crate) sigma: Option<f32>,
    /// Ratio of the DoG's wide σ [default: 1.6].
    #[arg(long, allow_negative_numbers = true)]
    pub(crate) dog_k: Option<f32>,
    /// Kuwahara radius in pixels [default: 4].
    #[arg(long, allow_negative_numbers = true)]
    pub(crate) kuwahara_radius: Option<i64>,
    /// Saturation factor of the context for style 14 [default: 0.2].
    #[arg(long, allow_negative_numbers = true)]
    pub(crate) saturation: Option<f32>,
    /// Object-space lines (styles 4-12): θ_c in degrees; suggestive contours closer than this to
    /// facing the viewer are dropped [default: 20].
    #[arg(long, allow_negative_numbers = true)]
    pub(crate) line_angle: Option<f32>,
    /// Object-space lines: the least D_w κ_r of a suggestive contour, per mm² [default: 0.0001].
    #[arg(long, allow_negative_numbers = true)]
    pub(crate) line_threshold: Option<f32>,
    /// Object-space lines: how far behind the focus surface, in voxels, a line still shows [default: 1.5].
    #[arg(long, allow_negative_numbers = true)]
    pub(crate) line_bias: Option<f32>,
    /// Object-space lines: visit every Nth cell (1 all; 2 the interactive mode) [default: 1].
    #[arg(long)]
    pub(crate) line_stride: Option<u32>,
    /// Object-space lines: smooth the volume first with a Gaussian of this radius in voxels
    /// (σ = R/3; 0 none), against speckle of suggestive contours on measured data; auto smooths
    /// quantised data (radius 1 or 2 by the quantisation step against the surfaces' gradient)
    /// and leaves float data alone [default: auto].
    #[arg(long, value_name = "auto|R", value_parser = parse_line_smooth)]
    pub(crate) line_smooth: Option<LineSmooth>,
    /// Object-space lines by the seeded traversal (Burns et al.): followed from a sparse grid of
    /// seeds for a bounded number of rounds, the viewer's interactive mode.
    #[arg(long)]
    pub(crate) line_seeded: bool,
}

impl StyleArgs {
    /// The flags read as values; [`StyleOverrides::apply`] puts them over the scene's style.
    pub(crate) fn overrides(&self) -> Result<StyleOverrides> {
        Ok(StyleOverrides {
            style: self.style.clone(),
            edge_color: self
                .edge_color
                .as_deref()
                .map(|c| parse_rgb("--edge-color", c))
                .transpose()?,
            edge_opacity: self.edge_opacity,
            edge_width: self.edge_width,
            edge_threshold: self.edge_threshold,
            sigma: self.sigma,
            dog_k: self.dog_k,
            kuwahara_radius: self.kuwahara_radius,
            saturation: self.saturation,
            line_angle: self.line_angle,
            line_threshold: self.line_threshold,
            line_bias: self.line_bias,
            line_stride: self.line_stride,
            line_smooth: self.line_smooth,
            line_seeded: self.line_seeded,
        })
    }
}

/// Importance modulation (SPEC IM3–IM5): each flag overrides the scene file's value.
#[derive(Args, Clone, Default)]
pub(crate) struct ModulationArgs {
    /// Colour modulation: raw ΔD (eq. 3) or |ΔD| (eq. 4); needs --gamma.
    #[arg(long, value_name = "raw|abs")]
    pub(crate) color_mod: Option<String>,
    /// γ of colour modulation, per normalised-intensity unit of ΔD (may be negative).
    #[arg(long, value_name = "G", allow_negative_numbers = true)]
    pub(crate) gamma: Option<f32>,
    /// Opacity modulation (eq. 5): t_l, t_h, k_l, k_h.
    #[arg(long, value_name = "TL,TH,KL,KH", allow_hyphen_values = true)]
    pub(crate) opacity_mod: Option<String>,
    /// Stippling (eq. 6): threshold t in [0, 1] and density factor f >= 0.
    #[arg(long, value_name = "T,F", allow_hyphen_values = true)]
    pub(crate) stipple: Option<String>,
    /// Seed of the stipple pattern [default: 0].
    #[arg(long)]
    pub(crate) seed: Option<u32>,
    /// The stipple colours as R,G,B in 0..1 [defaults: white 1,1,1 and black 0,0,0].
    #[arg(long, value_name = "R,G,B", allow_hyphen_values = true)]
    pub(crate) stipple_white: Option<String>,
    #[arg(long, value_name = "R,G,B", allow_hyphen_values = true)]
    pub(crate) stipple_black: Option<String>,
    /// Radius R of the importance map's Gaussian, in voxels [default: 10].
    #[arg(long, value_name = "R")]
    pub(crate) importance_radius: Option<u32>,
    /// Which level is modulated [default: both].
    #[arg(long, value_name = "focus|context|both")]
    pub(crate) modulate: Option<String>,
    /// What colour modulation adds to: the unlit colour or the Phong-lit one [default: phong].
    #[arg(long, value_name = "ambient|phong")]
    pub(crate) modulate_lighting: Option<String>,
}

impl ModulationArgs {
    /// The flags read as values; [`ModulationOverrides::apply`] puts them over the scene's.
    pub(crate) fn overrides(&self) -> Result<ModulationOverrides> {
        let floats = |v: &Option<String>, flag: &str, n: usize, what: &str| {
            v.as_deref()
                .map(|s| parse_floats(s, flag, n, what))
                .transpose()
        };
        let rgb =
            |v: &Option<String>, flag: &str| v.as_deref().map(|c| parse_rgb(flag, c)).transpose();
        let opacity = floats(
            &self.opacity_mod,
            "--opacity-mod",
            4,
            "TL,TH,KL,KH (t_l, t_h, k_l, k_h)",
        )?;
        let stipple = floats(
            &self.stipple,
            "--stipple",
            2,
            "T,F (threshold t and factor f)",
        )?;
        Ok(ModulationOverrides {
            color_mod: self.color_mod.clone(),
            gamma: self.gamma,
            opacity_mod: opacity.map(|v| [v[0], v[1], v[2], v[3]]),
            stipple: stipple.map(|v| [v[0], v[1]]),
            seed: self.seed,
            stipple_white: rgb(&self.stipple_white, "--stipple-white")?,
            stipple_black: rgb(&self.stipple_black, "--stipple-black")?,
            importance_radius: self.importance_radius,
            modulate: self.modulate.clone(),
            modulate_lighting: self.modulate_lighting.clone(),
        })
    }
}

/// Parses `n` comma-separated finite numbers for `flag`.
pub(crate) fn parse_floats(s: &str, flag: &str, n: usize, what: &str) -> Result<Vec<f32>> {
    let v: Vec<f32> = s
        .split(',')
        .map(|c| c.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|_| anyhow::anyhow!("{flag} '{s}' is not {n} numbers {what}"))?;
    anyhow::ensure!(
        v.len() == n,
        "{flag} '{s}' has {} value(s); expected {n}: {what}",
        v.len()
    );
    anyhow::ensure!(
        v.iter().all(|x| x.is_finite()),
        "{flag} '{s}' must be finite numbers"
    );
    Ok(v)
}

impl RawArgs {
    pub(crate) fn spec(&self) -> Result<Option<RawSpec>> {
        match (&self.raw_dims, &self.raw_type) {
            (None, None) if self.raw_spacing.is_some() || self.raw_origin.is_some() => {
                anyhow::bail!("--raw-spacing and --raw-origin need a raw input: --raw-dims X,Y,Z and --raw-type")
            }
            (None, None) => Ok(None),
            (Some(d), Some(t)) => {
                let dims: Vec<usize> = d
                    .split(',')
                    .map(|s| s.trim().parse::<usize>())
                    .collect::<Result<_, _>>()
                    .ok()
                    .filter(|v: &Vec<usize>| v.len() == 3)
                    .ok_or_else(|| {
                        anyhow::anyhow!(
                            "--raw-dims '{d}' is not three whole numbers like 256,256,128"
                        )
                    })?;
                Ok(Some(RawSpec {
                    dims: [dims[0], dims[1], dims[2]],
                    voxel_type: VoxelType::parse(t)?,
                    big_endian: self.big_endian,
                    offset: self.offset,
                    spacing: match &self.raw_spacing {
                        Some(sp) => {
                            let v =
                                parse_floats(sp, "--raw-spacing", 3, "SX,SY,SZ in millimetres")?;
                            anyhow::ensure!(
                                v.iter().all(|x| *x > 0.0),
                                "--raw-spacing '{sp}' must be three positive numbers"
                            );
                            [v[0] as f64, v[1] as f64, v[2] as f64]
                        }
                        None => [1.0; 3],
                    },
                }))
            }
            _ => {
                anyhow::bail!("raw input needs both --raw-dims X,Y,Z and --raw-type u8|u16|i16|f32")
            }
        }
    }
}

impl RawArgs {
    /// The origin given with --raw-origin, as LPS geometry.
    pub(crate) fn origin(&self) -> Result<Option<[f64; 3]>> {
        self.raw_origin
            .as_deref()
            .map(|o| {
                let v = parse_floats(o, "--raw-origin", 3, "X,Y,Z in LPS millimetres")?;
                Ok([v[0] as f64, v[1] as f64, v[2] as f64])
            })
            .transpose()
    }
}

pub(crate) fn parse_size(s: &str) -> Result<[u32; 2]> {
    s.split_once(['x', 'X'])
        .and_then(|(w, h)| Some([w.trim().parse().ok()?, h.trim().parse().ok()?]))
        .filter(|[w, h]: &[u32; 2]| *w > 0 && *h > 0)
        .ok_or_else(|| {
            anyhow::anyhow!(
                "--size '{s}' is not WIDTHxHEIGHT in whole pixels of 1 or more, like 512x512"
            )
        })
}

pub(crate) fn parse_rgb(flag: &str, s: &str) -> Result<[f32; 3]> {
    let v: Vec<f32> = s.split(',').filter_map(|c| c.trim().parse().ok()).collect();
    anyhow::ensure!(
        v.len() == 3 && v.iter().all(|c| (0.0..=1.0).contains(c)),
        "{flag} '{s}' is not R,G,B with each in 0..1"
    );
    Ok([v[0], v[1], v[2]])
}

/// Parses `--focus LO:HI` or `--iso V` (data units).
pub(crate) fn parse_focus(range: Option<&str>, iso: Option<f64>) -> Result<Focus> {
    match (range, iso) {
        (Some(_), Some(_)) => anyhow::bail!("give either --focus LO:HI or --iso V, not both"),
        (None, Some(v)) => {
            anyhow::ensure!(v.is_finite(), "--iso needs a finite value");
            Ok(Focus::Iso(v))
        }
        (Some(r), None) => {
            let [lo, hi] = parse_interval(r).map_err(|_| {
                anyhow::anyhow!(
                    "--focus '{r}' is not an interval LO:HI of data values with LO <= HI"
                )
            })?;
            Ok(Focus::Range { lo, hi })
        }
        (None, None) => Ok(Focus::None),
    }
}

pub(crate) fn parse_interval(s: &str) -> Result<[f64; 2]> {
    s.split_once(':')
        .and_then(|(a, b)| Some([a.trim().parse().ok()?, b.trim().parse().ok()?]))
        .filter(|[a, b]: &[f64; 2]| a <= b)
        .ok_or_else(|| anyhow::anyhow!("interval '{s}' is not LO:HI in data units with LO <= HI"))
}

/// `--line-smooth auto|R`.
pub(crate) fn parse_line_smooth(s: &str) -> std::result::Result<LineSmooth, String> {
    LineSmooth::parse(s).map_err(|e| e.to_string())
}
