//! The `vellum` command line. It parses arguments, calls the library and writes results; the work
//! itself lives in the library.

mod features;

use anyhow::{Context as _, Result};
use clap::{Args, Parser, Subcommand};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use vellum::classify::modulation::Modulation;
use vellum::classify::Focus;
use vellum::gpu::{Context, ContextDesc};
use vellum::render::scene::{ClassificationSpec, GpuScene, InputSpec, RawInput, Scene};
use vellum::volume::io::RawSpec;
use vellum::volume::{Volume, VoxelType};

#[derive(Parser)]
#[command(
    name = "vellum",
    version,
    about = "Illustrative volume rendering on Vulkan"
)]
struct Cli {
    /// Vulkan device: index or part of its name (also VELLUM_DEVICE).
    #[arg(long, global = true)]
    device: Option<String>,
    /// Log more (-v info, -vv debug).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

/// An input volume: a path, a DICOM folder or a phantom spec, with raw-file options.
#[derive(Args, Clone)]
struct InputArgs {
    /// File, DICOM folder, or phantom spec (phantom:shepp-logan:N, phantom:nested:N).
    input: String,
    #[command(flatten)]
    raw: RawArgs,
}

/// How to read a headerless input.
#[derive(Args, Clone)]
struct RawArgs {
    /// Raw input: dims as X,Y,Z.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    raw_dims: Option<String>,
    /// Raw input: voxel type.
    #[arg(long, value_name = "u8|u16|i16|f32")]
    raw_type: Option<String>,
    /// Raw input: multi-byte voxels are big-endian.
    #[arg(long)]
    big_endian: bool,
    /// Raw input: bytes to skip before the voxels.
    #[arg(long, value_name = "BYTES", default_value_t = 0)]
    offset: u64,
    /// Raw input: voxel spacing as SX,SY,SZ (millimetres) [default: 1,1,1].
    #[arg(long, value_name = "SX,SY,SZ", allow_hyphen_values = true)]
    raw_spacing: Option<String>,
    /// Raw input: the position of voxel (0,0,0) in LPS millimetres, as X,Y,Z; the volume is then
    /// taken as axis-aligned in LPS.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
    raw_origin: Option<String>,
}

#[derive(Subcommand)]
enum Command {
    /// List Vulkan devices and mark the one vellum would use.
    Devices {
        #[arg(long)]
        json: bool,
    },
    /// Dims, voxel type, spacing, range, mean and a 16-bin histogram of a volume.
    Info {
        #[command(flatten)]
        input: InputArgs,
        #[arg(long)]
        json: bool,
    },
    /// Convert a volume to NRRD (gzip).
    Convert {
        #[command(flatten)]
        input: InputArgs,
        /// Output volume: .nrrd, .nii or .nii.gz (the extension picks the format).
        output: PathBuf,
    },
    /// Upload a volume to a 3D image on the GPU, read it back and check it is bit-exact.
    Roundtrip {
        #[command(flatten)]
        input: InputArgs,
        #[arg(long)]
        json: bool,
    },
    /// The spatial importance map ΔD = G∗V − V (paper eq. 1).
    Importance {
        #[command(flatten)]
        input: InputArgs,
        /// Gaussian radius R in voxels (σ = R/3).
        #[arg(long, default_value_t = 5)]
        radius: u32,
        /// Write ΔD as a float volume (.nrrd, .nii or .nii.gz).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Write the three middle slices as a thermal PNG.
        #[arg(long)]
        slices: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
    /// Render a volume with 3D-texture slicing, in two levels (focus, context) or one pass.
    Render(Box<RenderArgs>),
    /// Object-space lines (silhouettes, suggestive contours) of the focus surface, drawn into the
    /// two-level frame (PNG) and written as vector paths of their visible parts (SVG).
    Lines(Box<LinesArgs>),
    /// Ambient-occlusion volume and occlusion spectrum (SPEC OS1-OS3).
    Occlusion {
        #[command(flatten)]
        input: InputArgs,
        /// Neighbourhood radius R in voxels.
        #[arg(long, default_value_t = 16)]
        radius: u32,
        /// Visibility mapping: ramp, truncated:T0,T1 (fractions of the data range), gaussian, tf:FILE.json.
        #[arg(long, default_value = "ramp")]
        mapping: String,
        /// Output resolution: one occlusion voxel per STRIDE³ input voxels (exact at the voxel it samples).
        #[arg(long, default_value_t = 1)]
        stride: u32,
        /// Write the occlusion volume as a float volume (.nrrd, .nii or .nii.gz).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Write the spectrum as a log-scaled PNG with axes.
        #[arg(long)]
        spectrum: Option<PathBuf>,
        /// Write the spectrum as CSV.
        #[arg(long)]
        spectrum_data: Option<PathBuf>,
        /// Spectrum bins along intensity and occlusion.
        #[arg(long, default_value_t = 256)]
        bins: u32,
        /// How the neighbourhood sum is computed: auto (a measured cost model), runs (direct sums on the GPU), fft-gpu or fft-cpu (FFT convolution, a cost that does not grow with the radius).
        #[arg(long, default_value = "auto")]
        method: String,
        #[arg(long)]
        json: bool,
    },
    /// Adaptive mapping selection (SPEC OS6): the truncated ramp that best separates an interval.
    OcclusionSelect {
        #[command(flatten)]
        input: InputArgs,
        /// Intensity interval of interest, in data units.
        #[arg(long, value_name = "LO:HI", allow_hyphen_values = true)]
        interval: String,
        #[arg(long, default_value_t = 16)]
        radius: u32,
        #[arg(long, default_value_t = 1)]
        stride: u32,
        /// How the neighbourhood sum is computed: auto (a measured cost model), runs (direct sums on the GPU), fft-gpu or fft-cpu (FFT convolution, a cost that does not grow with the radius).
        #[arg(long, default_value = "auto")]
        method: String,
        #[arg(long)]
        json: bool,
    },
    /// Variance of occlusion per intensity band against the radius (SPEC OS7).
    OcclusionSensitivity {
        #[command(flatten)]
        input: InputArgs,
        /// Radii in voxels.
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "4,8,16,32,64",
            allow_hyphen_values = true
        )]
        radii: Vec<u32>,
        /// Intensity bands.
        #[arg(long, default_value_t = 8)]
        bands: usize,
        /// Output stride; 0 picks 1 when an FFT method serves the largest radius, else the largest radius / 16 (at least 1).
        #[arg(long, default_value_t = 0)]
        stride: u32,
        /// How the neighbourhood sum is computed: auto (a measured cost model), runs (direct sums on the GPU), fft-gpu or fft-cpu (FFT convolution, a cost that does not grow with the radius).
        #[arg(long, default_value = "auto")]
        method: String,

        /// The plot (PNG).
        #[arg(long)]
        out: PathBuf,
        /// The data (CSV).
        #[arg(long)]
        csv: Option<PathBuf>,
    },
    /// Migrate a segmented feature into a private density interval (feature maps, SPEC FM1-FM5).
    Migrate(features::MigrateArgs),
    /// Print the tree of a feature map (features.json).
    Features(features::FeaturesArgs),
    /// Every style of the two-level paper on one volume: a labelled contact sheet (its Fig. 11).
    Styles(Box<StylesArgs>),
    /// Open a window on a volume (the built-in phantom when none is given) or a scene file: orbit,
    /// edit the transfer function over the histogram, pick styles, save scenes and screenshots.
    View(Box<ViewArgs>),
    /// The Itti-Koch-Niebur saliency map of an image, and its mean inside and outside a mask.
    Saliency {
        /// A PNG image.
        image: PathBuf,
        /// A PNG of the same size: non-black pixels are inside.
        #[arg(long)]
        mask: Option<PathBuf>,
        /// Write the saliency map as a PNG.
        #[arg(long)]
        out: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
    /// The papers' figures, rendered again as labelled contact sheets.
    Figures {
        #[command(subcommand)]
        which: FiguresCommand,
    },
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        which: BenchCommand,
    },
}

/// `vellum render`: a scene from flags, a scene file, or a scene file overridden by flags.
#[derive(Args, Clone)]
struct RenderArgs {
    /// File, DICOM folder, or phantom spec; overrides the scene file's input.
    input: Option<String>,
    #[command(flatten)]
    raw: RawArgs,
    /// A scene file (JSON); every flag given on the command line overrides its value.
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Write the scene that this command line describes to a JSON file.
    #[arg(long)]
    save_scene: Option<PathBuf>,
    /// Transfer function: a preset (grey, ct-bone, ct-skin-bone, mri-brain) or a JSON file [default: grey].
    #[arg(long)]
    tf: Option<String>,
    /// Focus: an interval of data values LO:HI.
    #[arg(long, value_name = "LO:HI", allow_hyphen_values = true)]
    focus: Option<String>,
    /// Focus: an isovalue in data units (an opaque surface).
    #[arg(long, value_name = "V", allow_negative_numbers = true)]
    iso: Option<f64>,
    /// Camera: azimuth and elevation in degrees (in LPS for an oriented volume: 0,0 is the anterior
    /// view), distance in bounding-sphere radii. Default: anterior for an oriented volume, else
    /// 30,20; without DIST the volume's projected bounding box fills the image.
    #[arg(long, value_name = "AZ,EL[,DIST]", allow_hyphen_values = true)]
    camera: Option<String>,
    /// A named view of an oriented volume: anterior, posterior, left, right, superior, inferior.
    #[arg(long, value_name = "NAME")]
    view: Option<String>,
    /// Orthographic instead of perspective projection.
    #[arg(long)]
    ortho: bool,
    /// Pan the view: X,Y in bounding-sphere radii (x right, y up).
    #[arg(long, value_name = "X,Y", allow_hyphen_values = true)]
    pan: Option<String>,
    /// Image size [default: 512x512].
    #[arg(long, value_name = "WxH", allow_hyphen_values = true)]
    size: Option<String>,
    /// Number of slice planes (default: two per voxel along the longest axis).
    #[arg(long)]
    slices: Option<u32>,
    /// The classic single pass instead of two levels.
    #[arg(long)]
    one_pass: bool,
    /// Renderer: view-aligned slicing, or ray casting at the same planes (same layers and styles).
    #[arg(long, value_name = "slicer|raycast")]
    renderer: Option<String>,
    /// Ray caster: jitter the sample planes per pixel with this seed (default: no jitter).
    #[arg(long, value_name = "SEED")]
    jitter: Option<u32>,
    /// Ray caster: stop a ray once its opacity reaches this, in (0, 1] [default: 0.99].
    #[arg(long, value_name = "A")]
    ert: Option<f32>,
    /// Ray caster: do not skip empty bricks.
    #[arg(long)]
    no_skip_empty: bool,
    /// Ray caster with --iso: refine the surface hit between planes (exact depth, no rings).
    #[arg(long)]
    refine_iso: bool,
    /// Ray caster: samples on the slicer's planes (default) or equal steps along each ray.
    #[arg(long, value_name = "planes|world-steps")]
    sampling: Option<String>,
    /// Background colour behind the volume in the PNG, as R,G,B in 0..1 [default: 0,0,0].
    #[arg(long, allow_hyphen_values = true)]
    background: Option<String>,
    /// Occlusion transfer function (JSON): colour and opacity over (intensity, occlusion).
    #[arg(long, conflicts_with = "tf")]
    otf: Option<PathBuf>,
    /// A feature map (features.json from `vellum migrate`): each feature gets its colour (FM6).
    #[arg(long, conflicts_with_all = ["otf", "tf"])]
    features: Option<PathBuf>,
    #[command(flatten)]
    modulation: ModulationArgs,
    #[command(flatten)]
    style: StyleArgs,
    /// Output PNG (required unless only --save-scene is asked for).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write the layers as float channels to this OpenEXR file.
    #[arg(long)]
    exr: Option<PathBuf>,
    #[arg(long)]
    json: bool,
}

