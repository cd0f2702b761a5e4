//! The command line's definitions: every subcommand and flag (clap), the parsers of flag values,
//! and the names of the flags that stand for the library's keys in its messages.

use crate::scene_args::SceneArgs;
use anyhow::Result;
use std::path::PathBuf;
use vellum::classify::modulation::Modulation;
use vellum::classify::Focus;
use vellum::render::style::LineSmooth;
use vellum::volume::io::RawSpec;
use vellum::volume::{Volume, VoxelType};

use clap::{Args, Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "vellum",
    version,
    about = "Illustrative volume rendering on Vulkan"
)]
pub(crate) struct Cli {
    /// Vulkan device: index or part of its name (also VELLUM_DEVICE).
    #[arg(long, global = true)]
    pub(crate) device: Option<String>,
    /// Log more (-v info, -vv debug).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    pub(crate) verbose: u8,
    #[command(subcommand)]
    pub(crate) command: Command,
}

/// An input volume: a path, a DICOM folder or a phantom spec, with raw-file options.
#[derive(Args, Clone)]
pub(crate) struct InputArgs {
    /// File, DICOM folder, or phantom spec (phantom:shepp-logan:N, phantom:nested:N).
    pub(crate) input: String,
    #[command(flatten)]
    pub(crate) raw: RawArgs,
}

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

