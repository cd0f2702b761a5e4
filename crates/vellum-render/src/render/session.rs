//! The library session (issue 39): the one place an input becomes something to render. A
//! [`Session`] opens any input (a file, a DICOM folder, a store, a phantom, or a volume already in
//! memory, such as Python's) with a GPU budget, decides alone whether it goes to the GPU whole or
//! through the brick cache, holds the rule that the ray caster draws a bricked volume, and draws
//! still frames. `render`, `view`, the ranks of an MPI job and Python all open their inputs here.
//!
//! The decision, by the bytes of the textures in core:
//! - intensity and stored gradients (10 bytes a voxel) within the budget: in core, as every
//!   renderer draws it;
//! - the intensity alone (2 bytes a voxel) within it: in core with no gradient texture, the ray
//!   caster making each shaded sample's gradient from the intensity
//!   ([`GradientSource::AtSample`]); not for a scene that makes another whole-volume texture the
//!   rule does not count (mixed channels, labels, occlusion, modulation, object-space lines);
//! - beyond that, the brick cache: a store is never read whole (its pyramid goes to the cache as
//!   it is on disk); any other input is read, and its pyramid is made in memory. Its pool holds
//!   intensity alone (2 bytes a texel), and the ray caster makes the gradients at each sample
//!   there too.
//!
//! Only the ray caster draws the last two, and the session says so when it makes a view one.

use crate::classify::Classification;
use crate::passes::gpu_volume::VolumeRef;
use crate::passes::normals::GradientSource;
use crate::render::bricked::{StillOptions, StreamReport};
use crate::render::frame::Renderer;
use crate::render::scene::{GpuScene, PagedScene, Scale, Scene};
use crate::render::stream::{StreamOptions, Streamer};
use crate::render::targets::FrameImage;
use crate::render::view::View;
use std::path::Path;
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::{Context, PassTime};
use vellum_volume::bricks::{in_core_bytes, intensity_bytes, BrickLevels};
use vellum_volume::geometry::Geometry;
use vellum_volume::Volume;

/// Host memory a streamed volume takes by default, besides its pools on the device: the decoded
/// chunks (seven eighths, `volume::bricks::DEFAULT_CHUNK_CACHE`) and the bricks waiting for the
/// GPU (an eighth, `render::stream::DEFAULT_READY_BYTES`). A frame's wavefront of chunks (with
/// the neighbours its bricks' aprons read) fits it at 1024² on a 2048³ store, so a chunk is
/// decoded about twice rather than eight times.
pub const DEFAULT_MEMORY: u64 = 1 << 30;

/// Loader threads for a store on a server, at least: requests in flight, each waiting on its
/// answer's latency rather than on a core.
pub const REMOTE_LOADERS: usize = 16;

/// Which levels a bricked frame samples.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq)]
pub enum Lod {
    /// The level each sample's projected voxel size asks for.
    #[default]
    Auto,
    /// Level 0 everywhere.
    Finest,
}

impl Lod {
    /// `auto` or `finest`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "auto" => Ok(Lod::Auto),
            "finest" => Ok(Lod::Finest),
            other => Err(Error::Invalid(format!(
                "`lod` {other:?} is unknown; expected auto or finest"
            ))),
        }
    }
}

/// How a session opens its input.
#[derive(Clone, Debug, Default)]
pub struct SessionOptions {
    /// MiB of GPU memory the volume's textures may take; `None`: half the device's largest heap.
    pub gpu_budget_mib: Option<f64>,
    /// Which levels a bricked frame samples.
    pub lod: Lod,
    /// The loaders of a bricked volume: how many, and how many bytes of bricks may wait ready.
    pub stream: StreamOptions,
    /// Bytes of decoded chunks kept for the bricks (`None`: the default).
    pub chunk_cache_bytes: Option<u64>,
}