/// `vellum lines`: the render flags, a kind of line, and the SVG.
#[derive(Args)]
struct LinesArgs {
    #[command(flatten)]
    render: RenderArgs,
    /// Which lines: silhouettes, suggestive (contours) or both.
    #[arg(long, default_value = "both")]
    kind: String,
    /// Write the visible segments as SVG paths (pixel coordinates of the PNG).
    #[arg(long)]
    svg: Option<PathBuf>,
}

/// `vellum view`: the windowed viewer.
#[derive(Args)]
struct ViewArgs {
    /// File, DICOM folder, or phantom spec [default: phantom:shepp-logan:128]; overrides the scene
    /// file's input.
    input: Option<String>,
    /// A scene file (JSON), as `render --scene` reads and the viewer saves.
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Transfer function: a preset (grey, ct-bone, ct-skin-bone, mri-brain) or a JSON file.
    #[arg(long)]
    tf: Option<String>,
    /// Focus: an interval of data values LO:HI.
    #[arg(long, value_name = "LO:HI", allow_hyphen_values = true)]
    focus: Option<String>,
    /// Focus: an isovalue in data units.
    #[arg(long, value_name = "V", allow_negative_numbers = true)]
    iso: Option<f64>,
    /// Window size [default: 1100x700].
    #[arg(long, value_name = "WxH")]
    size: Option<String>,
    /// Folder for screenshots (key S): vellum-0001.png, ... [default: the current folder].
    #[arg(long, value_name = "DIR")]
    screenshot_dir: Option<PathBuf>,
    /// Write a screenshot of the volume view to this PNG when the window closes.
    #[arg(long, value_name = "PNG")]
    screenshot_on_exit: Option<PathBuf>,
    /// Present without waiting for vertical blank (MAILBOX or IMMEDIATE where offered).
    #[arg(long)]
    no_vsync: bool,
    /// Renderer: slicer or raycast [default: the scene file's; without one, raycast with jitter].
    #[arg(long, value_name = "slicer|raycast")]
    renderer: Option<String>,
    /// Orbit N frames as a user's drag does (adaptive quality: half resolution while the camera
    /// moves), print the frame rate and frame-time percentiles, and close.
    #[arg(long, value_name = "N")]
    bench: Option<u32>,
    /// With --bench: orbit at full resolution instead.
    #[arg(long)]
    bench_full: bool,
    /// With --bench: print the report as JSON.
    #[arg(long)]
    json: bool,
}

/// `vellum styles`: the gallery of the 15 styles.
#[derive(Args)]
struct StylesArgs {
    #[command(flatten)]
    input: InputArgs,
    /// Transfer function: a preset or a JSON file.
    #[arg(long, default_value = "grey")]
    tf: String,
    /// Focus: an interval of data values LO:HI.
    #[arg(long, value_name = "LO:HI", allow_hyphen_values = true)]
    focus: Option<String>,
    /// Focus: an isovalue in data units (an opaque surface).
    #[arg(long, value_name = "V", allow_negative_numbers = true)]
    iso: Option<f64>,
    /// Camera: azimuth and elevation in degrees, distance in bounding-sphere radii.
    #[arg(
        long,
        value_name = "AZ,EL[,DIST]",
        default_value = "30,20,2.5",
        allow_hyphen_values = true
    )]
    camera: String,
    /// Size of each tile.
    #[arg(
        long,
        value_name = "WxH",
        default_value = "256x256",
        allow_hyphen_values = true
    )]
    size: String,
    /// Background colour as R,G,B in 0..1.
    #[arg(long, default_value = "0,0,0", allow_hyphen_values = true)]
    background: String,
    /// Colour of the edges and lines of every style, as R,G,B in 0..1 [default: 0,0,0].
    #[arg(long, value_name = "R,G,B", allow_hyphen_values = true)]
    edge_color: Option<String>,
    /// Object-space lines (styles 4-12): smooth the volume first with a Gaussian of this radius in
    /// voxels (σ = R/3; 0 none) [default: 0].
    #[arg(long, value_name = "R")]
    line_smooth: Option<u32>,
    /// The contact sheet (PNG).
    #[arg(long)]
    out: PathBuf,
    /// Also write each style as its own PNG into this folder.
    #[arg(long)]
    out_dir: Option<PathBuf>,
    /// With --out-dir, also write each style's layers as OpenEXR.
    #[arg(long, requires = "out_dir")]
    exr: bool,
    /// Report each style's mean saliency inside the focus against outside it.
    #[arg(long)]
    saliency: bool,
    #[arg(long)]
    json: bool,
    /// Renderer of every style: slicer (default) or raycast (the same layers, so the same styles).
    #[arg(long, value_name = "slicer|raycast")]
    renderer: Option<String>,
}

/// A perceptual style (SPEC TL4–TL7) and its parameters: each flag overrides the scene file's value.
#[derive(Args, Clone, Default)]
struct StyleArgs {
    /// A style of the two-level paper, by number (1-15) or name (e.g. 2 or dog; see `vellum styles`).
    #[arg(long, value_name = "N|NAME")]
    style: Option<String>,
    /// Edge colour as R,G,B in 0..1 [default: 0,0,0].
    #[arg(long, value_name = "R,G,B", allow_hyphen_values = true)]
    edge_color: Option<String>,
    /// Edge opacity in [0, 1] [default: 1].
    #[arg(long, allow_negative_numbers = true)]
    edge_opacity: Option<f32>,
    /// Edge width in pixels [default: 1].
    #[arg(long)]
    edge_width: Option<u32>,
    /// Threshold of the style's edge detector, in [0, 1]: Sobel's on the gradient magnitude
    /// [0.08], DoG's ε [0.005], Canny's high threshold [0.1].
    #[arg(long, allow_negative_numbers = true)]
    edge_threshold: Option<f32>,
    /// σ in pixels of the DoG's narrow Gaussian or Canny's smoothing [default: 1].
    #[arg(long, allow_negative_numbers = true)]
    sigma: Option<f32>,
    /// Ratio of the DoG's wide σ [default: 1.6].
    #[arg(long, allow_negative_numbers = true)]
    dog_k: Option<f32>,
    /// Kuwahara radius in pixels [default: 4].
    #[arg(long, allow_negative_numbers = true)]
    kuwahara_radius: Option<i64>,
    /// Saturation factor of the context for style 14 [default: 0.2].
    #[arg(long, allow_negative_numbers = true)]
    saturation: Option<f32>,
    /// Object-space lines (styles 4-12): θ_c in degrees; suggestive contours closer than this to
    /// facing the viewer are dropped [default: 20].
    #[arg(long, allow_negative_numbers = true)]
    line_angle: Option<f32>,
    /// Object-space lines: the least D_w κ_r of a suggestive contour, per mm² [default: 0.0001].
    #[arg(long, allow_negative_numbers = true)]
    line_threshold: Option<f32>,
    /// Object-space lines: how far behind the focus surface, in voxels, a line still shows [default: 1.5].
    #[arg(long, allow_negative_numbers = true)]
    line_bias: Option<f32>,
    /// Object-space lines: visit every Nth cell (1 all; 2 the interactive mode) [default: 1].
    #[arg(long)]
    line_stride: Option<u32>,
    /// Object-space lines: smooth the volume first with a Gaussian of this radius in voxels
    /// (σ = R/3; 0 none), against speckle of suggestive contours on measured data [default: 0].
    #[arg(long)]
    line_smooth: Option<u32>,
    /// Object-space lines by the seeded traversal (Burns et al.): followed from a sparse grid of
    /// seeds for a bounded number of rounds, the viewer's interactive mode.
    #[arg(long)]
    line_seeded: bool,
}