#[derive(Subcommand)]
pub(crate) enum Command {
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
    /// Convert a volume to NRRD (gzip), NIfTI, or an OME-Zarr multiscale store.
    Convert {
        #[command(flatten)]
        input: InputArgs,
        /// Output volume: .nrrd, .nii or .nii.gz, or a new folder ending .zarr (OME-NGFF 0.5,
        /// zstd, a pyramid of 2×2×2 means); the extension picks the format.
        output: PathBuf,
        /// OME-Zarr: chunk edge in voxels (default 64).
        #[arg(long)]
        chunk: Option<usize>,
        /// OME-Zarr: levels of the pyramid, or auto (halve until the longest axis is ≤ 64).
        #[arg(long, value_name = "auto|N")]
        levels: Option<String>,
        /// OME-Zarr: report what was written (levels, chunks, bytes, rate, peak memory) as JSON.
        #[arg(long)]
        json: bool,
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
        /// Write ΔD as a float volume (.nrrd, .nii or .nii.gz), or as an OME-Zarr store
        /// (a new folder ending .zarr), computed chunk by chunk.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Write the three middle slices as a thermal PNG.
        #[arg(long)]
        slices: Option<PathBuf>,
        #[command(flatten)]
        chunking: ChunkArgs,
        #[arg(long)]
        json: bool,
    },
    /// The Sobel normals the renderer shades with (SPEC TL1), chunk by chunk with a one-voxel
    /// halo, into an OME-Zarr store of four float32 channels: the gradient of the normalised
    /// intensity in world units (x, y, z) and its length.
    Normals {
        #[command(flatten)]
        input: InputArgs,
        /// The store to write: a new folder ending .zarr.
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        chunking: ChunkArgs,
        #[arg(long)]
        json: bool,
    },
    /// Render a volume with 3D-texture slicing, in two levels (focus, context) or one pass.
    Render(Box<RenderArgs>),
    /// Object-space lines (silhouettes, suggestive contours) of the focus surface, drawn into the
    /// two-level frame (PNG) and written as vector paths of their visible parts (SVG).
    Lines(Box<LinesArgs>),
    /// Ambient-occlusion volume and occlusion spectrum (SPEC OS1-OS3).
    Occlusion(OcclusionArgs),
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
    OcclusionSensitivity(SensitivityArgs),
    /// Migrate a segmented feature into a private density interval (feature maps, SPEC FM1-FM5).
    Migrate(crate::features::MigrateArgs),
    /// Print the tree of a feature map (features.json).
    Features(crate::features::FeaturesArgs),
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
    /// The showcase page: runs every command of a manifest (examples/showcase.json) on a volume
    /// and writes OUT/index.html, one offline page with each image, the command that made it and
    /// its GPU timings (what `make run` ends with).
    Showcase(ShowcaseArgs),
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
pub(crate) struct RenderArgs {
    #[command(flatten)]
    pub(crate) scene: SceneArgs,
    /// Write the scene that this command line describes to a JSON file.
    #[arg(long)]
    pub(crate) save_scene: Option<PathBuf>,
    /// Output PNG (required unless only --save-scene is asked for).
    #[arg(long)]
    pub(crate) out: Option<PathBuf>,
    /// Also write the layers as float channels to this OpenEXR file.
    #[arg(long)]
    pub(crate) exr: Option<PathBuf>,
    #[arg(long)]
    pub(crate) json: bool,
    /// GPU memory for the volume's textures in MiB; a volume that needs more is rendered through
    /// the brick cache (default: half the device's largest memory heap).
    #[arg(long, value_name = "MiB")]
    pub(crate) gpu_budget: Option<f64>,
    /// Brick cache: wait at most this long for bricks; the image then holds what was resident,
    /// coarser where a brick was missing, and the command says so.
    #[arg(long, value_name = "MS")]
    pub(crate) max_wait_ms: Option<u64>,
    /// Brick cache: level of detail, auto (the coarsest level whose voxels cover at most one
    /// pixel at the sample) or finest (level 0 everywhere).
    #[arg(long, default_value = "auto", value_name = "auto|finest")]
    pub(crate) lod: String,
    /// Brick cache: write each refinement of the frame into this folder (progress_000.png, ...):
    /// the first frame drawn from the coarsest level, then one after each pass.
    #[arg(long, value_name = "DIR")]
    pub(crate) progress_frames: Option<PathBuf>,
    /// Brick cache: host memory in MiB for decoded chunks and bricks waiting for the GPU
    /// (default 1024: 896 of chunks, 128 of bricks).
    #[arg(long, value_name = "MiB")]
    pub(crate) memory_budget: Option<f64>,
    /// Under mpirun: how the ranks' partial frames are composited, auto (direct send),
    /// direct-send or binary-swap (a power of two of ranks).
    #[arg(long, value_name = "auto|direct-send|binary-swap")]
    pub(crate) composite: Option<String>,
}

/// How the chunked passes run (issue 26).
#[derive(Args, Clone, Debug)]
pub(crate) struct ChunkArgs {
    /// Host memory for the pass in MiB: above it (and for a store input) the pass runs chunk by
    /// chunk into an OME-Zarr store (default: half the machine's memory), and then works within
    /// it (default 1024: the chunk edge and the chunks in flight fit).
    #[arg(long, value_name = "MiB")]
    pub(crate) memory_budget: Option<f64>,
    /// Chunk edge of a chunked pass (default: the largest that fits the budget, at most 256).
    #[arg(long, value_name = "N")]
    pub(crate) chunk: Option<usize>,
}

/// `vellum occlusion`: the flags.
#[derive(Args)]
pub(crate) struct OcclusionArgs {
    #[command(flatten)]
    pub(crate) input: InputArgs,
    /// Neighbourhood radius R in voxels.
    #[arg(long, default_value_t = 16)]
    pub(crate) radius: u32,
    /// Visibility mapping: ramp, truncated:T0,T1 (fractions of the data range), gaussian, tf:FILE.json.
    #[arg(long, default_value = "ramp")]
    pub(crate) mapping: String,
    /// Output resolution: one occlusion voxel per STRIDE³ input voxels (exact at the voxel it samples).
    #[arg(long, default_value_t = 1)]
    pub(crate) stride: u32,
    /// Write the occlusion volume as a float volume (.nrrd, .nii or .nii.gz).
    #[arg(long)]
    pub(crate) out: Option<PathBuf>,
    /// Write the spectrum as a log-scaled PNG with axes.
    #[arg(long)]
    pub(crate) spectrum: Option<PathBuf>,
    /// Write the spectrum as CSV.
    #[arg(long)]
    pub(crate) spectrum_data: Option<PathBuf>,
    /// Spectrum bins along intensity and occlusion.
    #[arg(long, default_value_t = 256)]
    pub(crate) bins: u32,
    /// How the neighbourhood sum is computed: auto (a measured cost model), runs (direct sums on the GPU), fft-gpu or fft-cpu (FFT convolution, a cost that does not grow with the radius).
    #[arg(long, default_value = "auto")]
    pub(crate) method: String,
    #[command(flatten)]
    pub(crate) chunking: ChunkArgs,
    #[arg(long)]
    pub(crate) json: bool,
}

/// `vellum occlusion-sensitivity`: the flags.
#[derive(Args)]
pub(crate) struct SensitivityArgs {
    #[command(flatten)]
    pub(crate) input: InputArgs,
    /// Radii in voxels.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "4,8,16,32,64",
        allow_hyphen_values = true
    )]
    pub(crate) radii: Vec<u32>,
    /// Intensity bands.
    #[arg(long, default_value_t = 8)]
    pub(crate) bands: usize,
    /// Output stride; 0 picks 1 when an FFT method serves the largest radius, else the largest radius / 16 (at least 1).
    #[arg(long, default_value_t = 0)]
    pub(crate) stride: u32,
    /// How the neighbourhood sum is computed: auto (a measured cost model), runs (direct sums on the GPU), fft-gpu or fft-cpu (FFT convolution, a cost that does not grow with the radius).
    #[arg(long, default_value = "auto")]
    pub(crate) method: String,

    /// The plot (PNG).
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// The data (CSV).
    #[arg(long)]
    pub(crate) csv: Option<PathBuf>,
}

