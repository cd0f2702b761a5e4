//! The command line's definitions: every subcommand and flag (clap), the parsers of flag values,
//! and the names of the flags that stand for the library's keys in its messages.

use crate::flags::*;
use crate::scene_args::SceneArgs;
use anyhow::Result;
use std::path::PathBuf;
use vellum::render::style::LineSmooth;
use vellum::volume::Volume;

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
    /// Stores on a server (http:// or https:// URLs): the chunk cache's folder (default
    /// $XDG_CACHE_HOME/vellum/http or ~/.cache/vellum/http).
    #[arg(long, global = true, value_name = "DIR")]
    pub(crate) cache_dir: Option<PathBuf>,
    /// Stores on a server: the chunk cache's size in MiB, 0 for none (default 1024).
    #[arg(long, global = true, value_name = "MIB")]
    pub(crate) cache_mib: Option<u64>,
    /// Stores on a server: seconds without a byte before a request is tried again (default 20;
    /// three more tries).
    #[arg(long, global = true, value_name = "S", value_parser = positive_seconds)]
    pub(crate) http_timeout: Option<f64>,
    #[command(subcommand)]
    pub(crate) command: Command,
}

fn positive_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!(
            "{s} is not a number of seconds; expected one above 0, such as 20"
        )),
    }
}

impl Cli {
    /// How this command reads stores on a server.
    pub(crate) fn remote(&self) -> vellum::volume::io::http_store::RemoteOptions {
        let mut o = vellum::volume::io::http_store::RemoteOptions::default();
        if let Some(dir) = &self.cache_dir {
            o.cache_dir = Some(dir.clone());
        }
        if let Some(mib) = self.cache_mib {
            o.cache_mib = mib;
        }
        if let Some(s) = self.http_timeout {
            o.timeout = std::time::Duration::from_secs_f64(s);
        }
        o
    }
}

/// An input volume: a path, a DICOM folder or a phantom spec, with raw-file options.
#[derive(Args, Clone)]
pub(crate) struct InputArgs {
    /// File, DICOM folder, OME-Zarr store (a folder or an http:// or https:// URL), or phantom
    /// spec (phantom:shepp-logan:N, phantom:nested:N).
    pub(crate) input: String,
    #[command(flatten)]
    pub(crate) raw: RawArgs,
    /// An OME-Zarr store with a t axis: the time point to read, from 0.
    #[arg(long, value_name = "T")]
    pub(crate) time: Option<usize>,
    /// An OME-Zarr store with a c axis: the channel to read, from 0.
    #[arg(long, value_name = "C")]
    pub(crate) channel: Option<usize>,
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
        /// OME-Zarr: a volume on the input's grid written as the next channel (repeatable; the
        /// input is channel 0), giving a store of (c, z, y, x) whose channels `render
        /// --channels` mixes. Channels of different voxel types are all written as float32.
        #[arg(long, value_name = "FILE")]
        add_channel: Vec<String>,
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
    /// Label a volume by seeded region growing: one segment per --region, numbered from 1 in
    /// order, written as a label volume that render, view and migrate read with --labels.
    Segment(crate::features::SegmentArgs),
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
    /// GPU memory for the volume's textures in MiB; a volume whose intensity alone needs more is
    /// rendered through the brick cache, one whose intensity fits and whose stored gradients would
    /// not is ray-cast in core with its gradients made at each sample (default: half the device's
    /// largest memory heap).
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
    /// Brick cache: draw the first coarse frame, as a window would show it, and time it
    /// (`first_frame_ms` in --json); without it or --progress-frames none is drawn.
    #[arg(long)]
    pub(crate) first_frame: bool,
    /// Brick cache: when the frame's bricks all fit the pool, draw the last frame whole over
    /// them, so that its ray cast (`passes.raycast` in --json) is timed as a whole frame's
    /// (bench scale does); without it the last frame keeps the rays the passes finished.
    #[arg(long)]
    pub(crate) time_whole_frame: bool,
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
    /// Start playing a store's time points (the play button); with --bench, the report counts
    /// the time points shown.
    #[arg(long)]
    pub(crate) play: bool,
    /// Time points per second while playing, at most: each waits for its load when that is
    /// slower (default 10).
    #[arg(long, value_name = "N", default_value_t = 10.0)]
    pub(crate) play_rate: f64,
    /// GPU memory for the volume's textures in MiB; a store whose intensity alone needs more is
    /// streamed through the brick cache, one whose intensity fits and whose stored gradients would
    /// not is drawn in core with its gradients made at each sample (default: half the device's
    /// largest memory heap).
    #[arg(long, value_name = "MiB")]
    pub(crate) gpu_budget: Option<f64>,
    /// Host memory in MiB for a streamed store's decoded chunks and the bricks waiting for the
    /// GPU (default 1024: 896 of chunks, 128 of bricks).
    #[arg(long, value_name = "MiB")]
    pub(crate) memory_budget: Option<f64>,
    /// With --bench: print the report as JSON.
    #[arg(long)]
    pub(crate) json: bool,
    /// With --bench: write every frame's figures to this CSV, warm-up included, one per row:
    /// kind (present, gpu, bricks), frame, name (frame_ms, a pass, asked, read), value.
    #[arg(long, value_name = "CSV")]
    pub(crate) bench_log: Option<PathBuf>,
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

impl InputArgs {
    pub(crate) fn load(&self) -> Result<Volume> {
        let (raw, origin) = (self.raw.spec()?, self.raw.origin()?);
        Ok(vellum::input::open(
            &self.input,
            raw.as_ref(),
            origin,
            self.pick(),
        )?)
    }