impl StyleArgs {
    /// Applies the flags over the scene file's style, if any.
    fn apply(
        &self,
        spec: Option<vellum::render::scene::StyleSpec>,
    ) -> Result<Option<vellum::render::scene::StyleSpec>> {
        use vellum::render::style::StyleDef;
        let params_given = self.edge_color.is_some()
            || self.edge_opacity.is_some()
            || self.edge_width.is_some()
            || self.edge_threshold.is_some()
            || self.sigma.is_some()
            || self.dog_k.is_some()
            || self.kuwahara_radius.is_some()
            || self.saturation.is_some()
            || self.line_angle.is_some()
            || self.line_threshold.is_some()
            || self.line_bias.is_some()
            || self.line_stride.is_some()
            || self.line_seeded
            || self.line_smooth.is_some();
        let mut spec = match (&self.style, spec) {
            (Some(s), old) => vellum::render::scene::StyleSpec {
                style: serde_json::Value::String(s.clone()),
                params: old.map(|o| o.params).unwrap_or_default(),
            },
            // Checked with the scene file's name when the view is made.
            (None, Some(old)) if !params_given => return Ok(Some(old)),
            (None, Some(old)) => old,
            (None, None) if params_given => {
                anyhow::bail!("the style flags need --style N|NAME")
            }
            (None, None) => return Ok(None),
        };
        let p = &mut spec.params;
        if let Some(c) = &self.edge_color {
            p.edge_color = parse_rgb("--edge-color", c)?;
        }
        if let Some(v) = self.edge_opacity {
            p.edge_opacity = v;
        }
        if let Some(v) = self.edge_width {
            p.edge_width = v;
        }
        let name = match &spec.style {
            serde_json::Value::String(s) => s.clone(),
            other => other.to_string(),
        };
        let def = StyleDef::find(&name)?;
        if let Some(t) = self.edge_threshold {
            use vellum::render::style::EdgeKind;
            match def.edges {
                Some(EdgeKind::Sobel) => p.sobel_threshold = t,
                Some(EdgeKind::Dog) => p.dog_threshold = t,
                Some(EdgeKind::Canny) => p.canny_high = t,
                None => anyhow::bail!(
                    "--edge-threshold has no effect on style {} ({}), which draws no image-space edges",
                    def.number,
                    def.name
                ),
            }
        }
        if let Some(v) = self.sigma {
            p.dog_sigma = v;
            p.canny_sigma = v;
        }
        if let Some(v) = self.dog_k {
            p.dog_k = v;
        }
        if let Some(r) = self.kuwahara_radius {
            anyhow::ensure!(
                (1..=16).contains(&r),
                "Kuwahara radius {r} is invalid; expected 1..=16 pixels"
            );
            p.kuwahara_radius = r as u32;
        }
        if let Some(v) = self.saturation {
            p.saturation = v;
        }
        if let Some(v) = self.line_angle {
            p.line_angle = v;
        }
        if let Some(v) = self.line_threshold {
            p.line_derivative_threshold = v;
        }
        if let Some(v) = self.line_bias {
            p.line_depth_bias = v;
        }
        if let Some(v) = self.line_stride {
            p.line_stride = v;
        }
        if let Some(v) = self.line_smooth {
            p.line_smooth = v;
        }
        if self.line_seeded {
            p.line_seeded = true;
        }
        spec.resolve()?;
        Ok(Some(spec))
    }
}

/// Importance modulation (SPEC IM3–IM5): each flag overrides the scene file's value.
#[derive(Args, Clone, Default)]
struct ModulationArgs {
    /// Colour modulation: raw ΔD (eq. 3) or |ΔD| (eq. 4); needs --gamma.
    #[arg(long, value_name = "raw|abs")]
    color_mod: Option<String>,
    /// γ of colour modulation, per normalised-intensity unit of ΔD (may be negative).
    #[arg(long, value_name = "G", allow_negative_numbers = true)]
    gamma: Option<f32>,
    /// Opacity modulation (eq. 5): t_l, t_h, k_l, k_h.
    #[arg(long, value_name = "TL,TH,KL,KH", allow_hyphen_values = true)]
    opacity_mod: Option<String>,
    /// Stippling (eq. 6): threshold t in [0, 1] and density factor f >= 0.
    #[arg(long, value_name = "T,F", allow_hyphen_values = true)]
    stipple: Option<String>,
    /// Seed of the stipple pattern [default: 0].
    #[arg(long)]
    seed: Option<u32>,
    /// The stipple colours as R,G,B in 0..1 [defaults: white 1,1,1 and black 0,0,0].
    #[arg(long, value_name = "R,G,B", allow_hyphen_values = true)]
    stipple_white: Option<String>,
    #[arg(long, value_name = "R,G,B", allow_hyphen_values = true)]
    stipple_black: Option<String>,
    /// Radius R of the importance map's Gaussian, in voxels [default: 10].
    #[arg(long, value_name = "R")]
    importance_radius: Option<u32>,
    /// Which level is modulated [default: both].
    #[arg(long, value_name = "focus|context|both")]
    modulate: Option<String>,
    /// What colour modulation adds to: the unlit colour or the Phong-lit one [default: phong].
    #[arg(long, value_name = "ambient|phong")]
    modulate_lighting: Option<String>,
}

impl ModulationArgs {
    /// Applies the flags over `m` (the scene file's modulation, or none).
    fn apply(&self, m: Option<Modulation>) -> Result<Option<Modulation>> {
        use vellum::classify::modulation::{
            ApplyTo, ColorMode, ColorModulation, ModulateLighting, OpacityModulation, Stipple,
        };
        let given = self.color_mod.is_some()
            || self.gamma.is_some()
            || self.opacity_mod.is_some()
            || self.stipple.is_some()
            || self.seed.is_some()
            || self.stipple_white.is_some()
            || self.stipple_black.is_some()
            || self.importance_radius.is_some()
            || self.modulate.is_some()
            || self.modulate_lighting.is_some();
        if !given {
            return Ok(m);
        }
        let mut m = m.unwrap_or_default();
        match (&self.color_mod, self.gamma) {
            (Some(mode), Some(gamma)) => {
                let mode = match mode.as_str() {
                    "raw" => ColorMode::Raw,
                    "abs" => ColorMode::Abs,
                    other => anyhow::bail!("--color-mod '{other}' is unknown; expected raw or abs"),
                };
                m.color = Some(ColorModulation { mode, gamma });
            }
            (Some(_), None) => anyhow::bail!("--color-mod needs --gamma G"),
            (None, Some(gamma)) => match &mut m.color {
                Some(c) => c.gamma = gamma,
                None => anyhow::bail!("--gamma needs --color-mod raw|abs"),
            },
            (None, None) => {}
        }
        if let Some(o) = &self.opacity_mod {
            let v = parse_floats(o, "--opacity-mod", 4, "TL,TH,KL,KH (t_l, t_h, k_l, k_h)")?;
            m.opacity = Some(OpacityModulation {
                t_low: v[0],
                t_high: v[1],
                k_low: v[2],
                k_high: v[3],
            });
        }
        if let Some(st) = &self.stipple {
            let v = parse_floats(st, "--stipple", 2, "T,F (threshold t and factor f)")?;
            let old = m.stipple;
            m.stipple = Some(Stipple {
                t: v[0],
                f: v[1],
                seed: old.map_or(0, |s| s.seed),
                white: old.map_or([1.0; 3], |s| s.white),
                black: old.map_or([0.0; 3], |s| s.black),
            });
        }
        let stipple_only = |flag: &str| anyhow::anyhow!("{flag} needs --stipple T,F");
        if let Some(seed) = self.seed {
            m.stipple
                .as_mut()
                .ok_or_else(|| stipple_only("--seed"))?
                .seed = seed;
        }
        if let Some(c) = &self.stipple_white {
            m.stipple
                .as_mut()
                .ok_or_else(|| stipple_only("--stipple-white"))?
                .white = parse_rgb("--stipple-white", c)?;
        }
        if let Some(c) = &self.stipple_black {
            m.stipple
                .as_mut()
                .ok_or_else(|| stipple_only("--stipple-black"))?
                .black = parse_rgb("--stipple-black", c)?;
        }
        if let Some(r) = self.importance_radius {
            m.importance_radius = r;
        }
        if let Some(a) = &self.modulate {
            m.apply_to = match a.as_str() {
                "focus" => ApplyTo::Focus,
                "context" => ApplyTo::Context,
                "both" => ApplyTo::Both,
                other => anyhow::bail!(
                    "--modulate '{other}' is unknown; expected focus, context or both"
                ),
            };
        }
        if let Some(l) = &self.modulate_lighting {
            m.lighting = match l.as_str() {
                "ambient" => ModulateLighting::Ambient,
                "phong" => ModulateLighting::Phong,
                other => anyhow::bail!(
                    "--modulate-lighting '{other}' is unknown; expected ambient or phong"
                ),
            };
        }
        anyhow::ensure!(
            m.is_active(),
            "the modulation flags need an effect: --color-mod with --gamma, --opacity-mod or --stipple"
        );
        m.validate()?;
        Ok(Some(m))
    }
}

/// Parses `n` comma-separated finite numbers for `flag`.
fn parse_floats(s: &str, flag: &str, n: usize, what: &str) -> Result<Vec<f32>> {
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

#[derive(Subcommand)]
enum FiguresCommand {
    /// The importance paper's Figures 3–9 (colour and opacity modulation, stippling) on the CT body
    /// and the CT head.
    Importance {
        /// Folder for the PNG sheets (created if missing).
        #[arg(long)]
        out_dir: PathBuf,
        /// Tile size in pixels.
        #[arg(long, default_value_t = 320)]
        size: u32,
    },
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Frame rate of every style the build can render, with each style pass's GPU time (paper Fig. 9).
    Styles {
        #[arg(long)]
        json: bool,
        /// Frames per style; each figure is the median.
        #[arg(long, default_value_t = 5)]
        repeat: usize,
        /// Square image sizes in pixels.
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "256,512,1024",
            allow_hyphen_values = true
        )]
        sizes: Vec<u32>,
        /// What draws the levels under the styles: slicer (default) or raycast (the viewer's).
        #[arg(long, default_value = "slicer", value_parser = ["slicer", "raycast"])]
        renderer: String,
    },
    /// Frames per second of the slice renderer, one pass against two levels (paper Fig. 9).
    Render {
        #[arg(long)]
        json: bool,
        /// Frames per case; each figure is the median.
        #[arg(long, default_value_t = 3)]
        repeat: usize,
        /// Square image sizes in pixels.
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "256,512,1024",
            allow_hyphen_values = true
        )]
        sizes: Vec<u32>,
        /// Frames of the orbit (10° a frame).
        #[arg(long, default_value_t = 36)]
        orbit_frames: usize,
        /// Also render the CT head with a peer, VTK's GPU ray caster (benches/vtk_peer.py, needs
        /// `pip install vtk`), on the same orbit, and report the ratios.
        #[arg(long, value_name = "vtk")]
        peer: Option<String>,
    },
    /// Object-space line extraction per kind, full and interactive (every other cell), on the
    /// GPU pass and the CPU reference, with segment counts.
    Lines {
        #[arg(long)]
        json: bool,
        /// A volume or phantom spec [default: the CT head from ../shared/data, and a 128³ torus].
        input: Option<String>,
        /// The isovalue for INPUT, in data units.
        #[arg(long, allow_negative_numbers = true)]
        iso: Option<f64>,
        /// Resample every volume trilinearly to N³ first (the paper's scale is 512).
        #[arg(long, value_name = "N")]
        resample: Option<usize>,
    },
    /// Ambient occlusion against the radius for each method (ms, the cost model's estimate, memory),
    /// the crossover radius, and scipy's FFT convolution as a peer.
    Occlusion {
        #[arg(long)]
        json: bool,
        /// A volume or phantom spec [default: the bonsai, 256³, from ../shared/data].
        input: Option<String>,
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "4,8,16,32,64,100",
            allow_hyphen_values = true
        )]
        radii: Vec<u32>,
        #[arg(long, value_delimiter = ',', default_value = "runs,fft-gpu,fft-cpu")]
        methods: Vec<String>,
        /// Skip a method whose estimated time exceeds this (its estimate is reported instead).
        #[arg(long, default_value_t = 150.0)]
        max_seconds: f64,
        /// Peer: scipy (scipy.signal.fftconvolve, benches/ao_peer.py).
        #[arg(long, value_name = "scipy")]
        peer: Option<String>,
    },
    /// The importance paper's Table 1: per-pass and total times for three volume sizes and R ∈ {1,5,10}.
    Table1 {
        #[arg(long)]
        json: bool,
        /// Runs per case; each figure is the median.
        #[arg(long, default_value_t = 3)]
        repeat: usize,
        /// Skip the scipy.ndimage peer.
        #[arg(long)]
        no_scipy: bool,
        /// Only these cases (e.g. "ct-body:1,salmon:10"); default all nine.
        #[arg(long, allow_hyphen_values = true)]
        cases: Option<String>,
    },
}