/// The input of a command that draws in core only (`lines`, `styles`: the slicer's two-level
/// frames and their image-space passes): `load`'s volume when its intensity and stored gradients
/// fit `budget` bytes (the slicer reads the stored gradients). Beyond it, one sentence naming the
/// command (`what`), the budget and the command's `flag` that raises it if it has one; a store
/// (at `path`, its time point and channel picked by `pick`) is refused before it is read.
pub fn in_core_only(
    (path, pick): (&str, vellum_volume::io::ome_zarr::Pick),
    (budget, flag): (u64, Option<&str>),
    what: &str,
    load: impl FnOnce() -> Result<Volume>,
) -> Result<Volume> {
    use vellum_volume::io::ome_zarr;
    let refuse = |dims: [usize; 3]| {
        let mib = budget as f64 / (1 << 20) as f64;
        let raise = flag.map(|f| format!("raise {f}, or ")).unwrap_or_default();
        Error::Invalid(format!(
            "{what} draws the whole volume in core, and {path} ({}x{}x{}) is larger than the GPU budget ({mib:.0} MiB); {raise}draw it with `vellum render --renderer raycast`, in core with its gradients made at each sample or through the brick cache",
            dims[0], dims[1], dims[2]
        ))
    };
    if ome_zarr::is_store(Path::new(path)) {
        let ms = ome_zarr::Multiscale::open_picked(Path::new(path), pick)?;
        let dims = ms.levels[0].dims;
        if in_core_bytes(dims) > budget {
            return Err(refuse(dims));
        }
    }
    let v = load()?;
    match in_core_bytes(v.dims) > budget {
        true => Err(refuse(v.dims)),
        false => Ok(v),
    }
}

impl SessionOptions {
    /// These options with `mib` MiB of host memory for a streamed volume (`None`: the
    /// default, [`DEFAULT_MEMORY`]): seven eighths for decoded chunks, an eighth for bricks
    /// waiting for the GPU. At least 1 MiB; `what` names the option in the sentence refusing
    /// less (`--memory-budget`, `memory_budget`).
    pub fn with_memory_budget(mut self, mib: Option<f64>, what: &str) -> Result<Self> {
        let memory = match mib {
            None => DEFAULT_MEMORY,
            Some(m) if m.is_finite() && m >= 1.0 => (m * (1u64 << 20) as f64) as u64,
            Some(m) => {
                return Err(Error::Invalid(format!(
                    "{what} {m} is invalid; expected at least 1 MiB"
                )))
            }
        };
        self.stream.ready_bytes = memory / 8;
        self.chunk_cache_bytes = Some(memory - memory / 8);
        Ok(self)
    }
}

/// An input opened on the host: whole, or as the pyramid the brick cache reads.
pub enum Opened {
    /// The whole volume, read into host memory.
    InCore(Volume),
    /// The pyramid the brick cache reads: a store's levels on disk, or levels made in memory.
    Bricked(Arc<BrickLevels>),
}

impl Opened {
    /// Opens the `scene`'s input (or `volume`, given in its place) for a GPU budget of `budget`
    /// bytes; see the module's documentation for the rule. A pyramid keeps `chunk_cache` bytes
    /// of decoded chunks (`None`: the default).
    pub fn open(
        scene: &Scene,
        volume: Option<Volume>,
        budget: u64,
        chunk_cache: Option<u64>,
    ) -> Result<Self> {
        let bricked = |mut levels: BrickLevels| -> Result<Opened> {
            // (Mixed channels share it, each its part: `mix_channels`.)
            if let (Some(bytes), None) = (chunk_cache, &scene.channels) {
                levels.set_chunk_budget(bytes);
            }
            // Each brick carries its slot's segment indices (the ray caster reads them nearest).
            if let Some(spec) = &scene.labels {
                let image = Path::new(&scene.input.path);
                let labels =
                    vellum_volume::labels::Labels::open(Path::new(&spec.path), Some(image))?;
                levels.set_labels(Arc::new(labels), &format!("the label volume {}", spec.path))?;
            }
            Ok(Opened::Bricked(Arc::new(levels)))
        };
        let v = match volume {
            Some(v) => v,
            None => {
                let path = Path::new(&scene.input.path);
                if scene.input.raw.is_none() {
                    let fits = |dims| fits_in_core(scene, dims, budget);
                    if let Some(mut levels) =
                        BrickLevels::of_store_beyond(path, fits, scene.input.pick())?
                    {
                        if let Some(spec) = &scene.channels {
                            mix_channels(&mut levels, scene, spec, chunk_cache)?;
                        }
                        return bricked(levels);
                    }
                }
                scene.load_volume()?
            }
        };
        if !fits_in_core(scene, v.dims, budget) {
            return bricked(BrickLevels::of_volume(v)?);
        }
        Ok(Opened::InCore(v))
    }