    /// The time point and channel of a store that `--time` and `--channel` pick.
    pub(crate) fn pick(&self) -> vellum::volume::io::ome_zarr::Pick {
        vellum::volume::io::ome_zarr::Pick {
            time: self.time,
            channel: self.channel,
        }
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
pub(crate) const KEY_FLAGS: [(&str, &str); 14] = [
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
    ("`time`", "--time T"),
    ("`channels`", "--channels C (or --channel C)"),
    ("`focus_labels`", "--focus-labels IDS"),
    ("`renderer: raycast`", "--renderer raycast"),
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

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use vellum::render::scene::Scene;

    /// The scenes `render` and `view` build from the same flags.
    fn both(flags: &[&str]) -> (Scene, Scene) {
        let parse = |command: &str| {
            let words: Vec<&str> = ["vellum", command]
                .into_iter()
                .chain(flags.iter().copied())
                .collect();
            Cli::try_parse_from(words).unwrap().command
        };
        match (parse("render"), parse("view")) {
            (Command::Render(r), Command::View(v)) => (
                r.scene.scene("render").unwrap(),
                v.scene.view_scene().unwrap(),
            ),
            _ => unreachable!("render and view parse to their commands"),
        }
    }

    #[test]
    fn render_and_view_build_the_same_scene_from_the_same_flags() {
        let cases: [&[&str]; 4] = [
            &["phantom:sphere:32", "--iso", "0.5", "--renderer", "raycast"],
            &[
                "phantom:sphere:32",
                "--tf",
                "ct-bone",
                "--camera",
                "10,20",
                "--size",
                "300x200",
                "--renderer",
                "raycast",
                "--jitter",
                "3",
                "--refine-iso",
                "--iso",
                "0.4",
            ],
            &[
                "phantom:sphere:32",
                "--renderer",
                "slicer",
                "--focus",
                "0.2:0.6",
                "--style",
                "3",
                "--background",
                "1,1,1",
            ],
            &[
                "phantom:torus:32",
                "--renderer",
                "slicer",
                "--ortho",
                "--one-pass",
            ],
        ];
        for flags in cases {
            let (render, view) = both(flags);
            assert_eq!(render, view, "{flags:?}");
        }
        // `--renderer raycast` means the same ray caster in both: the default options.
        let (render, _) = both(cases[0]);
        assert_eq!(
            render.raycast,
            Some(vellum::render::view::RayOptions::default())
        );
        // Without the flag, the viewer's default differs from render's, as documented.
        let (render, view) = both(&["phantom:sphere:32"]);
        assert!(render.raycast.is_none() && view.raycast.is_some_and(|r| r.jitter.is_some()));
    }
}