impl RawArgs {
    fn spec(&self) -> Result<Option<RawSpec>> {
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
    fn origin(&self) -> Result<Option<[f64; 3]>> {
        self.raw_origin
            .as_deref()
            .map(|o| {
                let v = parse_floats(o, "--raw-origin", 3, "X,Y,Z in LPS millimetres")?;
                Ok([v[0] as f64, v[1] as f64, v[2] as f64])
            })
            .transpose()
    }
}

impl InputArgs {
    fn load(&self) -> Result<Volume> {
        let raw = self.raw.spec()?;
        if let Some(o) = self.raw.origin()? {
            let v = vellum::input::load(&self.input, raw.as_ref())?;
            let g = vellum::volume::geometry::Geometry::lps(o, vellum::volume::geometry::IDENTITY)?;
            return Ok(v.with_geometry(g)?);
        }
        Ok(vellum::input::load(&self.input, raw.as_ref())?)
    }
}

fn context(cli: &Cli) -> Result<Arc<Context>> {
    Ok(Context::new(&ContextDesc {
        validation: None,
        device: cli.device.clone(),
    })?)
}

/// Says on stderr if the validation layer complained (the messages themselves are at -vv).
fn report_validation(ctx: &Context) {
    ctx.report_validation();
}

#[cfg(unix)]
unsafe extern "C" {
    fn signal(signum: i32, handler: usize) -> usize;
}

/// Lets every option take a negative number as its value (`--focus -2000:-500`, `--radius -5`),
/// so that a negative value is parsed, and refused with a sentence where it makes no sense,
/// instead of being taken for an unknown flag. List-valued options also set
/// `allow_hyphen_values` where they are declared.
fn negatives(cmd: clap::Command) -> clap::Command {
    cmd.mut_args(|a| {
        if a.get_action().takes_values() && !a.is_positional() {
            a.allow_negative_numbers(true)
        } else {
            a
        }
    })
    .mut_subcommands(negatives)
}

/// The command line, parsed; a negative value for a whole-number option gets a sentence.
fn parse_cli() -> Cli {
    use clap::error::{ContextKind, ContextValue, ErrorKind};
    use clap::{CommandFactory, FromArgMatches};
    let parsed = negatives(Cli::command())
        .try_get_matches()
        .and_then(|m| Cli::from_arg_matches(&m));
    match parsed {
        Ok(cli) => cli,
        Err(e) => {
            let text = |k| match e.get(k) {
                Some(ContextValue::String(s)) => Some(s.clone()),
                _ => None,
            };
            let unsigned = std::error::Error::source(&e).is_some_and(|s| {
                let s = s.to_string();
                s.contains("invalid digit") || s.contains("is not in 0..")
            });
            if let (ErrorKind::ValueValidation, Some(arg), Some(value), true) = (
                e.kind(),
                text(ContextKind::InvalidArg),
                text(ContextKind::InvalidValue),
                unsigned,
            ) {
                if value.starts_with('-') {
                    let name = arg.split_whitespace().next().unwrap_or(&arg);
                    eprintln!("error: {name} is {value}; expected a whole number of zero or more");
                    std::process::exit(2);
                }
            }
            e.exit()
        }
    }
}

fn main() -> ExitCode {
    // Rust ignores SIGPIPE, which turns `vellum info x | head` into a panic in println!. Restore
    // the default so the CLI ends quietly like other Unix tools (13 = SIGPIPE, 0 = SIG_DFL).
    #[cfg(unix)]
    // SAFETY: setting a signal disposition to its default before any threads start.
    unsafe {
        signal(13, 0);
    }
    let cli = parse_cli();
    let level = match cli.verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or(level))
        .format_timestamp(None)
        .init();
    // Ctrl-C or SIGTERM removes the command's temporary files; nothing partial stays behind.
    if let Err(e) = ctrlc::set_handler(|| {
        vellum::output::remove_pending();
        std::process::exit(130);
    }) {
        log::warn!("no Ctrl-C handler: {e}");
    }
    // Every output of the command, or none (see output.rs).
    vellum::output::begin();
    let result = run(&cli).and_then(|()| Ok(vellum::output::commit()?));
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            vellum::output::abort();
            eprintln!("error: {}", vellum::error::one_line(&format!("{e:#}")));
            ExitCode::FAILURE
        }
    }
}

/// The output files a command will write, as given.
fn output_paths(command: &Command) -> Vec<&Path> {
    fn all<'a>(v: &[&'a Option<PathBuf>]) -> Vec<&'a Path> {
        v.iter().filter_map(|p| p.as_deref()).collect()
    }
    match command {
        Command::Convert { output, .. } => vec![output.as_path()],
        Command::Importance { out, slices, .. } => all(&[out, slices]),
        Command::Render(a) => all(&[&a.out, &a.exr, &a.save_scene]),
        Command::Lines(a) => all(&[&a.render.out, &a.render.exr, &a.svg]),
        Command::Occlusion {
            out,
            spectrum,
            spectrum_data,
            ..
        } => all(&[out, spectrum, spectrum_data]),
        Command::OcclusionSensitivity { out, csv, .. } => {
            let mut v = all(&[csv]);
            v.push(out.as_path());
            v
        }
        Command::Migrate(a) => a.outputs(),
        Command::Saliency { out, .. } => all(&[out]),
        Command::Styles(a) => vec![a.out.as_path()],
        _ => vec![],
    }
}

/// Refuses two outputs of one command at the same path, before any work is done.
fn check_distinct_outputs(command: &Command) -> Result<()> {
    let paths = output_paths(command);
    for (i, a) in paths.iter().enumerate() {
        let key = |p: &Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
        if paths[..i].iter().any(|b| key(b) == key(a)) {
            anyhow::bail!(
                "{} is given for two outputs of one command; expected a separate path for each",
                a.display()
            );
        }
    }
    Ok(())
}

