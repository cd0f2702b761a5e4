//! The flags that describe a scene, turned into a [`Scene`] over a base one.

use crate::flags::*;
use anyhow::Result;
use clap::Args;
use std::path::PathBuf;
use vellum::render::overrides::{
    parse_channel_tf, parse_label_colour, CameraAngles, Front, SceneOverrides,
};
use vellum::render::scene::{InputSpec, NamedView, RawInput, Scene};

/// The scene a `render` command line describes: the scene file (or defaults) with every given
/// flag applied over it.
/// The flags that describe a scene: input, classification, focus, camera, size, planes,
/// renderer, background, modulation and style. `render`, `lines` and `view` take them alike, and
/// [`SceneArgs::apply`] is the one place that turns them into a [`Scene`].
#[derive(Args, Clone, Default)]
pub(crate) struct SceneArgs {
    /// File, DICOM folder, or phantom spec; overrides the scene file's input.
    pub(crate) input: Option<String>,
    #[command(flatten)]
    pub(crate) raw: RawArgs,
    /// An OME-Zarr store with a t axis: the time point to read, from 0; `render --time all
    /// --out DIR/` writes one PNG per time point.
    #[arg(long, value_name = "T|all", value_parser = parse_time)]
    pub(crate) time: Option<TimeArg>,
    /// An OME-Zarr store with a c axis: the channel to read, from 0; several (0,2) are mixed
    /// in one ray by the ray caster (at most 4, in core), each with its own transfer function.
    #[arg(long, value_name = "C[,C...]", value_delimiter = ',')]
    pub(crate) channels: Option<Vec<usize>>,
    /// Several channels: over (composited at each sample, the first on top; default), add
    /// (summed: the fluorescence look) or max (each channel's maximum along the ray).
    #[arg(long, value_name = "over|add|max")]
    pub(crate) mix: Option<String>,
    /// Several channels: channel C's transfer function, a preset or a JSON file over the
    /// channel's own range (repeatable; default: the store's omero colour and window, else a
    /// ramp over its auto window in green, magenta, cyan, yellow).
    #[arg(long, value_name = "C=PRESET|FILE")]
    pub(crate) channel_tf: Vec<String>,
    /// Several channels: the one the two levels, shading and importance work on (default: the
    /// first listed).
    #[arg(long, value_name = "C")]
    pub(crate) focus_channel: Option<usize>,
    /// A scene file (JSON); every flag given on the command line overrides its value.
    #[arg(long = "scene", value_name = "FILE")]
    pub(crate) file: Option<PathBuf>,
    /// Transfer function: auto (the grey ramp over the window from the 1st to the 99.5th
    /// percentile of the voxels above the background; for a mask or labels, opaque white from
    /// halfway between the two lowest values), a preset (grey, ct-bone, ct-skin-bone,
    /// mri-brain) or a JSON file [default: auto].
    #[arg(long)]
    pub(crate) tf: Option<String>,
    /// Focus: an interval of data values LO:HI.
    #[arg(long, value_name = "LO:HI", allow_hyphen_values = true)]
    pub(crate) focus: Option<String>,
    /// Focus: an isovalue in data units (an opaque surface).
    #[arg(long, value_name = "V", allow_negative_numbers = true)]
    pub(crate) iso: Option<f64>,
    /// Camera: azimuth and elevation in degrees (in LPS for an oriented volume: 0,0 is the anterior
    /// view), distance in bounding-sphere radii. Default: anterior for an oriented volume, else
    /// 30,20; without DIST the volume's projected bounding box fills the image.
    #[arg(long, value_name = "AZ,EL[,DIST]", allow_hyphen_values = true)]
    pub(crate) camera: Option<String>,
    /// A named view of an oriented volume: anterior, posterior, left, right, superior, inferior.
    #[arg(long, value_name = "NAME")]
    pub(crate) view: Option<String>,
    /// Orthographic instead of perspective projection.
    #[arg(long)]
    pub(crate) ortho: bool,
    /// Pan the view: X,Y in bounding-sphere radii (x right, y up).
    #[arg(long, value_name = "X,Y", allow_hyphen_values = true)]
    pub(crate) pan: Option<String>,
    /// Image size [default: 512x512].
    #[arg(long, value_name = "WxH", allow_hyphen_values = true)]
    pub(crate) size: Option<String>,
    /// Number of slice planes (default: two per voxel along the longest axis).
    #[arg(long)]
    pub(crate) slices: Option<u32>,
    /// The classic single pass instead of two levels.
    #[arg(long)]
    pub(crate) one_pass: bool,
    /// Renderer: view-aligned slicing, or ray casting at the same planes (same layers and styles).
    #[arg(long, value_name = "slicer|raycast")]
    pub(crate) renderer: Option<String>,
    /// Ray caster: jitter the sample planes per pixel with this seed (default: no jitter).
    #[arg(long, value_name = "SEED")]
    pub(crate) jitter: Option<u32>,
    /// Ray caster: stop a ray once its opacity reaches this, in (0, 1] [default: 0.99].
    #[arg(long, value_name = "A")]
    pub(crate) ert: Option<f32>,
    /// Ray caster: do not skip empty bricks.
    #[arg(long)]
    pub(crate) no_skip_empty: bool,
    /// Ray caster with --iso: refine the surface hit between planes (exact depth, no rings).
    #[arg(long)]
    pub(crate) refine_iso: bool,
    /// Ray caster: samples on the slicer's planes (default) or equal steps along each ray.
    #[arg(long, value_name = "planes|world-steps")]
    pub(crate) sampling: Option<String>,
    /// Background colour behind the volume in the PNG, as R,G,B in 0..1 [default: 0,0,0].
    #[arg(long, allow_hyphen_values = true)]
    pub(crate) background: Option<String>,
    /// Occlusion transfer function (JSON): colour and opacity over (intensity, occlusion).
    #[arg(long, conflicts_with = "tf")]
    pub(crate) otf: Option<PathBuf>,
    /// A feature map (features.json from `vellum migrate`): each feature gets its colour (FM6).
    /// With --otf, the two compose: features in their colours, the context by the occlusion TF.
    #[arg(long, conflicts_with = "tf")]
    pub(crate) features: Option<PathBuf>,
    /// A label volume on the input's grid: a file, a store, or the name of a label image in the
    /// input store's `labels` group. Each segment takes its colour (the store's NGFF colours,
    /// else one made from its id), sampled nearest; the ray caster draws them.
    #[arg(long, value_name = "PATH|NAME")]
    pub(crate) labels: Option<String>,
    /// Label ids not drawn, e.g. 2,5 (the background, 0, never is).
    #[arg(long, value_name = "IDS", value_delimiter = ',')]
    pub(crate) hide_labels: Option<Vec<u32>>,
    /// Label ids drawn as the focus level of the two levels; every other segment is the context.
    #[arg(long, value_name = "IDS", value_delimiter = ',')]
    pub(crate) focus_labels: Option<Vec<u32>>,
    /// A segment's colour, ID=#RRGGBB (repeatable).
    #[arg(long, value_name = "ID=#RRGGBB")]
    pub(crate) label_colour: Vec<String>,
    #[command(flatten)]
    pub(crate) modulation: ModulationArgs,
    #[command(flatten)]
    pub(crate) style: StyleArgs,
}