/// `vellum lines`: the render flags, a kind of line, and the SVG.
#[derive(Args)]
pub(crate) struct LinesArgs {
    #[command(flatten)]
    pub(crate) render: RenderArgs,
    /// Which lines: silhouettes, suggestive (contours) or both.
    #[arg(long, default_value = "both")]
    pub(crate) kind: String,
    /// Write the visible segments as SVG paths (pixel coordinates of the PNG).
    #[arg(long)]
    pub(crate) svg: Option<PathBuf>,
}

/// `vellum view`: the windowed viewer.
#[derive(Args)]
pub(crate) struct ViewArgs {
    // The scene: the same flags as `render` (input [default: phantom:shepp-logan:128], --scene,
    // --tf, --iso, --renderer [default: the scene file's; without one, raycast with jitter],
    // ...). --size WxH is also the window's size [default: 1100x700].
    #[command(flatten)]
    pub(crate) scene: SceneArgs,
    /// Folder for screenshots (key S): vellum-0001.png, ... [default: the current folder].
    #[arg(long, value_name = "DIR")]
    pub(crate) screenshot_dir: Option<PathBuf>,
    /// Write a screenshot of the volume view to this PNG when the window closes.
    #[arg(long, value_name = "PNG")]
    pub(crate) screenshot_on_exit: Option<PathBuf>,
    /// Present without waiting for vertical blank (MAILBOX or IMMEDIATE where offered).
    #[arg(long)]
    pub(crate) no_vsync: bool,
    /// Orbit N frames as a user's drag does (adaptive quality: half resolution while the camera
    /// moves), print the frame rate and frame-time percentiles, and close.
    #[arg(long, value_name = "N")]
    pub(crate) bench: Option<u32>,
    /// With --bench: orbit at full resolution instead.
    #[arg(long)]
    pub(crate) bench_full: bool,
    /// GPU memory for the volume's textures in MiB; a store that needs more is streamed through
    /// the brick cache (default: half the device's largest memory heap).
    #[arg(long, value_name = "MiB")]
    pub(crate) gpu_budget: Option<f64>,
    /// With --bench: print the report as JSON.
    #[arg(long)]
    pub(crate) json: bool,
}