fn run(cli: &Cli) -> Result<()> {
    ContextDesc::check_environment()?;
    check_distinct_outputs(&cli.command)?;
    match &cli.command {
        Command::Devices { json } => devices(cli, *json),
        Command::Info { input, json } => info(input, *json),
        Command::Convert { input, output } => {
            let v = input.load()?;
            vellum::volume::io::write(output, &v)?;
            println!(
                "wrote {} ({}x{}x{} {})",
                output.display(),
                v.dims[0],
                v.dims[1],
                v.dims[2],
                v.voxel_type().name()
            );
            Ok(())
        }
        Command::Roundtrip { input, json } => roundtrip(cli, input, *json),
        Command::Importance {
            input,
            radius,
            out,
            slices,
            json,
        } => importance(
            cli,
            input,
            *radius,
            out.as_deref(),
            slices.as_deref(),
            *json,
        ),
        Command::Render(args) => render(cli, args),
        Command::Lines(args) => lines(cli, args),
        Command::Bench {
            which:
                BenchCommand::Render {
                    json,
                    repeat,
                    sizes,
                    orbit_frames,
                    peer,
                },
        } => {
            let ctx = context(cli)?;
            let opts = vellum::bench::render::Options {
                repeat: (*repeat).max(1),
                sizes: sizes.clone(),
                orbit_frames: (*orbit_frames).max(1),
                raycast: false,
            };
            if let Some(other) = peer.as_deref().filter(|p| *p != "vtk") {
                anyhow::bail!("--peer {other:?} is unknown; expected vtk");
            }
            let mut table = vellum::bench::render::run(&ctx, &opts)?;
            if peer.is_some() {
                table.peer = Some(vellum::bench::render::vtk_peer(
                    &ctx,
                    &opts.sizes,
                    opts.orbit_frames,
                )?);
            }
            report_validation(&ctx);
            print_report(*json, &table, || {
                table.to_text() + &table.peer.as_ref().map(|p| p.to_text()).unwrap_or_default()
            })
        }
        Command::Occlusion {
            input,
            radius,
            mapping,
            stride,
            out,
            spectrum,
            spectrum_data,
            bins,
            method,
            json,
        } => occlusion(
            cli,
            input,
            *radius,
            mapping,
            *stride,
            out.as_deref(),
            spectrum.as_deref(),
            spectrum_data.as_deref(),
            *bins,
            method,
            *json,
        ),
        Command::OcclusionSelect {
            input,
            interval,
            radius,
            stride,
            method,
            json,
        } => occlusion_select(cli, input, interval, *radius, *stride, method, *json),
        Command::OcclusionSensitivity {
            input,
            radii,
            bands,
            stride,
            method,
            out,
            csv,
        } => occlusion_sensitivity(
            cli,
            input,
            radii,
            *bands,
            *stride,
            method,
            out,
            csv.as_deref(),
        ),
        Command::Styles(args) => styles(cli, args),
        Command::View(args) => view(cli, args),
        Command::Bench {
            which:
                BenchCommand::Styles {
                    json,
                    repeat,
                    sizes,
                    renderer,
                },
        } => {
            let ctx = context(cli)?;
            let opts = vellum::bench::render::Options {
                repeat: (*repeat).max(1),
                sizes: sizes.clone(),
                orbit_frames: 0,
                raycast: renderer == "raycast",
            };
            let table = vellum::bench::render::run_styles(&ctx, &opts)?;
            report_validation(&ctx);
            print_report(*json, &table, || table.to_text())
        }
        Command::Saliency {
            image,
            mask,
            out,
            json,
        } => saliency(image, mask.as_deref(), out.as_deref(), *json),
        Command::Figures {
            which: FiguresCommand::Importance { out_dir, size },
        } => {
            let ctx = context(cli)?;
            let files = vellum::figures::importance(&ctx, out_dir, *size)?;
            report_validation(&ctx);
            for f in files {
                println!("wrote {}", f.display());
            }
            Ok(())
        }
        Command::Migrate(args) => features::migrate(args),
        Command::Features(args) => features::print_tree(args),
        Command::Bench {
            which:
                BenchCommand::Lines {
                    json,
                    input,
                    iso,
                    resample,
                },
        } => {
            let input = match (input, iso) {
                (Some(i), Some(v)) => Some((i.clone(), *v)),
                (None, None) => None,
                _ => anyhow::bail!("bench lines takes an input and --iso V together"),
            };
            if let Some(n) = resample {
                anyhow::ensure!(
                    (2..=1024).contains(n),
                    "--resample {n} is invalid; expected 2..=1024 voxels per side"
                );
            }
            let ctx = context(cli)?;
            let table = vellum::bench::lines::run(
                &ctx,
                &vellum::bench::lines::Options {
                    input,
                    resample: *resample,
                },
            )?;
            report_validation(&ctx);
            print_report(*json, &table, || table.to_text())
        }
        Command::Bench {
            which:
                BenchCommand::Occlusion {
                    json,
                    input,
                    radii,
                    methods,
                    max_seconds,
                    peer,
                },
        } => {
            use vellum::passes::occlusion::{check_radius_stride, Method};
            if let Some(other) = peer.as_deref().filter(|p| *p != "scipy") {
                anyhow::bail!("--peer {other:?} is unknown; expected scipy");
            }
            for &r in radii {
                check_radius_stride(r, 1)?;
            }
            let methods = methods
                .iter()
                .map(|m| match Method::parse(m)? {
                    Method::Auto => Err(anyhow::anyhow!(
                        "--methods takes runs, fft-gpu and fft-cpu; auto picks among them"
                    )),
                    m => Ok(m),
                })
                .collect::<Result<Vec<_>>>()?;
            anyhow::ensure!(
                max_seconds.is_finite() && *max_seconds > 0.0,
                "--max-seconds {max_seconds} is invalid; expected a positive number"
            );
            let ctx = context(cli)?;
            let opts = vellum::bench::occlusion::Options {
                input: input.clone(),
                radii: radii.clone(),
                methods,
                max_seconds: *max_seconds,
                scipy: peer.is_some(),
            };
            let table = vellum::bench::occlusion::run(&ctx, &opts)?;
            report_validation(&ctx);
            print_report(*json, &table, || table.to_text())
        }
        Command::Bench {
            which:
                BenchCommand::Table1 {
                    json,
                    repeat,
                    no_scipy,
                    cases,
                },
        } => {
            let ctx = context(cli)?;
            let opts = vellum::bench::table1::Options {
                repeat: (*repeat).max(1),
                scipy: !no_scipy,
                cases: cases.clone(),
            };
            let table = vellum::bench::table1::run(&ctx, &opts)?;
            report_validation(&ctx);
            print_report(*json, &table, || table.to_text())
        }
    }
}

fn devices(cli: &Cli, json: bool) -> Result<()> {
    let (candidates, chosen) = vellum::gpu::context::probe_devices(&ContextDesc {
        validation: Some(false),
        device: cli.device.clone(),
    })?;
    let selector = ContextDesc {
        validation: None,
        device: cli.device.clone(),
    }
    .device_selector();
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({ "devices": candidates, "chosen": chosen }))?
        );
        if chosen.is_none() {
            anyhow::bail!(
                "no device matches{}; the listing above gives each device's reason",
                selector.map_or(String::new(), |s| format!(" the selector {s:?}"))
            );
        }
        return Ok(());
    }
    for c in &candidates {
        let mark = if Some(c.index) == chosen { "*" } else { " " };
        println!(
            "{mark} [{}] {} ({}, Vulkan {}, driver {})",
            c.index, c.name, c.device_type, c.api_version, c.driver
        );
        if let Some(r) = &c.rejected {
            println!("      rejected: {r}");
        }
    }
    if chosen.is_none() {
        match selector {
            Some(s) => anyhow::bail!(
                "no device matches the selector {s:?}; expected an index or part of a name from the list above"
            ),
            None => anyhow::bail!("no listed device can be used (see the reasons above)"),
        }
    }
    Ok(())
}

fn info(input: &InputArgs, json: bool) -> Result<()> {
    let v = input.load()?;
    let s = vellum::volume::stats::stats(&v, 16);
    if json {
        let out = json!({
            "input": input.input, "dims": v.dims, "voxel_type": v.voxel_type(), "spacing": v.spacing,
            "origin": v.geometry.origin, "direction": v.geometry.direction,
            "orientation": v.geometry.orientation_code(), "space": v.geometry.space,
            "min": s.min, "max": s.max, "mean": s.mean, "histogram": s.histogram, "sha256": v.sha256_hex(),
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!("input:   {}", input.input);
    println!(
        "dims:    {} x {} x {} ({} voxels)",
        v.dims[0],
        v.dims[1],
        v.dims[2],
        v.len()
    );
    println!("type:    {}", v.voxel_type().name());
    println!(
        "spacing: {} x {} x {}",
        v.spacing[0], v.spacing[1], v.spacing[2]
    );
    let g = &v.geometry;
    println!(
        "origin:  {} {} {} (LPS, mm)",
        g.origin[0], g.origin[1], g.origin[2]
    );
    for (r, row) in g.direction.iter().enumerate() {
        println!(
            "{}{:>10.6} {:>10.6} {:>10.6}",
            if r == 0 { "direction: " } else { "           " },
            row[0],
            row[1],
            row[2]
        );
    }
    println!("orientation: {}", g.orientation_code());
    println!("range:   {} .. {}", s.min, s.max);
    println!("mean:    {:.4}", s.mean);
    println!("sha256:  {}", v.sha256_hex());
    println!("histogram (16 bins over the range):");
    let peak = s.histogram.iter().copied().max().unwrap_or(1).max(1);
    let width = (s.max - s.min) / 16.0;
    for (i, &c) in s.histogram.iter().enumerate() {
        let bar = "#".repeat(((c as f64 / peak as f64) * 40.0).ceil() as usize);
        println!("  {:>12.3} {:>10}  {bar}", s.min + i as f64 * width, c);
    }
    Ok(())
}

fn roundtrip(cli: &Cli, input: &InputArgs, json: bool) -> Result<()> {
    let v = input.load()?;
    let ctx = context(cli)?;
    let r = vellum::passes::volume_image::round_trip(&ctx, &v)?;
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({ "device": ctx.info.name, "round_trip": r }))?
        );
    } else {
        let ms = |n: &str| vellum::gpu::profiler::total_ms(&r.passes, n);
        println!(
            "GPU round trip on {}: {} bytes, upload {:.2} ms, readback {:.2} ms, {}",
            ctx.info.name,
            r.bytes,
            ms("upload"),
            ms("readback"),
            if r.bit_exact { "bit-exact" } else { "MISMATCH" }
        );
    }
    report_validation(&ctx);
    anyhow::ensure!(
        r.bit_exact,
        "the volume read back from the GPU differs from what was uploaded"
    );
    Ok(())
}

fn importance(
    cli: &Cli,
    input: &InputArgs,
    radius: u32,
    out: Option<&std::path::Path>,
    slices: Option<&std::path::Path>,
    json: bool,
) -> Result<()> {
    let v = input.load()?;
    let ctx = context(cli)?;
    let map = vellum::passes::importance::ImportanceMap::new(&ctx)?;
    let r = map.compute(&v, radius, false)?;
    report_validation(&ctx);
    if let Some(path) = out {
        vellum::volume::io::write(path, &r.delta_d)
            .with_context(|| format!("writing ΔD to {}", path.display()))?;
    }
    if let Some(path) = slices {
        let limit = vellum::volume::slices::abs_quantile(
            (0..r.delta_d.len()).map(|i| r.delta_d.data.get_f64(i)),
            0.995,
        );
        let (w, h, rgb) = vellum::volume::slices::thermal_slices(&r.delta_d, limit);
        vellum::output::write_png_rgb(path, w, h, &rgb)?;
    }
    let passes: serde_json::Map<String, serde_json::Value> = r
        .passes
        .iter()
        .map(|p| (p.name.clone(), json!(p.ms)))
        .collect();
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(
                &json!({ "device": ctx.info.name, "radius": radius, "dims": v.dims, "passes": passes, "total_ms": r.total_ms })
            )?
        );
    } else {
        let s = vellum::volume::stats::stats(&r.delta_d, 0);
        println!(
            "importance map of {} (R = {radius}) on {}",
            input.input, ctx.info.name
        );
        println!("  ΔD range {:.4} .. {:.4}", s.min, s.max);
        for p in &r.passes {
            println!("  {:<9} {:>9.3} ms", p.name, p.ms);
        }
        println!(
            "  total     {:>9.3} ms (conversion, allocation, upload, passes, readback)",
            r.total_ms
        );
    }
    Ok(())
}
fn parse_size(s: &str) -> Result<[u32; 2]> {
    s.split_once(['x', 'X'])
        .and_then(|(w, h)| Some([w.trim().parse().ok()?, h.trim().parse().ok()?]))
        .filter(|[w, h]: &[u32; 2]| *w > 0 && *h > 0)
        .ok_or_else(|| {
            anyhow::anyhow!(
                "--size '{s}' is not WIDTHxHEIGHT in whole pixels of 1 or more, like 512x512"
            )
        })
}