    /// Level 0's dims, spacing and placement.
    pub fn grid(&self) -> ([usize; 3], [f64; 3], Geometry) {
        match self {
            Opened::InCore(v) => (v.dims, v.spacing, v.geometry),
            Opened::Bricked(b) => (b.levels()[0].dims, b.levels()[0].spacing, b.geometry),
        }
    }

    /// The volume, or the finest level of the pyramid of at most `voxels` voxels, read whole
    /// (for statistics, a histogram or the regions of a job).
    pub fn small(&self, voxels: usize) -> Result<std::borrow::Cow<'_, Volume>> {
        match self {
            Opened::InCore(v) => Ok(std::borrow::Cow::Borrowed(v)),
            Opened::Bricked(b) => Ok(std::borrow::Cow::Owned(b.read_small_level(voxels)?)),
        }
    }
}

/// A volume on the GPU with its classification: in core, or through the brick cache with the
/// streamer that fills it.
pub enum Prepared {
    /// The whole volume's textures, with its classification.
    InCore(GpuScene),
    /// The brick cache's pools with their classification, and the streamer that fills them.
    Paged(PagedScene, Box<Streamer>),
}

impl Prepared {
    /// `opened` on the GPU, classified by `classification` with the scene's focus and
    /// modulation; a pyramid goes to pools of `budget` bytes with loaders started on its
    /// coarsest level.
    pub fn new(
        ctx: &Arc<Context>,
        scene: &Scene,
        classification: &Classification,
        opened: &Opened,
        (budget, opts): (u64, &SessionOptions),
    ) -> Result<Self> {
        let modulation = scene.modulation.clone().unwrap_or_default();
        Ok(match opened {
            Opened::InCore(v) => {
                let (scale, classification) = series_scale(scene, classification)?;
                let normals = crate::passes::normals::Normals::new(ctx)?;
                let source = gradient_source(scene, v.dims, budget);
                Self::in_core(&normals, (v, scale, source), scene, &classification)?
            }
            Opened::Bricked(levels) => {
                let finest = opts.lod == Lod::Finest;
                let focus = (scene.focus, &modulation);
                let paged = PagedScene::prepare(
                    ctx,
                    levels.clone(),
                    classification,
                    focus,
                    budget,
                    finest,
                )?;
                let mut stream_opts = opts.stream;
                let remote = vellum_volume::io::http_store::is_url(Path::new(&scene.input.path));
                if remote && std::env::var_os("VELLUM_LOADERS").is_none() {
                    // A store on a server: the loaders mostly wait on answers, so more of them
                    // keep more requests in flight (each sends its own).
                    stream_opts.threads = stream_opts.threads.max(REMOTE_LOADERS);
                }
                let mut stream = Streamer::new(levels.clone(), stream_opts);
                stream.start(&paged.volume.paged);
                Prepared::Paged(paged, Box::new(stream))
            }
        })
    }

    /// A volume in core on the GPU, as [`Prepared::new`] makes one, on `scale`, with its
    /// gradients from `source` ([`gradient_source`]) and the pipelines of `normals`: a front end
    /// that prepares one volume after another (the viewer) builds them once, and knows a
    /// series' scale already.
    pub fn in_core(
        normals: &crate::passes::normals::Normals,
        input: (&Volume, crate::render::scene::Scale, GradientSource),
        scene: &Scene,
        classification: &Classification,
    ) -> Result<Self> {
        let modulation = scene.modulation.clone().unwrap_or_default();
        let gpu = GpuScene::prepare_with(normals, input, classification, scene.focus, &modulation)?;
        Ok(Prepared::InCore(gpu))
    }