/// What `vellum view` opens without an input or a scene file.
#[cfg_attr(not(feature = "viewer"), allow(dead_code))]
const DEFAULT_VIEW_INPUT: &str = "phantom:shepp-logan:128";

impl SceneArgs {
    /// The scene the flags start from: the scene file (`--scene`), else a new scene of the
    /// input, else of `default_input`; `command` names the subcommand in the error.
    pub(crate) fn base(&self, default_input: Option<&str>, command: &str) -> Result<Scene> {
        let input = self.input.as_deref().or(default_input);
        match (&self.file, input) {
            (Some(path), _) => Ok(Scene::load(path)?),
            (None, Some(input)) => Ok(Scene::new(InputSpec::new(input.to_string()))),
            (None, None) => anyhow::bail!(
                "{command} needs an input (a file, DICOM folder or phantom spec) or --scene FILE"
            ),
        }
    }

    /// The scene these flags describe for `command`, which needs an input or a scene file.
    pub(crate) fn scene(&self, command: &str) -> Result<Scene> {
        self.apply(self.base(None, command)?)
    }

    /// The viewer's scene: the flags over the scene file, or over a new scene of the input (the
    /// Shepp–Logan phantom without one). Without a scene file or `--renderer`, the window's
    /// default renderer: the ray caster (3–4× the slicer's speed, BENCHMARKS.md) with jitter
    /// against slicing rings. With the same flags `render` builds the same scene.
    #[cfg_attr(not(feature = "viewer"), allow(dead_code))]
    pub(crate) fn view_scene(&self) -> Result<Scene> {
        let mut scene = self.apply(self.base(Some(DEFAULT_VIEW_INPUT), "view")?)?;
        if self.file.is_none() && self.renderer.is_none() {
            scene.raycast = Some(vellum::render::view::RayOptions {
                jitter: Some(1),
                ..Default::default()
            });
        }
        Ok(scene)
    }