fn parse_rgb(flag: &str, s: &str) -> Result<[f32; 3]> {
    let v: Vec<f32> = s.split(',').filter_map(|c| c.trim().parse().ok()).collect();
    anyhow::ensure!(
        v.len() == 3 && v.iter().all(|c| (0.0..=1.0).contains(c)),
        "{flag} '{s}' is not R,G,B with each in 0..1"
    );
    Ok([v[0], v[1], v[2]])
}

/// Parses `--focus LO:HI` or `--iso V` (data units).
fn parse_focus(range: Option<&str>, iso: Option<f64>) -> Result<Focus> {
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

/// The scene a `render` command line describes: the scene file (or defaults) with every given
/// flag applied over it.
fn render_scene(a: &RenderArgs) -> Result<Scene> {
    let mut scene = match (&a.scene, &a.input) {
        (Some(path), _) => Scene::load(path)?,
        (None, Some(input)) => Scene::new(InputSpec {
            path: input.clone(),
            raw: None,
        }),
        (None, None) => anyhow::bail!(
            "render needs an input (a file, DICOM folder or phantom spec) or --scene FILE"
        ),
    };
    if let Some(input) = &a.input {
        scene.input = InputSpec {
            path: input.clone(),
            raw: None,
        };
    }
    if let Some(raw) = a.raw.spec()? {
        scene.input.raw = Some(RawInput {
            dims: raw.dims,
            voxel_type: raw.voxel_type.name().to_string(),
            big_endian: raw.big_endian,
            offset: raw.offset,
            spacing: raw.spacing,
            origin: a.raw.origin()?,
        });
    }
    let path_arg = |p: &std::path::Path| p.to_string_lossy().into_owned();
    if let Some(tf) = &a.tf {
        scene.classification = ClassificationSpec::Transfer(tf.clone());
    }
    if let Some(otf) = &a.otf {
        scene.classification = ClassificationSpec::Occlusion(path_arg(otf));
    }
    if let Some(f) = &a.features {
        scene.classification = ClassificationSpec::Features(path_arg(f));
    }
    if a.focus.is_some() || a.iso.is_some() {
        scene.focus = parse_focus(a.focus.as_deref(), a.iso)?;
    }
    if a.camera.is_some() && a.view.is_some() {
        anyhow::bail!("give either --camera AZ,EL[,DIST] or --view NAME, not both");
    }
    if let Some(c) = &a.camera {
        let parsed = vellum::render::camera::Camera::parse(c)?;
        scene.camera.view = None;
        scene.camera.azimuth = Some(parsed.azimuth_deg);
        scene.camera.elevation = Some(parsed.elevation_deg);
        // Without DIST the volume is framed.
        scene.camera.distance = (c.split(',').count() == 3).then_some(parsed.distance);
    }
    if let Some(v) = &a.view {
        scene.camera.view = Some(vellum::render::scene::NamedView::parse(v)?);
        scene.camera.azimuth = None;
        scene.camera.elevation = None;
    }
    if a.ortho {
        scene.camera.ortho = true;
    }
    if let Some(p) = &a.pan {
        let v: Vec<f32> = p.split(',').filter_map(|c| c.trim().parse().ok()).collect();
        anyhow::ensure!(
            v.len() == 2 && v.iter().all(|c| c.is_finite()),
            "--pan '{p}' is not X,Y in bounding-sphere radii"
        );
        scene.camera.pan = [v[0], v[1]];
    }
    if let Some(size) = &a.size {
        scene.size = parse_size(size)?;
    }
    if let Some(n) = a.slices {
        scene.slices = Some(n);
    }
    if a.one_pass {
        scene.one_pass = true;
    }
    match a.renderer.as_deref() {
        None => {}
        Some("slicer") => scene.raycast = None,
        Some("raycast") => scene.raycast = Some(scene.raycast.unwrap_or_default()),
        Some(other) => anyhow::bail!("--renderer {other:?} is unknown; expected slicer or raycast"),
    }
    let ray_flags = a.jitter.is_some()
        || a.ert.is_some()
        || a.no_skip_empty
        || a.refine_iso
        || a.sampling.is_some();
    match (&mut scene.raycast, ray_flags) {
        (Some(r), _) => {
            if let Some(seed) = a.jitter {
                r.jitter = Some(seed);
            }
            if let Some(ert) = a.ert {
                r.ert = ert;
            }
            if a.no_skip_empty {
                r.skip_empty = false;
            }
            if a.refine_iso {
                r.refine_iso = true;
            }
            if let Some(s) = &a.sampling {
                r.sampling = vellum::render::raycast::Sampling::parse(s)?;
            }
            r.validate()?;
        }
        (None, true) => anyhow::bail!(
            "--jitter, --ert, --no-skip-empty, --refine-iso and --sampling set the ray caster; add --renderer raycast"
        ),
        (None, false) => {}
    }
    if let Some(b) = &a.background {
        scene.background = parse_rgb("--background", b)?;
    }
    if scene.one_pass && matches!(scene.focus, Focus::Range { .. }) {
        anyhow::bail!(
            "--one-pass draws a single level, which a --focus LO:HI interval would not change; drop one of them (--iso V does work in one pass: it makes the surface opaque)"
        );
    }
    scene.modulation = a.modulation.apply(scene.modulation.take())?;
    scene.style = a.style.apply(scene.style.take())?;
    scene.validate()?;
    Ok(scene)
}

fn lines(cli: &Cli, a: &LinesArgs) -> Result<()> {
    use std::io::Write;
    use vellum::render::slicer::{to_rgb8, Renderer};
    let (style, both) = match a.kind.as_str() {
        "silhouettes" => ("silhouettes", false),
        "suggestive" => ("suggestive", false),
        "both" => ("silhouettes", true),
        k => anyhow::bail!("--kind {k:?} is unknown; expected silhouettes, suggestive or both"),
    };
    anyhow::ensure!(
        a.render.style.style.is_none(),
        "lines takes --kind, not --style; the style is the lines"
    );
    let out = a
        .render
        .out
        .as_deref()
        .ok_or_else(|| anyhow::anyhow!("lines needs --out image.png"))?;
    // The style flags (edge colour, width, line parameters) apply to the lines' style.
    let mut args = a.render.clone();
    args.style.style = Some(style.into());
    let mut scene = render_scene(&args)?;
    let mut params = scene.style.take().map(|s| s.params).unwrap_or_default();
    params.line_both = both;
    scene.style = Some(vellum::render::scene::StyleSpec {
        style: serde_json::Value::String(style.into()),
        params,
    });
    let classification = scene.classification()?;
    let v = scene.load_volume()?;
    let view = scene.view(v.geometry.is_oriented())?;
    let ctx = context(cli)?;
    let modulation = scene.modulation.clone().unwrap_or_default();
    let mut gpu = GpuScene::prepare(&ctx, &v, &classification, scene.focus, &modulation)?;
    let renderer = Renderer::new(&ctx)?;
    let frame = renderer.render_frame(&gpu.volume, &mut gpu.classify, &view, true)?;
    report_validation(&ctx);
    let (segments, found) = match renderer.line_buffer() {
        Some(b) => b.read()?,
        None => (Vec::new(), 0),
    };
    let raster = renderer
        .last_lines_view()
        .ok_or_else(|| anyhow::anyhow!("the frame drew no lines; give a focus with --iso V"))?;
    let depth = frame
        .layers
        .as_ref()
        .map(|l| l.focus_depth.clone())
        .ok_or_else(|| anyhow::anyhow!("lines need a two-level frame; drop --one-pass"))?;
    let [w, h] = frame.size;
    // Visible pieces per kind, in the PNG's pixel coordinates.
    let mut pieces: [Vec<Vec<[f32; 2]>>; 2] = [Vec::new(), Vec::new()];
    for seg in &segments {
        let k = (seg.kind() > 0.5) as usize;
        pieces[k].extend(raster.visible_pieces(seg, &depth, [w, h]));
    }
    vellum::output::write_png_rgb(out, w, h, &to_rgb8(&frame.composite, scene.background))?;
    if let Some(path) = &a.render.exr {
        frame.write_exr(path)?;
    }
    if let Some(path) = &a.svg {
        let colour = |c: [f32; 3]| {
            format!(
                "#{:02x}{:02x}{:02x}",
                (c[0] * 255.0) as u8,
                (c[1] * 255.0) as u8,
                (c[2] * 255.0) as u8
            )
        };
        let p = &scene.style.as_ref().map(|s| s.params).unwrap_or_default();
        vellum::output::write_atomic(path, |f| {
            writeln!(
                f,
                r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}">"#
            )?;
            writeln!(
                f,
                "<!-- vellum lines of {}: visible parts only -->",
                scene.input.path
            )?;
            for (k, name) in [(0, "silhouettes"), (1, "suggestive-contours")] {
                writeln!(
                    f,
                    r#"<g id="{name}" fill="none" stroke="{}" stroke-width="{}" stroke-linecap="round" stroke-linejoin="round">"#,
                    colour(p.edge_color),
                    p.edge_width
                )?;
                for piece in &pieces[k] {
                    let mut d = String::new();
                    for (i, q) in piece.iter().enumerate() {
                        d.push_str(&format!(
                            "{}{:.2} {:.2}",
                            if i == 0 { "M" } else { " L" },
                            q[0],
                            q[1]
                        ));
                    }
                    writeln!(f, r#"<path d="{d}"/>"#)?;
                }
                writeln!(f, "</g>")?;
            }
            writeln!(f, "</svg>")?;
            Ok(())
        })?;
    }
    let stored = segments.len() as u64;
    let report = json!({
        "device": ctx.info.name,
        "kind": a.kind,
        "segments_found": found,
        "segments_stored": stored,
        "overflowed": found > stored,
        "silhouette_segments": segments.iter().filter(|s| s.kind() < 0.5).count(),
        "suggestive_segments": segments.iter().filter(|s| s.kind() > 0.5).count(),
        "visible_paths": [pieces[0].len(), pieces[1].len()],
        "passes": frame.passes.iter().map(|p| (p.name.clone(), json!(p.ms))).collect::<serde_json::Map<_, _>>(),
    });
    if a.render.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "lines of {} ({w}x{h}) on {}: {found} segments ({} silhouette, {} suggestive), {} visible paths",
            scene.input.path,
            ctx.info.name,
            report["silhouette_segments"],
            report["suggestive_segments"],
            pieces[0].len() + pieces[1].len()
        );
        if found > stored {
            println!("  the buffer held {stored} of them; the rest were dropped");
        }
    }
    Ok(())
}