    /// The volume as the renderer draws it.
    pub fn volume(&self) -> VolumeRef<'_> {
        match self {
            Prepared::InCore(g) => (&g.volume).into(),
            Prepared::Paged(p, _) => (&p.volume).into(),
        }
    }

    /// The volume and its classification, for recording a frame.
    pub fn parts(
        &mut self,
    ) -> (
        VolumeRef<'_>,
        &mut crate::classify::textures::GpuClassification,
    ) {
        match self {
            Prepared::InCore(g) => ((&g.volume).into(), &mut g.classify),
            Prepared::Paged(p, _) => ((&p.volume).into(), &mut p.classify),
        }
    }

    /// The classification on the GPU.
    pub fn classify(&mut self) -> &mut crate::classify::textures::GpuClassification {
        match self {
            Prepared::InCore(g) => &mut g.classify,
            Prepared::Paged(p, _) => &mut p.classify,
        }
    }

    /// GPU ms of the passes that prepared a volume in core (none for the brick cache).
    pub fn passes(&self) -> &[PassTime] {
        match self {
            Prepared::InCore(g) => &g.passes,
            Prepared::Paged(..) => &[],
        }
    }

    /// Whether the volume goes through the brick cache.
    pub fn is_paged(&self) -> bool {
        matches!(self, Prepared::Paged(..))
    }

    /// Where the shading's gradients come from.
    pub fn gradients(&self) -> ShadingGradients {
        match self {
            Prepared::InCore(g) => match g.volume.gradient.image() {
                Some(_) => ShadingGradients::Stored,
                None => ShadingGradients::AtSample,
            },
            Prepared::Paged(..) => ShadingGradients::Pool,
        }
    }

    /// The occlusion spectrum made while preparing, taken out (an occlusion TF in core only).
    pub fn take_spectrum(&mut self) -> Option<crate::passes::occlusion::Spectrum> {
        match self {
            Prepared::InCore(g) => g.spectrum.take(),
            Prepared::Paged(..) => None,
        }
    }
}

/// The scale a volume in core is drawn on, and its classification there: the scene's
/// `input.range` (and `input.line_smooth`) when it gives one; for a later time point of a store
/// (`time` > 0), the smallest and largest values of time point 0 and its `auto` line smoothing,
/// with `auto` made from time point 0, so that every frame of a series shares one scale, one
/// transfer function and one line smoothing (`render --time T` draws what the frame T of
/// `render --time all` draws); else the volume's own.
pub fn series_scale(
    scene: &Scene,
    classification: &Classification,
) -> Result<(Scale, Classification)> {
    if let Some(r) = scene.input.range {
        if !(r[0].is_finite() && r[1].is_finite() && r[0] < r[1]) {
            return Err(Error::Invalid(format!(
                "the input's range [{}, {}] is empty; expected the smallest value below the largest",
                r[0], r[1]
            )));
        }
        return Ok((scene.input.scale(), classification.clone()));
    }
    if scene.input.time.unwrap_or(0) == 0 {
        return Ok((scene.input.scale(), classification.clone()));
    }
    let mut first = scene.clone();
    first.input.time = Some(0);
    let t0 = first.load_volume()?;
    let range = t0.normalised_range();
    let classification = match classification {
        Classification::Auto => {
            Classification::Transfer(crate::classify::window::auto(&t0, range)?)
        }
        c => c.clone(),
    };
    let scale = Scale {
        range: Some(range),
        line_smooth: Some(
            scene
                .input
                .line_smooth
                .unwrap_or_else(|| vellum_volume::lines::auto_smooth_radius(&t0)),
        ),
    };
    Ok((scale, classification))
}

/// Puts what the scene draws beside its volume on the GPU: a label volume's segments and the
/// channels mixed in the ray (`Session::prepare` does; a front end that prepares the volume
/// itself, as the viewer does, calls it after).
pub fn attach_beside(ctx: &Arc<Context>, scene: &Scene, prepared: &mut Prepared) -> Result<()> {
    if let Some(spec) = &scene.labels {
        attach_labels(ctx, scene, spec, prepared)?;
    }
    if let Some(spec) = &scene.channels {
        attach_channels(ctx, scene, spec, prepared)?;
    }
    Ok(())
}