    /// `scene` with every flag given applied over it, checked.
    pub(crate) fn apply(&self, scene: Scene) -> Result<Scene> {
        Ok(self.overrides()?.apply(scene)?)
    }

    /// The flags read as values: the one type of overrides the Python keywords fill too.
    pub(crate) fn overrides(&self) -> Result<SceneOverrides> {
        let a = self;
        let path_arg = |p: &Option<PathBuf>| p.as_ref().map(|p| p.to_string_lossy().into_owned());
        Ok(SceneOverrides {
            front: Front::Cli,
            input: a.input.clone(),
            raw: a.raw_input()?,
            time: match a.time {
                None => None,
                Some(TimeArg::One(t)) => Some(t),
                Some(TimeArg::All) => anyhow::bail!(
                    "--time all writes one image per time point, which only render does (render --time all --out DIR/); give one time point"
                ),
            },
            channels: a.channels.clone(),
            mix: a.mix.clone(),
            channel_tfs: a
                .channel_tf
                .iter()
                .map(|c| parse_channel_tf(c))
                .collect::<vellum::Result<_>>()?,
            focus_channel: a.focus_channel,
            tf: a.tf.clone(),
            otf: path_arg(&a.otf),
            features: path_arg(&a.features),
            focus: a
                .focus
                .as_deref()
                .map(|r| {
                    parse_interval(r).map_err(|_| {
                        anyhow::anyhow!(
                            "--focus '{r}' is not an interval LO:HI of data values with LO <= HI"
                        )
                    })
                })
                .transpose()?,
            iso: a.iso,
            camera: a.camera.as_deref().map(parse_camera).transpose()?,
            view: a.view.as_deref().map(NamedView::parse).transpose()?,
            ortho: a.ortho,
            pan: a.pan.as_deref().map(parse_pan).transpose()?,
            size: a.size.as_deref().map(parse_size).transpose()?,
            slices: a.slices,
            one_pass: a.one_pass.then_some(true),
            renderer: a.renderer.clone(),
            jitter: a.jitter,
            ert: a.ert,
            no_skip_empty: a.no_skip_empty,
            refine_iso: a.refine_iso,
            sampling: a.sampling.clone(),
            background: a
                .background
                .as_deref()
                .map(|b| parse_rgb("--background", b))
                .transpose()?,
            labels: a.labels.clone(),
            hide_labels: a.hide_labels.clone(),
            focus_labels: a.focus_labels.clone(),
            label_colours: a
                .label_colour
                .iter()
                .map(|c| parse_label_colour(c))
                .collect::<vellum::Result<_>>()?,
            modulation: a.modulation.overrides()?,
            style: a.style.overrides()?,
        })
    }

    /// How to read a headerless input, when the flags say.
    fn raw_input(&self) -> Result<Option<RawInput>> {
        let Some(raw) = self.raw.spec()? else {
            return Ok(None);
        };
        Ok(Some(RawInput {
            dims: raw.dims,
            voxel_type: raw.voxel_type.name().to_string(),
            big_endian: raw.big_endian,
            offset: raw.offset,
            spacing: raw.spacing,
            origin: self.raw.origin()?,
        }))
    }
}

/// `--time T` or `--time all`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum TimeArg {
    /// One time point, from 0.
    One(usize),
    /// Every time point, one image each (`render` only).
    All,
}

fn parse_time(s: &str) -> std::result::Result<TimeArg, String> {
    match s {
        "all" => Ok(TimeArg::All),
        _ => s
            .parse()
            .map(TimeArg::One)
            .map_err(|_| format!("'{s}' is not a time point (0, 1, ...) or all")),
    }
}

/// `--camera AZ,EL[,DIST]`: without DIST the volume is framed.
fn parse_camera(c: &str) -> Result<CameraAngles> {
    let parsed = vellum::render::camera::Camera::parse(c)?;
    Ok(CameraAngles {
        azimuth: parsed.azimuth_deg,
        elevation: parsed.elevation_deg,
        distance: (c.split(',').count() == 3).then_some(parsed.distance),
    })
}

/// `--pan X,Y` in bounding-sphere radii.
fn parse_pan(p: &str) -> Result<[f32; 2]> {
    let v: Vec<f32> = p.split(',').filter_map(|c| c.trim().parse().ok()).collect();
    anyhow::ensure!(
        v.len() == 2 && v.iter().all(|c| c.is_finite()),
        "--pan '{p}' is not X,Y in bounding-sphere radii"
    );
    Ok([v[0], v[1]])
}