fn render(cli: &Cli, a: &RenderArgs) -> Result<()> {
    use vellum::render::slicer::{to_rgb8, Renderer};
    let scene = render_scene(a)?;
    if let Some(path) = &a.save_scene {
        scene.save(path)?;
        if a.out.is_none() {
            println!("wrote the scene to {}", path.display());
            return Ok(());
        }
    }
    let out = a.out.as_deref().ok_or_else(|| {
        anyhow::anyhow!("render needs --out image.png (or only --save-scene FILE)")
    })?;
    // Errors from what a scene file names say which file and which key they came from.
    let from = |key: &str, e: vellum::Error| match &a.scene {
        Some(p) => anyhow::anyhow!("scene file {}: {key}: {e}", p.display()),
        None => e.into(),
    };
    let classification = scene
        .classification()
        .map_err(|e| from("classification", e))?;
    let v = scene.load_volume().map_err(|e| from("input", e))?;
    let view = scene
        .view(v.geometry.is_oriented())
        .map_err(|e| from("style", e))?;
    let ctx = context(cli)?;
    let modulation = scene.modulation.clone().unwrap_or_default();
    let mut gpu = GpuScene::prepare(&ctx, &v, &classification, scene.focus, &modulation)?;
    let frame = Renderer::new(&ctx)?.render_frame(&gpu.volume, &mut gpu.classify, &view, true)?;
    report_validation(&ctx);
    let [w, h] = frame.size;
    vellum::output::write_png_rgb(out, w, h, &to_rgb8(&frame.composite, scene.background))?;
    if let Some(path) = &a.exr {
        frame.write_exr(path)?;
    }
    let passes: Vec<_> = gpu.passes.iter().chain(&frame.passes).collect();
    if a.json {
        let map: serde_json::Map<String, serde_json::Value> = passes
            .iter()
            .map(|p| (p.name.clone(), json!(p.ms)))
            .collect();
        println!(
            "{}",
            serde_json::to_string_pretty(
                &json!({ "device": ctx.info.name, "size": frame.size, "slices": frame.slices, "passes": map })
            )?
        );
    } else {
        println!(
            "rendered {} ({w}x{h}, {} slices) on {}",
            scene.input.path, frame.slices, ctx.info.name
        );
        for p in passes {
            println!("  {:<14} {:>9.3} ms", p.name, p.ms);
        }
    }
    Ok(())
}

fn view(cli: &Cli, a: &ViewArgs) -> Result<()> {
    let mut scene = match &a.scene {
        Some(path) => Scene::load(path)?,
        None => {
            let mut s = Scene::new(InputSpec {
                path: "phantom:shepp-logan:128".into(),
                raw: None,
            });
            // The window's default: the ray caster, the faster renderer (BENCHMARKS.md), with
            // jitter against slicing rings.
            s.raycast = Some(vellum::render::raycast::RayOptions {
                jitter: Some(1),
                ..Default::default()
            });
            s
        }
    };
    match a.renderer.as_deref() {
        None => {}
        Some("slicer") => scene.raycast = None,
        Some("raycast") if scene.raycast.is_none() => {
            scene.raycast = Some(vellum::render::raycast::RayOptions {
                jitter: Some(1),
                ..Default::default()
            });
        }
        Some("raycast") => {}
        Some(other) => {
            anyhow::bail!("--renderer {other:?} is unknown; expected slicer or raycast")
        }
    }
    if let Some(input) = &a.input {
        scene.input = InputSpec {
            path: input.clone(),
            raw: None,
        };
    }
    if let Some(tf) = &a.tf {
        scene.classification = ClassificationSpec::Transfer(tf.clone());
    }
    if a.focus.is_some() || a.iso.is_some() {
        scene.focus = parse_focus(a.focus.as_deref(), a.iso)?;
    }
    let window_size = match &a.size {
        Some(s) => parse_size(s)?,
        None => [1100, 700],
    };
    if let Some(0) = a.bench {
        anyhow::bail!("--bench 0 is invalid; expected a number of frames of 1 or more");
    }
    anyhow::ensure!(
        a.json <= a.bench.is_some(),
        "--json prints the report of --bench N; add --bench"
    );
    anyhow::ensure!(
        a.bench_full <= a.bench.is_some(),
        "--bench-full changes the orbit of --bench N; add --bench"
    );
    if let Some(p) = &a.screenshot_on_exit {
        vellum::output::check_extension(p, &["png"], "a PNG image")?;
    }
    let screenshot_dir = a
        .screenshot_dir
        .clone()
        .unwrap_or_else(|| PathBuf::from("."));
    anyhow::ensure!(
        screenshot_dir.is_dir(),
        "--screenshot-dir {} is not a folder; expected an existing folder",
        screenshot_dir.display()
    );
    // The viewer's files (screenshots, scenes) land when they are made, each atomically, not at
    // the end of the command: close the command's all-or-nothing transaction.
    vellum::output::commit()?;
    let report = vellum::viewer::run(vellum::viewer::ViewOptions {
        scene,
        device: cli.device.clone(),
        window_size,
        screenshot_dir,
        screenshot_on_exit: a.screenshot_on_exit.clone(),
        vsync: !a.no_vsync,
        bench_frames: a.bench.map(|n| n + 5),
        bench_full: a.bench_full,
    })?;
    if let Some(r) = report {
        if a.json {
            println!("{}", serde_json::to_string_pretty(&r)?);
        } else {
            println!(
                "{} at {}x{} ({} quality, rendered at {}x{}) on {}: {:.1} fps over {} frames; frame time p50 {:.2} ms, p95 {:.2} ms, p99 {:.2} ms",
                r.input, r.size[0], r.size[1], r.quality, r.render_size[0], r.render_size[1], r.device, r.fps, r.frames, r.p50_ms, r.p95_ms, r.p99_ms
            );
            for (name, ms) in &r.gpu_ms {
                println!("  {name:<14} {ms:>9.3} ms (median GPU)");
            }
        }
    }
    Ok(())
}

fn styles(cli: &Cli, a: &StylesArgs) -> Result<()> {
    use vellum::render::slicer::{Lighting, View};
    let focus = parse_focus(a.focus.as_deref(), a.iso)?;
    anyhow::ensure!(
        focus != Focus::None,
        "the styles work on a focus; give --iso V or --focus LO:HI"
    );
    let size = parse_size(&a.size)?;
    anyhow::ensure!(
        size.iter().all(|&s| (16..=2048).contains(&s)),
        "--size {}x{} is invalid; expected 16..=2048 pixels per side",
        size[0],
        size[1]
    );
    let background = parse_rgb("--background", &a.background)?;
    let tf = vellum::classify::transfer::TransferFunction::from_arg(&a.tf)?;
    let view = View {
        camera: vellum::render::camera::Camera::parse(&a.camera)?,
        size,
        slices: None,
        one_pass: false,
        lighting: Lighting::default(),
        style: None,
        fit: a.camera.split(',').count() == 2,
        raycast: match a.renderer.as_deref() {
            None | Some("slicer") => None,
            Some("raycast") => Some(vellum::render::raycast::RayOptions::default()),
            Some(other) => {
                anyhow::bail!("--renderer {other:?} is unknown; expected slicer or raycast")
            }
        },
    };
    let v = a.input.load()?;
    let ctx = context(cli)?;
    let mut scene = GpuScene::prepare(
        &ctx,
        &v,
        &vellum::classify::Classification::Transfer(tf),
        focus,
        &Modulation::default(),
    )?;
    let (sheet, tiles) = vellum::figures::style_gallery(
        &ctx,
        &mut scene,
        &view,
        {
            let mut p = vellum::render::style::StyleParams::default();
            if let Some(c) = &a.edge_color {
                p.edge_color = parse_rgb("--edge-color", c)?;
            }
            if let Some(r) = a.line_smooth {
                p.line_smooth = r;
                p.validate()?;
            }
            p
        },
        background,
        a.saliency,
    )?;
    report_validation(&ctx);
    // Everything is rendered; now the files.
    vellum::output::write_png_rgb(&a.out, sheet.width as u32, sheet.height as u32, &sheet.rgb)?;
    if let Some(dir) = &a.out_dir {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        for t in &tiles {
            if let Some(f) = &t.frame {
                let stem = format!("style{:02}_{}", t.def.number, t.def.name.replace('+', "_"));
                vellum::output::write_png_rgb(
                    &dir.join(format!("{stem}.png")),
                    size[0],
                    size[1],
                    &vellum::render::slicer::to_rgb8(&f.composite, background),
                )?;
                if a.exr {
                    f.write_exr(&dir.join(format!("{stem}.exr")))?;
                }
            }
        }
    }
    let baseline = tiles
        .iter()
        .find(|t| t.def.number == 15)
        .and_then(|t| t.saliency);
    let rows: Vec<serde_json::Value> = tiles
        .iter()
        .map(|t| {
            json!({
                "number": t.def.number, "name": t.def.name, "rendered": t.frame.is_some(),
                "reason": t.def.unavailable_reason(),
                "passes": t.frame.as_ref().map(|f| f.passes.iter().map(|p| (p.name.clone(), json!(p.ms))).collect::<serde_json::Map<_, _>>()),
                "saliency_focus": t.saliency.map(|s| s.0), "saliency_context": t.saliency.map(|s| s.1),
                "focus_share": t.saliency.map(|s| s.0 / (s.0 + s.1)),
            })
        })
        .collect();
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(
                &json!({ "device": ctx.info.name, "input": a.input.input, "styles": rows })
            )?
        );
        return Ok(());
    }
    println!(
        "styles of {} on {} written to {}",
        a.input.input,
        ctx.info.name,
        a.out.display()
    );
    for t in &tiles {
        match (&t.frame, t.saliency) {
            (None, _) => println!(
                "  {:>2} {:<34} not rendered: {}",
                t.def.number,
                t.def.name,
                t.def.unavailable_reason().unwrap_or_default()
            ),
            (Some(_), Some((i, o))) => {
                let share = i / (i + o);
                let vs = baseline.map_or(String::new(), |(bi, bo)| {
                    format!(" ({:+.3} against style 15)", share - bi / (bi + bo))
                });
                println!("  {:>2} {:<34} saliency focus {i:.4} context {o:.4} focus share {share:.3}{vs}", t.def.number, t.def.name);
            }
            (Some(_), None) => println!("  {:>2} {}", t.def.number, t.def.name),
        }
    }
    Ok(())
}