/// `vellum styles`: the gallery of the 15 styles.
#[derive(Args)]
pub(crate) struct StylesArgs {
    #[command(flatten)]
    pub(crate) input: InputArgs,
    /// Transfer function: auto (the grey ramp over the histogram's window), a preset or a JSON
    /// file.
    #[arg(long, default_value = "auto")]
    pub(crate) tf: String,
    /// Focus: an interval of data values LO:HI.
    #[arg(long, value_name = "LO:HI", allow_hyphen_values = true)]
    pub(crate) focus: Option<String>,
    /// Focus: an isovalue in data units (an opaque surface).
    #[arg(long, value_name = "V", allow_negative_numbers = true)]
    pub(crate) iso: Option<f64>,
    /// Camera: azimuth and elevation in degrees, distance in bounding-sphere radii.
    #[arg(
        long,
        value_name = "AZ,EL[,DIST]",
        default_value = "30,20,2.5",
        allow_hyphen_values = true
    )]
    pub(crate) camera: String,
    /// Size of each tile.
    #[arg(
        long,
        value_name = "WxH",
        default_value = "256x256",
        allow_hyphen_values = true
    )]
    pub(crate) size: String,
    /// Background colour as R,G,B in 0..1.
    #[arg(long, default_value = "0,0,0", allow_hyphen_values = true)]
    pub(crate) background: String,
    /// Colour of the edges and lines of every style, as R,G,B in 0..1 [default: 0,0,0].
    #[arg(long, value_name = "R,G,B", allow_hyphen_values = true)]
    pub(crate) edge_color: Option<String>,
    /// Object-space lines (styles 4-12): smooth the volume first with a Gaussian of this radius in
    /// voxels (σ = R/3; 0 none), or auto: by the data's quantisation [default: auto].
    #[arg(long, value_name = "auto|R", value_parser = parse_line_smooth)]
    pub(crate) line_smooth: Option<LineSmooth>,
    /// The contact sheet (PNG).
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// Also write each style as its own PNG into this folder.
    #[arg(long)]
    pub(crate) out_dir: Option<PathBuf>,
    /// With --out-dir, also write each style's layers as OpenEXR.
    #[arg(long, requires = "out_dir")]
    pub(crate) exr: bool,
    /// Report each style's mean saliency inside the focus against outside it.
    #[arg(long)]
    pub(crate) saliency: bool,
    #[arg(long)]
    pub(crate) json: bool,
    /// Renderer of every style: slicer (default) or raycast (the same layers, so the same styles).
    #[arg(long, value_name = "slicer|raycast")]
    pub(crate) renderer: Option<String>,
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
    /// Applies the flags over the scene file's style, if any.
    pub(crate) fn apply(
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
    /// Applies the flags over `m` (the scene file's modulation, or none).
    pub(crate) fn apply(&self, m: Option<Modulation>) -> Result<Option<Modulation>> {
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

#[derive(Subcommand)]
pub(crate) enum FiguresCommand {
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
pub(crate) enum BenchCommand {
    /// Out of core (issue 26): Shepp-Logan phantoms streamed into stores, rendered through the
    /// brick cache and in core where they fit, and the importance map chunked and in core.
    Scale {
        #[arg(long)]
        json: bool,
        /// Phantom sizes (voxels per axis), e.g. 256,512,1024,2048 (required: 2048³ takes a few
        /// minutes and 37 GiB of writes before compression).
        #[arg(long, value_delimiter = ',', required = true)]
        sizes: Vec<usize>,
        /// Square image size in pixels.
        #[arg(long, default_value_t = 256)]
        image: u32,
        /// Where the stores go (removed afterwards unless --keep).
        #[arg(long, default_value = "bench-scale")]
        dir: PathBuf,
        #[arg(long)]
        keep: bool,
    },
    /// Many ranks (issue 27; needs a build with --features mpi and Open MPI's mpirun): strong
    /// scaling of the chunked importance map (R = 10) and occlusion (R = 16) of a Shepp-Logan
    /// phantom streamed into a store, and the compositing of a shared two-level frame against the
    /// ranks, the image size and the exchange, with the bytes each frame sends.
    Mpi {
        #[arg(long)]
        json: bool,
        /// Phantom size (voxels per axis).
        #[arg(long, default_value_t = 1024)]
        size: usize,
        /// Chunk edge of the passes' output stores.
        #[arg(long, default_value_t = 128)]
        chunk: usize,
        /// Rank counts, e.g. 1,2,4 (required: a 1024³ store takes minutes per count); counts
        /// above the cores are oversubscribed.
        #[arg(long, value_delimiter = ',', required = true)]
        ranks: Vec<usize>,
        /// Square image sizes of the compositing rows.
        #[arg(long, value_delimiter = ',', default_value = "512,1024")]
        images: Vec<u32>,
        /// Where the stores go (removed afterwards unless --keep).
        #[arg(long, default_value = "bench-mpi")]
        dir: PathBuf,
        #[arg(long)]
        keep: bool,
    },
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
        /// Also time the four passes with the device kept busy: N rounds back to back in each of
        /// three submissions on the volume uploaded once, medians of the last (0: off).
        #[arg(long, default_value_t = 0)]
        sustained: usize,
    },
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

impl InputArgs {
    pub(crate) fn load(&self) -> Result<Volume> {
        let raw = self.raw.spec()?;
        if let Some(o) = self.raw.origin()? {
            let v = vellum::input::load(&self.input, raw.as_ref())?;
            let g = vellum::volume::geometry::Geometry::lps(o, vellum::volume::geometry::IDENTITY)?;
            return Ok(v.with_geometry(g)?);
        }
        Ok(vellum::input::load(&self.input, raw.as_ref())?)
    }
}

/// Lets every option take a negative number as its value (`--focus -2000:-500`, `--radius -5`),
/// so that a negative value is parsed, and refused with a sentence where it makes no sense,
/// instead of being taken for an unknown flag. List-valued options also set
/// `allow_hyphen_values` where they are declared.
pub(crate) fn negatives(cmd: clap::Command) -> clap::Command {
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
pub(crate) fn parse_cli() -> Cli {
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
                    std::process::exit(1);
                }
            }
            // Help and version go out as clap writes them; any other mistake is one sentence
            // and status 1, as every other bad input (docs/cli.md).
            if matches!(
                e.kind(),
                ErrorKind::DisplayHelp
                    | ErrorKind::DisplayVersion
                    | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
            ) {
                e.exit()
            }
            let text = e.render().to_string();
            let first = text
                .lines()
                .find(|l| !l.trim().is_empty())
                .unwrap_or("the command line could not be read");
            let first = first.trim_start_matches("error: ");
            eprintln!(
                "error: {}",
                vellum::error::one_line(&format!("{first} (see --help)"))
            );
            std::process::exit(1);
        }
    }
}