/// Makes every brick of `levels` (the focus channel's pyramid) carry the voxels of the channels
/// `spec` mixes, each from its own pyramid over its own range; the chunk cache's bytes are
/// shared among the pyramids. The focus channel takes the range its description gives it, as
/// [`attach_channels`] describes it.
fn mix_channels(
    levels: &mut BrickLevels,
    scene: &Scene,
    spec: &crate::classify::channels::ChannelSpec,
    chunk_cache: Option<u64>,
) -> Result<()> {
    use vellum_volume::bricks::Mixed;
    use vellum_volume::io::ome_zarr::{Multiscale, Pick};
    let path = Path::new(&scene.input.path);
    let time = scene.input.time;
    let channels = spec.read_at(path, time, true)?;
    let focus = scene.input.channel.unwrap_or(spec.channels[0]);
    let share = chunk_cache.unwrap_or(DEFAULT_MEMORY * 7 / 8) / channels.len() as u64;
    levels.set_chunk_budget(share);
    let mut mixed = Vec::with_capacity(channels.len());
    for c in &channels {
        if c.index == focus {
            levels.set_range(c.range);
            mixed.push(Mixed::Own);
            continue;
        }
        let pick = Pick {
            time,
            channel: Some(c.index),
        };
        let mut other =
            BrickLevels::of_store(Arc::new(Multiscale::open_picked(path, pick)?), 1 << 24)?;
        other.set_range(c.range);
        other.set_chunk_budget(share);
        mixed.push(Mixed::Other(Box::new(other)));
    }
    levels.mix(mixed)
}

/// Puts the label volume `spec` names on the GPU beside the volume: in core, read here and
/// checked against the input's grid; through the brick cache, whose bricks carry its segment
/// indices ([`Opened::open`] attached it to the pyramid), its table.
fn attach_labels(
    ctx: &Arc<Context>,
    scene: &Scene,
    spec: &crate::classify::labels::LabelSpec,
    prepared: &mut Prepared,
) -> Result<()> {
    // A label volume drawn over itself hides id 0, which would only outline each segment.
    let same = |p: &str| std::fs::canonicalize(p).ok();
    let over_itself = same(&spec.path).is_some_and(|l| Some(l) == same(&scene.input.path));
    let g = match prepared {
        Prepared::InCore(g) => g,
        Prepared::Paged(p, _) => {
            // The pyramid was opened with them ([`Opened::open`]): its bricks carry them.
            let Some(labels) = p.volume.paged.levels.labels() else {
                return Err(Error::Invalid(
                    "the brick cache was opened without the label volume; expected `labels` when the input is opened".into(),
                ));
            };
            let gpu = crate::classify::labels::GpuLabels::new(
                ctx,
                labels.clone(),
                spec,
                (!over_itself, false),
            )?;
            p.classify.labels = Some(gpu);
            return Ok(());
        }
    };
    let image = Path::new(&scene.input.path);
    let labels = vellum_volume::labels::Labels::open(Path::new(&spec.path), Some(image))?;
    labels.check_grid(g.volume.dims, &format!("the label volume {}", spec.path))?;
    let gpu =
        crate::classify::labels::GpuLabels::new(ctx, Arc::new(labels), spec, (!over_itself, true))?;
    g.classify.labels = Some(gpu);
    Ok(())
}

/// Reads the channels `spec` mixes from the input store and puts them on the GPU beside the
/// volume (the focus channel, which every pass sees): in core, their textures; through the brick
/// cache, whose bricks carry their voxels ([`mix_channels`]), their transfer functions.
fn attach_channels(
    ctx: &Arc<Context>,
    scene: &Scene,
    spec: &crate::classify::channels::ChannelSpec,
    prepared: &mut Prepared,
) -> Result<()> {
    let path = Path::new(&scene.input.path);
    let focus = scene.input.channel.unwrap_or(spec.channels[0]);
    let k = spec.channels.iter().position(|&c| c == focus).unwrap_or(0);
    let g = match prepared {
        Prepared::InCore(g) => g,
        Prepared::Paged(p, _) => {
            if p.volume.channels.is_none() {
                return Err(Error::Invalid(
                    "the brick cache was opened without the channels to mix; expected `channels` when the input is opened".into(),
                ));
            }
            let channels = spec.read_at(path, scene.input.time, true)?;
            let gpu =
                crate::classify::channels::GpuChannels::new_paged(ctx, &channels, spec.mix, k)?;
            p.classify.channels = Some(gpu);
            return Ok(());
        }
    };
    if scene.input.raw.is_some()
        || !vellum_volume::io::ome_zarr::is_store(Path::new(&scene.input.path))
    {
        return Err(Error::Invalid(format!(
            "`channels` mixes channels of an OME-Zarr store; {} is not one",
            scene.input.path
        )));
    }
    let channels = spec.read(path, scene.input.time)?;
    let gpu =
        crate::classify::channels::GpuChannels::new(ctx, &channels, spec.mix, (k, g.volume.range))?;
    g.classify.channels = Some(gpu);
    Ok(())
}