fn saliency(
    image: &std::path::Path,
    mask: Option<&std::path::Path>,
    out: Option<&std::path::Path>,
    json: bool,
) -> Result<()> {
    let img = image::open(image)
        .with_context(|| format!("reading the image {}", image.display()))?
        .to_rgb8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    anyhow::ensure!(
        w >= 16 && h >= 16,
        "{} is {w}x{h}; the saliency metric needs at least 16x16 pixels",
        image.display()
    );
    let rgb: Vec<[f32; 3]> = img
        .pixels()
        .map(|p| p.0.map(|c| c as f32 / 255.0))
        .collect();
    let map = vellum::imaging::saliency::saliency(&rgb, w, h);
    let inside = match mask {
        Some(m) => {
            let mimg = image::open(m)
                .with_context(|| format!("reading the mask {}", m.display()))?
                .to_rgb8();
            anyhow::ensure!(
                (mimg.width() as usize, mimg.height() as usize) == (w, h),
                "the mask {} is {}x{} but the image is {w}x{h}",
                m.display(),
                mimg.width(),
                mimg.height()
            );
            let mask: Vec<bool> = mimg.pixels().map(|p| p.0.iter().any(|&c| c > 0)).collect();
            Some(vellum::imaging::saliency::inside_outside(&map, &mask))
        }
        None => None,
    };
    if let Some(path) = out {
        let bytes: Vec<u8> = map
            .data
            .iter()
            .flat_map(|&v| vellum::plot::heat(v as f64))
            .collect();
        vellum::output::write_png_rgb(path, w as u32, h as u32, &bytes)?;
    }
    let (peak_at, _) = map
        .data
        .iter()
        .enumerate()
        .fold((0, f32::MIN), |b, (i, &v)| if v > b.1 { (i, v) } else { b });
    let peak = [peak_at % w, peak_at / w];
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({
                "image": image.display().to_string(), "size": [w, h], "most_salient": peak,
                "mean_inside": inside.map(|s| s.0), "mean_outside": inside.map(|s| s.1),
            }))?
        );
    } else {
        println!(
            "saliency of {} ({w}x{h}): most salient point at {}, {}",
            image.display(),
            peak[0],
            peak[1]
        );
        if let Some((i, o)) = inside {
            println!(
                "  mean inside the mask {i:.4}, outside {o:.4}, inside share {:.3}",
                i / (i + o)
            );
        }
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn occlusion(
    cli: &Cli,
    input: &InputArgs,
    radius: u32,
    mapping: &str,
    stride: u32,
    out: Option<&std::path::Path>,
    spectrum_png: Option<&std::path::Path>,
    spectrum_csv: Option<&std::path::Path>,
    bins: u32,
    method: &str,
    json: bool,
) -> Result<()> {
    use vellum::passes::occlusion::{parse_mapping, Method, Occlusion, OcclusionParams};
    let (visibility, neighbourhood) = parse_mapping(mapping)?;
    let method = Method::parse(method)?;
    let v = input.load()?;
    let ctx = context(cli)?;
    let want_spectrum = spectrum_png.is_some() || spectrum_csv.is_some() || json;
    let params = OcclusionParams {
        radius,
        visibility,
        neighbourhood,
        stride,
        spectrum_bins: want_spectrum.then_some([bins, bins]),
        method,
        pad: None,
    };
    let start = std::time::Instant::now();
    let r = Occlusion::new(&ctx)?.compute(&v, &params)?;
    let wall_ms = start.elapsed().as_secs_f64() * 1e3;
    report_validation(&ctx);
    if let Some(path) = out {
        vellum::volume::io::write(path, &r.occlusion)
            .with_context(|| format!("writing the occlusion volume to {}", path.display()))?;
    }
    if let Some(s) = &r.spectrum {
        let b = [s.bins[0] as usize, s.bins[1] as usize];
        if let Some(path) = spectrum_png {
            let c = vellum::plot::histogram_2d(
                &s.counts,
                b,
                "INTENSITY",
                s.intensity_range,
                "OCCLUSION",
                [0.0, 1.0],
            );
            vellum::output::write_png_rgb(path, c.width as u32, c.height as u32, &c.rgb)?;
        }
        if let Some(path) = spectrum_csv {
            s.write_csv(path)?;
        }
    }
    let stats = vellum::volume::stats::stats(&r.occlusion, 0);
    let passes: serde_json::Map<String, serde_json::Value> = r
        .passes
        .iter()
        .map(|p| (p.name.clone(), json!(p.ms)))
        .collect();
    if json {
        let out = json!({
            "device": ctx.info.name, "radius": radius, "mapping": mapping, "stride": stride, "dims": v.dims,
            "occlusion_dims": r.occlusion.dims, "occlusion_range": [stats.min, stats.max], "passes": passes, "total_ms": wall_ms,
            "method": r.method.name(),
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!(
            "occlusion of {} (R = {radius}, {mapping}, stride {stride}, method {}) on {}",
            input.input,
            r.method.name(),
            ctx.info.name
        );
        println!(
            "  occlusion {}x{}x{}, range {:.4} .. {:.4}",
            r.occlusion.dims[0], r.occlusion.dims[1], r.occlusion.dims[2], stats.min, stats.max
        );
        for p in &r.passes {
            println!("  {:<18} {:>10.3} ms", p.name, p.ms);
        }
        println!("  {:<18} {wall_ms:>10.3} ms", "total");
    }
    Ok(())
}

fn parse_interval(s: &str) -> Result<[f64; 2]> {
    s.split_once(':')
        .and_then(|(a, b)| Some([a.trim().parse().ok()?, b.trim().parse().ok()?]))
        .filter(|[a, b]: &[f64; 2]| a <= b)
        .ok_or_else(|| anyhow::anyhow!("interval '{s}' is not LO:HI in data units with LO <= HI"))
}

fn occlusion_select(
    cli: &Cli,
    input: &InputArgs,
    interval: &str,
    radius: u32,
    stride: u32,
    method: &str,
    json: bool,
) -> Result<()> {
    let interval = parse_interval(interval)?;
    let method = vellum::passes::occlusion::Method::parse(method)?;
    let v = input.load()?;
    let ctx = context(cli)?;
    let occ = vellum::passes::occlusion::Occlusion::new(&ctx)?;
    let start = std::time::Instant::now();
    let sel =
        vellum::passes::occlusion_analysis::select(&occ, &v, interval, radius, stride, method)?;
    report_validation(&ctx);
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(
                &json!({ "device": ctx.info.name, "selection": sel, "total_ms": start.elapsed().as_secs_f64() * 1e3 })
            )?
        );
        return Ok(());
    }
    let b = &sel.best;
    println!(
        "adaptive mapping for {}:{} ({} voxels, R = {radius}, stride {stride}) on {}",
        interval[0], interval[1], sel.voxels_in_interval, ctx.info.name
    );
    println!(
        "  best: --mapping truncated:{},{}  (data {:.1}..{:.1}), score {:.3e}, k = {}, means {:?}",
        b.t0,
        b.t1,
        b.t0_value,
        b.t1_value,
        b.score,
        b.k,
        b.means
            .iter()
            .map(|m| format!("{m:.3}"))
            .collect::<Vec<_>>()
    );
    println!("  every candidate (t0, t1 as fractions of the range), best first:");
    for c in &sel.candidates {
        println!(
            "    {:.3} {:.3}  score {:.4e}  k {}",
            c.t0, c.t1, c.score, c.k
        );
    }
    println!("  took {:.0} ms", start.elapsed().as_secs_f64() * 1e3);
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn occlusion_sensitivity(
    cli: &Cli,
    input: &InputArgs,
    radii: &[u32],
    bands: usize,
    stride: u32,
    method: &str,
    out: &std::path::Path,
    csv: Option<&std::path::Path>,
) -> Result<()> {
    use vellum::passes::occlusion::{Method, Neighbourhood, OcclusionParams};
    use vellum::volume::reference::occlusion::Visibility;
    anyhow::ensure!(
        !radii.is_empty() && bands > 0,
        "give at least one radius and one band"
    );
    let method = Method::parse(method)?;
    let v = input.load()?;
    let ctx = context(cli)?;
    let occ = vellum::passes::occlusion::Occlusion::new(&ctx)?;
    let largest = radii.iter().copied().max().unwrap_or(16);
    let stride = if stride == 0 {
        // Full resolution when an FFT method serves the largest radius there (its cost does not
        // grow with R); otherwise the runs method's cost calls for a coarser output.
        let p = OcclusionParams {
            radius: largest,
            visibility: Visibility::Ramp,
            neighbourhood: Neighbourhood::Ball,
            stride: 1,
            spectrum_bins: None,
            method,
            pad: None,
        };
        match occ.choose(v.dims, &p, false)? {
            Method::FftCpu | Method::FftGpu => 1,
            _ => (largest / 16).max(1),
        }
    } else {
        stride
    };
    let rows =
        vellum::passes::occlusion_analysis::sensitivity(&occ, &v, radii, bands, stride, method)?;
    report_validation(&ctx);
    let c = vellum::passes::occlusion_analysis::sensitivity_plot(&rows);
    vellum::output::write_png_rgb(out, c.width as u32, c.height as u32, &c.rgb)?;
    if let Some(path) = csv {
        vellum::passes::occlusion_analysis::write_sensitivity_csv(&rows, path)?;
    }
    println!(
        "sensitivity of {} over radii {radii:?} (stride {stride}, {bands} bands) written to {}",
        input.input,
        out.display()
    );
    Ok(())
}

/// Prints `value` as pretty JSON, or the text `text` makes.
fn print_report<T: serde::Serialize>(
    json: bool,
    value: &T,
    text: impl FnOnce() -> String,
) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(value)?);
    } else {
        print!("{}", text());
    }
    Ok(())
}