/// The library's errors name the scene's keys and the passes' parameters in backticks
/// (`one_pass`, `iso`, `method`); the command line names its flags for them.
pub(crate) const KEY_FLAGS: [(&str, &str); 10] = [
    ("`one_pass`", "--one-pass"),
    ("`iso`", "--iso V"),
    ("`focus`", "--focus LO:HI"),
    ("`size`", "--size"),
    ("`slices`", "--slices"),
    ("`method`", "--method"),
    ("`radius`", "--radius"),
    ("`style`", "--style"),
    ("`gpu_budget`", "--gpu-budget"),
    ("`lod`", "--lod"),
];

/// `message` with each key the library names replaced by its flag.
pub(crate) fn flags_for_keys(message: &str) -> String {
    // A message about a file's fields (a scene, a transfer function: `PATH.json: unknown field
    // `radius`…`) names the file's keys, not flags.
    if message.contains(".json: ") {
        return message.to_string();
    }
    KEY_FLAGS
        .iter()
        .fold(message.to_string(), |m, (key, flag)| m.replace(key, flag))
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
fn parse_line_smooth(s: &str) -> std::result::Result<LineSmooth, String> {
    LineSmooth::parse(s).map_err(|e| e.to_string())
}

/// `vellum showcase`.
#[derive(Args)]
pub(crate) struct ShowcaseArgs {
    /// The volume of the per-technique sections (file, DICOM folder or phantom spec); the composed
    /// picture and the feature and occlusion sections use the scenes the manifest names.
    pub(crate) input: String,
    /// The focus isovalue of the two-level sections, in the input's data units.
    #[arg(long, allow_negative_numbers = true)]
    pub(crate) iso: f64,
    /// The output folder; it gets index.html and every file the page shows.
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// The manifest: sections, their commands, images and captions.
    #[arg(long, default_value = "examples/showcase.json")]
    pub(crate) manifest: PathBuf,
}