/// Where a frame's shading takes its gradients from, as reports name it
/// ([`ShadingGradients::name`]).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum ShadingGradients {
    /// A texture of them, made once (`stored`).
    Stored,
    /// Made from the intensity at each shaded sample (`at_sample`).
    AtSample,
    /// Made at each shaded sample from the brick cache's intensity pool (`pool`).
    Pool,
}

impl ShadingGradients {
    /// The name `render --json` and Python give it.
    pub fn name(self) -> &'static str {
        match self {
            ShadingGradients::Stored => "stored",
            ShadingGradients::AtSample => "at_sample",
            ShadingGradients::Pool => "pool",
        }
    }
}

/// Whether the `scene` may be drawn in core with its gradients made at each sample: it makes no
/// other whole-volume texture that the rule does not count (mixed channels, a label volume, an
/// occlusion transfer function's occlusion volume, importance modulation's ΔD, a style's
/// object-space lines), and `VELLUM_GRADIENTS_AT_SAMPLE` is not 0 (which holds every scene to
/// the stored gradients' rule, for measuring the brick cache against this).
fn at_sample_allowed(scene: &Scene) -> bool {
    use crate::render::scene::ClassificationSpec::{Composed, Occlusion};
    let occlusion = matches!(scene.classification, Occlusion(_) | Composed { .. });
    let modulated = scene.modulation.as_ref().is_some_and(|m| m.is_active());
    let lines = (scene.style.as_ref().and_then(|s| s.resolve().ok()))
        .is_some_and(|s| s.def.lines.is_some());
    std::env::var("VELLUM_GRADIENTS_AT_SAMPLE").as_deref() != Ok("0")
        && scene.channels.is_none()
        && scene.labels.is_none()
        && !(occlusion || modulated || lines)
}

/// Whether the `scene`'s volume of `dims` goes to the GPU whole within `budget` bytes: its
/// intensity alone fits where [`at_sample_allowed`], else its intensity and stored gradients.
fn fits_in_core(scene: &Scene, dims: [usize; 3], budget: u64) -> bool {
    match at_sample_allowed(scene) {
        true => intensity_bytes(dims) <= budget,
        false => in_core_bytes(dims) <= budget,
    }
}

/// Where the `scene`'s volume of `dims`, going to the GPU whole, takes its gradients from within
/// a budget of `budget` bytes: stored when its intensity and gradients fit (or the scene may not
/// make them at each sample), else made at each sample.
pub fn gradient_source(scene: &Scene, dims: [usize; 3], budget: u64) -> GradientSource {
    match in_core_bytes(dims) <= budget || !at_sample_allowed(scene) {
        true => GradientSource::Stored,
        false => GradientSource::AtSample,
    }
}

/// Why only the ray caster draws a volume.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum RayCastOnly {
    /// It goes through the brick cache.
    Bricked,
    /// It is in core with its gradients made at each sample.
    GradientsAtSample,
}

/// The ray caster draws a volume for `why`: `raycast` (a view's or a scene's) made so, with the
/// sentence that says so when it was not (`budget` bytes, for the sentence).
pub fn ray_cast_only(
    raycast: &mut Option<crate::render::raycast::RayOptions>,
    budget: u64,
    why: RayCastOnly,
) -> Option<String> {
    if raycast.is_some() {
        return None;
    }
    *raycast = Some(Default::default());
    let mib = budget as f64 / (1 << 20) as f64;
    Some(match why {
        RayCastOnly::Bricked => format!(
            "the volume is larger than the GPU budget ({mib:.0} MiB): the ray caster draws it through the brick cache"
        ),
        RayCastOnly::GradientsAtSample => format!(
            "the volume's gradients do not fit the GPU budget ({mib:.0} MiB): the ray caster draws it in core, making them at each sample"
        ),
    })
}

/// One input opened for rendering: its volume on the GPU, and a renderer.
pub struct Session {
    /// The volume on the GPU with its classification.
    pub prepared: Prepared,
    /// The renderer that draws its frames.
    pub renderer: Renderer,
    /// The GPU budget in bytes.
    pub budget: u64,
}

impl Session {
    /// Opens the `scene`'s input (or `volume` in its place) on `ctx` within `opts`'s budget.
    pub fn open(
        ctx: &Arc<Context>,
        scene: &Scene,
        volume: Option<Volume>,
        opts: &SessionOptions,
    ) -> Result<Self> {
        let classification = scene.classification()?;
        let budget = crate::render::bricked::gpu_budget_bytes(ctx, opts.gpu_budget_mib)?;
        let opened = Opened::open(scene, volume, budget, opts.chunk_cache_bytes)?;
        Self::prepare(ctx, scene, &classification, &opened, (budget, opts))
    }

    /// A session on an input already opened (`Opened::open`, e.g. on another thread).
    pub fn prepare(
        ctx: &Arc<Context>,
        scene: &Scene,
        classification: &Classification,
        opened: &Opened,
        (budget, opts): (u64, &SessionOptions),
    ) -> Result<Self> {
        let mut prepared = Prepared::new(ctx, scene, classification, opened, (budget, opts))?;
        attach_beside(ctx, scene, &mut prepared)?;
        Ok(Session {
            prepared,
            renderer: Renderer::new(ctx)?,
            budget,
        })
    }

    /// `view` as this session draws it, and the sentence to say when the brick cache or a label
    /// volume made it a ray-cast view.
    pub fn view(&self, mut view: View) -> (View, Option<String>) {
        let why = match self.prepared.gradients() {
            ShadingGradients::Pool => Some(RayCastOnly::Bricked),
            ShadingGradients::AtSample => Some(RayCastOnly::GradientsAtSample),
            ShadingGradients::Stored => None,
        };
        let note = why.and_then(|why| ray_cast_only(&mut view.raycast, self.budget, why));
        let (labels, channels) = match &self.prepared {
            Prepared::InCore(g) => (g.classify.labels.is_some(), g.classify.channels.is_some()),
            Prepared::Paged(p, _) => (p.classify.labels.is_some(), p.classify.channels.is_some()),
        };
        if (labels || channels) && view.raycast.is_none() {
            view.raycast = Some(Default::default());
            let said = match labels {
                true => "segments from a label volume are drawn by the ray caster",
                false => "channels are mixed by the ray caster",
            };
            return (view, Some(said.into()));
        }
        (view, note)
    }

    /// One frame of `view` read back: in core at once, or through the brick cache once it is
    /// complete (see `render::bricked`), with what the streaming did.
    pub fn still(
        &mut self,
        view: &View,
        opts: StillOptions,
    ) -> Result<(FrameImage, Option<StreamReport>)> {
        match &mut self.prepared {
            Prepared::InCore(g) => {
                let frame = self
                    .renderer
                    .render_frame(&g.volume, &mut g.classify, view, true)?;
                Ok((frame, None))
            }
            Prepared::Paged(p, stream) => {
                let (frame, report) = self.renderer.render_bricked(
                    &mut p.volume,
                    &mut p.classify,
                    stream,
                    view,
                    opts,
                )?;
                Ok((frame, Some(report)))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_memory_budget_splits_into_chunks_and_bricks() {
        let opts = SessionOptions::default().with_memory_budget(Some(64.0), "--memory-budget");
        let opts = opts.unwrap();
        assert_eq!(opts.chunk_cache_bytes, Some(56 << 20));
        assert_eq!(opts.stream.ready_bytes, 8 << 20);
        let default = SessionOptions::default()
            .with_memory_budget(None, "x")
            .unwrap();
        assert_eq!(default.chunk_cache_bytes, Some(DEFAULT_MEMORY / 8 * 7));
        for bad in [0.5, f64::NAN, -3.0] {
            let e = SessionOptions::default()
                .with_memory_budget(Some(bad), "memory_budget")
                .unwrap_err()
                .to_string();
            assert!(
                e.starts_with("memory_budget ") && e.contains("at least 1 MiB"),
                "{e}"
            );
        }
    }
}
