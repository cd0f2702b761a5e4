//! Scenes: the whole composed render as a file ([`Scene`], JSON, versioned), and a volume prepared
//! on the GPU for rendering ([`GpuScene`]).
//!
//! ## The file
//! ```json
//! {"version": 1,
//!  "input": {"path": "../shared/data/volumes/cthead_stanford/cthead_stanford.nhdr"},
//!  "classification": {"transfer": "ct-skin-bone"},
//!  "focus": {"iso": 1300},
//!  "camera": {"azimuth": 0, "elevation": 0, "distance": 2.4},
//!  "size": [512, 512]}
//! ```
//! - `input`: `path` is a file, a DICOM folder or a phantom spec; `raw` describes a headerless
//!   file (`dims`, `type`, `big_endian`, `offset`, `spacing`). Relative paths, here and in
//!   `classification`, are relative to the scene file's folder.
//! - `classification`: one of `{"transfer": PRESET or FILE.json}`, `{"occlusion": OTF.json}` (an
//!   occlusion transfer function, which carries its AO radius and mapping) or
//!   `{"features": features.json}`.
//! - `focus`: `"none"`, `{"iso": V}` or `{"range": {"lo": A, "hi": B}}`, in data units.
//! - `camera`: `view` (anterior, posterior, left, right, superior, inferior) or `azimuth` and
//!   `elevation` in degrees; `distance` and `pan` in bounding-sphere radii; `ortho`; `fov_y`.
//!   Left out, the view is anterior with superior up for an oriented volume, and the distance
//!   fits the volume's projected bounding box (see [`CameraSpec`]); `size`, `slices` (null: two per voxel), `one_pass`, `background` (RGB behind the
//!   volume in PNGs), `lighting` (`ambient`, `diffuse`, `specular`, `shininess`).
//! - `modulation`: importance modulation (`classify::modulation::Modulation`): `color`
//!   (`{"mode": "raw"|"abs", "gamma": G}`), `opacity` (`{"t_low", "t_high", "k_low", "k_high"}`),
//!   `stipple` (`{"t", "f", "seed", "white", "black"}`), `importance_radius`, `apply_to`
//!   (`focus`, `context`, `both`) and `lighting` (`ambient`, `phong`).
//! - `style`: a perceptual style of the two-level paper, `{"style": 2 | "dog", "params": {..}}`
//!   (`render::style`). Styles 4–12 draw object-space lines; their `params` include
//!   `line_angle`, `line_derivative_threshold`, `line_depth_bias`, `line_stride`, `line_smooth`,
//!   `line_seeded` and `line_both`.
//!
//! Every key is checked: an unknown key is an error that names it.
//!
//! ## On the GPU
//! [`GpuScene::prepare`] runs the chain volume → normals → (occlusion) in one submission: the host
//! uploads the volume once, and the occlusion volume that an occlusion transfer function needs is
//! computed from the texture already on the GPU and sampled by the renderer where it lies.

use crate::classify::compose::{composed_table, composed_visibility};
use crate::classify::features::feature_transfer_function;
use crate::classify::mapping::parse_mapping;
use crate::classify::modulation::Modulation;
use crate::classify::otf::OcclusionTf;
use crate::classify::textures::GpuClassification;
use crate::classify::transfer::TransferFunction;
use crate::classify::{Classification, Focus};
use crate::passes::importance::ImportanceMap;
use crate::passes::normals::{GradientSource, Normals, VolumeTextures};
use crate::passes::occlusion::{Occlusion, OcclusionParams};
use crate::render::camera::Camera;
use crate::render::style::{Style, StyleParams};
use crate::render::view::{Lighting, View};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;
use vellum_error::{Error, Result};
use vellum_gpu::{Context, Frames, FramesDesc, PassTime};
use vellum_volume::io::http_store::is_url;
use vellum_volume::io::RawSpec;
use vellum_volume::{Volume, VoxelType};

/// The scene-file version this build reads and writes.
pub(crate) const SCENE_VERSION: u32 = 1;

/// A headerless input's layout.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawInput {
    /// Voxels along x, y, z.
    pub dims: [usize; 3],
    /// u8, u16, i16 or f32.
    #[serde(rename = "type")]
    pub voxel_type: String,
    /// Multi-byte voxels are stored most significant byte first (default false).
    #[serde(default)]
    pub big_endian: bool,
    /// Bytes to skip before the first voxel (default 0).
    #[serde(default)]
    pub offset: u64,
    /// Physical voxel size along x, y, z, in millimetres when `origin` is given (default 1).
    #[serde(default = "unit_spacing")]
    pub spacing: [f64; 3],
    /// Position of voxel (0,0,0) in LPS millimetres: the volume is then axis-aligned in LPS.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub origin: Option<[f64; 3]>,
}

fn unit_spacing() -> [f64; 3] {
    [1.0; 3]
}

/// What to load.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputSpec {
    /// A file, a DICOM folder or a phantom spec (`phantom:shepp-logan:128`).
    pub path: String,
    /// The layout of a headerless file at `path`; left out, the file describes itself.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub raw: Option<RawInput>,
    /// The time point of an OME-Zarr store with a t axis, from 0 (`--time`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time: Option<usize>,
    /// The channel of an OME-Zarr store with a c axis, from 0 (`--channels`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channel: Option<usize>,
    /// The values the renderer's intensity scale spans (the transfer function's 0 and 1);
    /// left out, the volume's own smallest and largest, or for a later time point of a series
    /// those of time point 0, so that the frames of a series compare.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub range: Option<[f64; 2]>,
    /// The `auto` line smoothing's radius (`--line-smooth auto`); left out, measured on the
    /// volume, or for a later time point of a series time point 0's, so that its lines compare.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub line_smooth: Option<u32>,
}

pub use crate::passes::normals::Scale;

impl InputSpec {
    /// The scale the input is drawn on, as given.
    pub fn scale(&self) -> Scale {
        Scale {
            range: self.range,
            line_smooth: self.line_smooth,
        }
    }

    /// The input at `path`, which describes itself, its only time point and channel.
    pub fn new(path: impl Into<String>) -> Self {
        InputSpec {
            path: path.into(),
            ..Default::default()
        }
    }

    /// The time point and channel to read from a store.
    pub fn pick(&self) -> vellum_volume::io::ome_zarr::Pick {
        vellum_volume::io::ome_zarr::Pick {
            time: self.time,
            channel: self.channel,
        }
    }
}

/// How samples are classified, as named in a scene file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum ClassificationSpec {
    /// A transfer-function preset or a JSON file.
    Transfer(String),
    /// An occlusion transfer function (JSON file).
    Occlusion(String),
    /// A feature map (features.json from `vellum migrate`).
    Features(String),
    /// A feature map composed with an occlusion transfer function (`classify::compose`): the
    /// features in their colours, the context by intensity and occlusion.
    Composed {
        /// The feature map file (features.json).
        features: String,
        /// The occlusion transfer function file (JSON).
        occlusion: String,
    },
}

impl ClassificationSpec {
    /// The spec with every file path it names passed through `f` (transfer-function presets are
    /// left alone).
    fn map_paths(&self, f: impl Fn(&str) -> String) -> Self {
        match self {
            ClassificationSpec::Transfer(t) if is_named(t) => self.clone(),
            ClassificationSpec::Transfer(t) => ClassificationSpec::Transfer(f(t)),
            ClassificationSpec::Occlusion(o) => ClassificationSpec::Occlusion(f(o)),
            ClassificationSpec::Features(m) => ClassificationSpec::Features(f(m)),
            ClassificationSpec::Composed {
                features,
                occlusion,
            } => ClassificationSpec::Composed {
                features: f(features),
                occlusion: f(occlusion),
            },
        }
    }
}

impl Default for ClassificationSpec {
    fn default() -> Self {
        ClassificationSpec::Transfer(crate::classify::window::AUTO.into())
    }
}

/// A named view of an oriented volume, in LPS patient space: where the eye is.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NamedView {
    /// The eye in front of the patient (azimuth 0°).
    Anterior,
    /// The eye behind the patient (azimuth 180°).
    Posterior,
    /// The eye on the patient's left (azimuth 90°).
    Left,
    /// The eye on the patient's right (azimuth −90°).
    Right,
    /// The eye above the head (elevation 90°).
    Superior,
    /// The eye below the feet (elevation −90°).
    Inferior,
}

impl NamedView {
    /// Azimuth and elevation in degrees (the camera's axes are the volume's world axes: LPS when
    /// the orientation is known, so azimuth 0 puts the eye on the anterior side with superior up).
    pub(crate) fn angles(self) -> (f32, f32) {
        match self {
            NamedView::Anterior => (0.0, 0.0),
            NamedView::Posterior => (180.0, 0.0),
            NamedView::Left => (90.0, 0.0),
            NamedView::Right => (-90.0, 0.0),
            NamedView::Superior => (0.0, 90.0),
            NamedView::Inferior => (0.0, -90.0),
        }
    }

    /// Parses a view name.
    pub fn parse(s: &str) -> Result<Self> {
        serde_json::from_value(serde_json::Value::String(s.to_lowercase())).map_err(|_| {
            Error::Invalid(format!(
                "view {s:?} is unknown; expected anterior, posterior, left, right, superior or inferior"
            ))
        })
    }
}

/// The camera, in the scene file's terms. Every field may be left out:
/// - `view` (a [`NamedView`]) or `azimuth` and `elevation` in degrees; without them, the anterior
///   view with superior up for a volume whose orientation is known, else azimuth 30, elevation 20
///   in the volume's own axes (+z up);
/// - `distance` in bounding-sphere radii; without it, the distance that fits the volume's projected
///   bounding box in the image with a 5 % margin.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraSpec {
    /// A named view; not together with `azimuth` or `elevation`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub view: Option<NamedView>,
    /// Azimuth in degrees; 0 puts the eye on the anterior side of an oriented volume.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub azimuth: Option<f32>,
    /// Elevation in degrees; 90 looks down from above (superior for an oriented volume).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub elevation: Option<f32>,
    /// Distance of the eye in bounding-sphere radii; left out, fitted to the volume.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub distance: Option<f32>,
    /// Orthographic projection instead of perspective.
    pub ortho: bool,
    /// Pan (x right, y up) in bounding-sphere radii.
    pub pan: [f32; 2],
    /// Vertical field of view in degrees.
    pub(crate) fov_y: f32,
}

impl Default for CameraSpec {
    fn default() -> Self {
        CameraSpec {
            view: None,
            azimuth: None,
            elevation: None,
            distance: None,
            ortho: false,
            pan: [0.0; 2],
            fov_y: DEFAULT_CAMERA.fov_y_deg,
        }
    }
}

/// The camera of a volume with no known orientation, without `--camera`.
pub const DEFAULT_CAMERA: Camera = Camera {
    azimuth_deg: 30.0,
    elevation_deg: 20.0,
    distance: 2.5,
    ortho: false,
    fov_y_deg: 50.0,
    pan: glam::Vec2::ZERO,
};

impl From<&Camera> for CameraSpec {
    fn from(c: &Camera) -> Self {
        CameraSpec {
            view: None,
            azimuth: Some(c.azimuth_deg),
            elevation: Some(c.elevation_deg),
            distance: Some(c.distance),
            ortho: c.ortho,
            pan: c.pan.to_array(),
            fov_y: c.fov_y_deg,
        }
    }
}

impl CameraSpec {
    /// The camera for a volume whose orientation is known (`oriented`) or not, checked, and
    /// whether its distance is to be fitted to the volume.
    pub fn camera(&self, oriented: bool) -> Result<(Camera, bool)> {
        let (az, el) = match (self.view, self.azimuth, self.elevation) {
            (Some(_), Some(_), _) | (Some(_), _, Some(_)) => return Err(Error::Invalid(
                "the camera gives both a named view and azimuth/elevation; expected one of them"
                    .into(),
            )),
            (Some(v), None, None) => v.angles(),
            (None, az, el) => {
                let (daz, del) = if oriented {
                    NamedView::Anterior.angles()
                } else {
                    (DEFAULT_CAMERA.azimuth_deg, DEFAULT_CAMERA.elevation_deg)
                };
                (az.unwrap_or(daz), el.unwrap_or(del))
            }
        };
        let c = Camera {
            azimuth_deg: az,
            elevation_deg: el,
            distance: self.distance.unwrap_or(DEFAULT_CAMERA.distance),
            ortho: self.ortho,
            fov_y_deg: self.fov_y,
            pan: glam::Vec2::from_array(self.pan),
        };
        c.validate()?;
        Ok((c, self.distance.is_none()))
    }
}

/// A perceptual style and its parameters, as the scene file holds them:
/// `{"style": 2 | "dog", "params": {"dog_sigma": 1.5, ...}}` (see `render::style::StyleParams`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StyleSpec {
    /// The paper's style number (1–15) or its name.
    pub style: serde_json::Value,
    /// The style's parameters; keys left out keep their defaults.
    #[serde(default)]
    pub params: StyleParams,
}

impl StyleSpec {
    /// The style, checked (unknown styles and bad parameters are refused).
    pub fn resolve(&self) -> Result<Style> {
        let name = match &self.style {
            serde_json::Value::String(s) => s.clone(),
            serde_json::Value::Number(n) => n.to_string(),
            other => {
                return Err(Error::Invalid(format!(
                    "style {other} is neither a number nor a name"
                )))
            }
        };
        Style::new(&name, self.params)
    }
}

/// The whole composed render.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// The file format's version; only `SCENE_VERSION` loads.
    pub version: u32,
    /// The volume to render.
    pub input: InputSpec,
    /// How samples are classified; left out, the automatic window (`auto`).
    #[serde(default)]
    pub classification: ClassificationSpec,
    /// The focus level of two-level frames, in data units; left out, none.
    #[serde(default)]
    pub focus: Focus,
    /// The camera; every key may be left out.
    #[serde(default)]
    pub camera: CameraSpec,
    /// Image width and height in pixels (default 512 × 512).
    #[serde(default = "default_size")]
    pub size: [u32; 2],
    /// Slice planes; null or left out, about two per voxel along the longest axis.
    #[serde(default)]
    pub slices: Option<u32>,
    /// Render every sample as context in one pass, without the focus level and its layers.
    #[serde(default)]
    pub one_pass: bool,
    /// RGB in [0, 1] behind the volume in PNG output (default black).
    #[serde(default)]
    pub background: [f32; 3],
    /// The Phong headlight's coefficients (`ambient`, `diffuse`, `specular`, `shininess`).
    #[serde(default)]
    pub lighting: Lighting,
    /// A perceptual style over the two levels; none by default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub style: Option<StyleSpec>,
    /// Importance modulation by ΔD (SPEC IM3–IM5, `classify::modulation`); none by default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modulation: Option<Modulation>,
    /// Ray cast with these options instead of slicing (`render::raycast`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub raycast: Option<crate::render::raycast::RayOptions>,
    /// Segments from a label volume beside the input (`classify::labels`); none by default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub labels: Option<crate::classify::labels::LabelSpec>,
    /// Several channels of the input store mixed in one ray (`classify::channels`); the input's
    /// own channel is the focus channel. None by default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channels: Option<crate::classify::channels::ChannelSpec>,
}

fn default_size() -> [u32; 2] {
    [512, 512]
}

/// Resolves `p` against `dir` unless it is absolute, a URL or a phantom spec.
fn resolve(dir: &Path, p: &str) -> String {
    if p.starts_with("phantom:") || Path::new(p).is_absolute() || is_url(Path::new(p)) {
        return p.to_string();
    }
    dir.join(p).to_string_lossy().into_owned()
}

/// Makes `p` absolute (for saving) unless it is a phantom spec or a preset name.
/// Whether a transfer function `t` is a name (a preset or `auto`) rather than a file.
fn is_named(t: &str) -> bool {
    crate::classify::transfer::PRESETS.contains(&t) || t == crate::classify::window::AUTO
}

fn absolute(p: &str) -> String {
    if p.starts_with("phantom:") || is_named(p) || is_url(Path::new(p)) {
        return p.to_string();
    }
    std::path::absolute(p)
        .map(|a| a.to_string_lossy().into_owned())
        .unwrap_or_else(|_| p.to_string())
}

impl Scene {
    /// A scene of `input` with every other field at its default.
    pub fn new(input: InputSpec) -> Self {
        Scene {
            version: SCENE_VERSION,
            input,
            classification: ClassificationSpec::default(),
            focus: Focus::None,
            camera: CameraSpec::default(),
            size: default_size(),
            slices: None,
            one_pass: false,
            background: [0.0; 3],
            lighting: Lighting::default(),
            style: None,
            modulation: None,
            raycast: None,
            labels: None,
            channels: None,
        }
    }

    /// Parses a scene from JSON; relative paths stay as written.
    pub fn from_json_str(json: &str) -> Result<Self> {
        let scene: Scene = serde_json::from_str(json).map_err(|e| Error::Invalid(e.to_string()))?;
        if scene.version != SCENE_VERSION {
            return Err(Error::Invalid(format!(
                "version {} is not supported; expected \"version\": {SCENE_VERSION}",
                scene.version
            )));
        }
        scene.validate()?;
        Ok(scene)
    }

    /// Reads a scene file, resolving its relative paths against the file's folder. Every error
    /// names the file.
    pub fn load(path: &Path) -> Result<Self> {
        let in_file = |e: Error| Error::Invalid(format!("scene file {}: {e}", path.display()));
        let text = vellum_volume::io::read_text(path)?;
        let mut scene = Scene::from_json_str(&text).map_err(in_file)?;
        let dir = path.parent().unwrap_or(Path::new("."));
        scene.input.path = resolve(dir, &scene.input.path);
        scene.classification = scene.classification.map_paths(|p| resolve(dir, p));
        if let Some(l) = &mut scene.labels {
            // A bare name that is no file beside the scene names a label image of the input
            // store's `labels` group.
            if dir.join(&l.path).exists() {
                l.path = resolve(dir, &l.path);
            }
        }
        Ok(scene)
    }

    /// Writes the scene as pretty JSON, atomically, with absolute paths so that it loads from any
    /// folder.
    pub fn save(&self, path: &Path) -> Result<()> {
        let mut s = self.clone();
        s.input.path = absolute(&s.input.path);
        s.classification = s.classification.map_paths(absolute);
        if let Some(l) = s.labels.as_mut().filter(|l| Path::new(&l.path).exists()) {
            l.path = absolute(&l.path);
        }
        let json = serde_json::to_string_pretty(&s)
            .map_err(|e| Error::Invalid(format!("scene cannot be written as JSON: {e}")))?;
        vellum_volume::output::write_atomic(path, |w| {
            use std::io::Write;
            writeln!(w, "{json}")
        })
    }

    /// Checks the values that serde's types do not: sizes, slices, background, lighting, camera.
    pub fn validate(&self) -> Result<()> {
        let [w, h] = self.size;
        if w == 0 || h == 0 {
            return Err(Error::Invalid(format!(
                "size {w}x{h} is invalid; expected at least 1 pixel per side"
            )));
        }
        if let Some(n) = self.slices {
            if n == 0 || n > crate::render::view::MAX_SLICES {
                return Err(Error::Invalid(format!(
                    "slices {n} is invalid; expected 1..={}",
                    crate::render::view::MAX_SLICES
                )));
            }
        }
        if !self.background.iter().all(|c| (0.0..=1.0).contains(c)) {
            return Err(Error::Invalid(format!(
                "background {:?} is invalid; expected R, G, B each in 0..1",
                self.background
            )));
        }
        self.focus.validate()?;
        self.lighting.validate()?;
        if let Some(m) = &self.modulation {
            m.validate()?;
        }
        self.camera.camera(false)?;
        Ok(())
    }

    /// The raw-file layout of the input, if any.
    pub(crate) fn raw_spec(&self) -> Result<Option<RawSpec>> {
        self.input
            .raw
            .as_ref()
            .map(|r| {
                Ok(RawSpec {
                    dims: r.dims,
                    voxel_type: VoxelType::parse(&r.voxel_type)?,
                    big_endian: r.big_endian,
                    offset: r.offset,
                    spacing: r.spacing,
                })
            })
            .transpose()
    }

    /// Loads the input volume whole, through the one opener (`vellum_volume::input::open`).
    pub fn load_volume(&self) -> Result<Volume> {
        let origin = self.input.raw.as_ref().and_then(|r| r.origin);
        vellum_volume::input::open(
            &self.input.path,
            self.raw_spec()?.as_ref(),
            origin,
            self.input.pick(),
        )
    }

    /// Loads the files the classification names.
    pub fn classification(&self) -> Result<Classification> {
        Ok(match &self.classification {
            ClassificationSpec::Transfer(t) if t == crate::classify::window::AUTO => {
                Classification::Auto
            }
            ClassificationSpec::Transfer(t) => {
                Classification::Transfer(TransferFunction::from_arg(t)?)
            }
            ClassificationSpec::Occlusion(f) => {
                Classification::Occlusion(OcclusionTf::load(Path::new(f))?)
            }
            ClassificationSpec::Features(f) => Classification::Features(self.feature_map(f)?),
            ClassificationSpec::Composed {
                features,
                occlusion,
            } => Classification::Composed(
                self.feature_map(features)?,
                OcclusionTf::load(Path::new(occlusion))?,
            ),
        })
    }

    /// Loads the feature map at `f` and checks that it names this scene's input.
    fn feature_map(&self, f: &str) -> Result<vellum_volume::feature::FeatureMap> {
        let map = vellum_volume::feature::FeatureMap::load(Path::new(f))?;
        if map.nodes.is_empty() {
            return Err(Error::Invalid(format!(
                "the feature map {f} holds no features; expected one made by `vellum migrate`"
            )));
        }
        // A map names the volume it was made for; rendering another one would colour
        // intervals that mean nothing there.
        let input = Path::new(&self.input.path).file_name();
        if let (Some(named), Some(input)) = (&map.volume, input) {
            if Path::new(named).file_name() != Some(input) {
                return Err(Error::Invalid(format!(
                    "the feature map {f} was made for {named}, not {}; expected the feature volume it describes",
                    input.to_string_lossy()
                )));
            }
        }
        Ok(map)
    }

    /// The view of a volume whose orientation is known (`oriented`) or not: camera (fitted to
    /// the volume when the scene gives no distance), size, slices, one pass or two levels,
    /// lighting, style.
    pub fn view(&self, oriented: bool) -> Result<View> {
        let (camera, fit) = self.camera.camera(oriented)?;
        Ok(View {
            camera,
            fit,
            size: self.size,
            slices: self.slices,
            one_pass: self.one_pass,
            lighting: self.lighting,
            style: self.style.as_ref().map(StyleSpec::resolve).transpose()?,
            raycast: self.raycast,
        })
    }
}

/// A volume prepared for rendering: its textures and normals, the occlusion volume when an
/// occlusion transfer function needs one, ΔD when modulation needs it, and the classification
/// (transfer-function textures, focus, modulation).
pub struct GpuScene {
    /// The volume's textures: intensity, gradients, and the occlusion volume and ΔD when needed.
    pub volume: VolumeTextures,
    /// Transfer-function textures, focus and modulation.
    pub classify: GpuClassification,
    /// GPU ms of `upload`, `sobel_normals`; for occlusion `to_float` and `occlusion`; for
    /// modulation `pack`, `gauss_x`, `gauss_y`, `gauss_z`, `subtract` and `unpack`.
    pub passes: Vec<PassTime>,
    /// The occlusion spectrum (256 × 256 bins) when an occlusion transfer function needed the
    /// occlusion volume: the viewer's occlusion editor draws over it.
    pub spectrum: Option<crate::passes::occlusion::Spectrum>,
}

/// What an occlusion transfer function asks of the occlusion pass: its radius, mapping and
/// stride, with the 256 × 256 spectrum the viewer's editor draws over.
pub fn occlusion_params(otf: &crate::classify::otf::OcclusionTf) -> Result<OcclusionParams> {
    let (visibility, neighbourhood) = parse_mapping(&otf.mapping)?;
    Ok(OcclusionParams {
        radius: otf.radius,
        visibility,
        neighbourhood,
        stride: otf.effective_stride(),
        spectrum_bins: Some([256, 256]),
        method: Default::default(),
        pad: None,
    })
}

/// The table and occlusion parameters of a feature map composed with an occlusion TF, on a
/// feature volume whose data range is `range`: the occlusion TF's mapping applies to each value's
/// original intensity (`classify::compose`).
fn composed(
    map: &vellum_volume::feature::FeatureMap,
    otf: &OcclusionTf,
    range: [f64; 2],
) -> Result<(Vec<[f32; 4]>, OcclusionParams)> {
    let mut params = occlusion_params(otf)?;
    params.visibility = composed_visibility(map, &params.visibility, range)?;
    Ok((composed_table(map, &otf.table()?, range)?, params))
}

/// A volume prepared for rendering through the brick cache: its pools, nothing resident yet,
/// and the classification.
pub struct PagedScene {
    /// The brick pools and cache of the volume.
    pub volume: crate::passes::paging::PagedVolume,
    /// Transfer-function textures, focus and modulation.
    pub classify: GpuClassification,
}

impl PagedScene {
    /// A volume for the brick cache (`volume::bricks`, `passes::paging`): pools of `budget_bytes`,
    /// nothing resident yet, and the classification. Occlusion transfer functions and importance
    /// modulation read whole-volume passes and are refused in one sentence naming the budget.
    pub fn prepare(
        ctx: &Arc<Context>,
        levels: Arc<vellum_volume::bricks::BrickLevels>,
        classification: &Classification,
        (focus, modulation): (Focus, &Modulation),
        budget_bytes: u64,
        finest: bool,
    ) -> Result<PagedScene> {
        focus.validate()?;
        let budget = budget_bytes as f64 / (1 << 20) as f64;
        if modulation.is_active() {
            return Err(Error::Invalid(format!(
                "importance modulation needs the importance map of the whole volume, which is larger than the GPU budget ({budget:.0} MiB); raise --gpu-budget or drop the modulation"
            )));
        }
        let transfer = match classification {
            Classification::Auto => {
                // The window from the finest level of at most 2 Mi voxels, as a channel's is
                // (`DESCRIBE_VOXELS`): its percentiles are the volume's to a bin or two, and a
                // level of 16 Mi voxels (64 MiB of floats) was read whole before the first
                // frame, 64 requests of a store on a server.
                let small =
                    levels.read_small_level(crate::classify::channels::DESCRIBE_VOXELS)?;
                crate::classify::window::auto(&small, levels.range())?
            }
            Classification::Transfer(tf) => tf.clone(),
            Classification::Features(map) => feature_transfer_function(map, levels.range())?,
            Classification::Occlusion(_) | Classification::Composed(..) => {
                return Err(Error::Invalid(format!(
                    "an occlusion transfer function needs the occlusion volume of the whole volume, which is larger than the GPU budget ({budget:.0} MiB); raise --gpu-budget or use a transfer function"
                )))
            }
        };
        let volume = crate::passes::paging::PagedVolume::new(ctx, levels, budget_bytes, finest)?;
        focus.check_in(volume.range)?;
        let classify = GpuClassification::new(ctx, &transfer, focus)?;
        Ok(PagedScene { volume, classify })
    }
}

impl GpuScene {
    /// Uploads `v`, computes its normals (occlusion when the classification needs it, ΔD when
    /// `modulation` is active) in one submission, and creates the classification textures.
    pub fn prepare(
        ctx: &Arc<Context>,
        v: &Volume,
        classification: &Classification,
        focus: Focus,
        modulation: &Modulation,
    ) -> Result<GpuScene> {
        Self::prepare_in_range(
            ctx,
            (v, Scale::default()),
            classification,
            focus,
            modulation,
        )
    }

    /// [`GpuScene::prepare`] on `scale` where it is given: the intensity scale spanning its
    /// range (values outside it clamp) rather than `v`'s own smallest and largest, and its line
    /// smoothing rather than `v`'s measured: a time point of a series on the series' scale.
    pub fn prepare_in_range(
        ctx: &Arc<Context>,
        input: (&Volume, Scale),
        classification: &Classification,
        focus: Focus,
        modulation: &Modulation,
    ) -> Result<GpuScene> {
        let normals = Normals::new(ctx)?;
        let (v, scale) = input;
        let input = (v, scale, GradientSource::Stored);
        Self::prepare_with(&normals, input, classification, focus, modulation)
    }

    /// [`GpuScene::prepare_in_range`] with the pipelines of `normals`, which a caller that
    /// prepares one volume after another (the viewer, a series' time points) builds once: on
    /// lavapipe, building them compiles the shader, a few milliseconds each time. Its gradients
    /// come from `source` (`sobel_normals` runs only for stored ones).
    pub fn prepare_with(
        normals: &Normals,
        (v, scale, source): (&Volume, Scale, GradientSource),
        classification: &Classification,
        focus: Focus,
        modulation: &Modulation,
    ) -> Result<GpuScene> {
        focus.validate()?;
        modulation.validate()?;
        let ctx = normals.context();
        let (mut volume, staging) = VolumeTextures::new_over(ctx, v, scale, source)?;
        focus.check_in(volume.range)?;
        let (transfer, otf) = match classification {
            Classification::Auto => (crate::classify::window::auto(v, volume.range)?, None),
            Classification::Transfer(tf) => (tf.clone(), None),
            Classification::Features(map) => {
                let s = vellum_volume::stats::stats(v, 0);
                (feature_transfer_function(map, [s.min, s.max])?, None)
            }
            Classification::Occlusion(otf) => (
                TransferFunction::preset("grey")?,
                Some((otf.table()?, occlusion_params(otf)?)),
            ),
            Classification::Composed(map, otf) => (
                TransferFunction::preset("grey")?,
                Some(composed(map, otf, volume.range)?),
            ),
        };
        let mut occlusion = match &otf {
            Some(_) => Some(Occlusion::new(ctx)?),
            None => None,
        };
        let mut importance = match modulation.is_active() {
            true => Some(ImportanceMap::new(ctx)?),
            false => None,
        };
        let mut frames = Frames::new(ctx, &FramesDesc::one_shot("prepare scene", 16))?;
        let ((occlusion_image, importance_volume, spectrum_buffer), _) = frames.frame(|f| {
            volume.record_upload(ctx, f, &staging);
            normals.record(f, &volume)?;
            let delta_d = match &mut importance {
                Some(map) => Some(map.record_from_texture(
                    f,
                    &volume.intensity,
                    volume.dims,
                    normals.nearest(),
                    modulation.importance_radius,
                )?),
                None => None,
            };
            let image = match (&mut occlusion, &otf) {
                (Some(occ), Some((_, p))) => {
                    let input = occ.record_input_from_texture(f, &volume, normals.nearest())?;
                    let mut targets = occ.targets(&input, p)?;
                    occ.record(f, &input, &mut targets, p)?;
                    // The input and work images drop here, mid-recording: their release is
                    // deferred until this frame completes (gpu/lifetime.rs).
                    let spectrum = targets.spectrum.take();
                    Some((targets.occlusion, spectrum))
                }
                _ => None,
            };
            let (image, spectrum) = match image {
                Some((i, s)) => (Some(i), s),
                None => (None, None),
            };
            Ok((image, delta_d, spectrum))
        })?;
        let passes = frames.finish()?;
        let spectrum =
            match spectrum_buffer {
                Some(b) => Some(crate::passes::occlusion::Spectrum {
                    bins: [256, 256],
                    counts: bytemuck::pod_collect_to_vec(b.mapped().ok_or_else(|| {
                        Error::Invalid("spectrum buffer is not host-visible".into())
                    })?),
                    intensity_range: volume.range,
                }),
                None => None,
            };
        volume.occlusion = occlusion_image;
        volume.importance = importance_volume;
        let mut classify = GpuClassification::new(ctx, &transfer, focus)?;
        classify.set_occlusion_table(otf.map(|(table, _)| table))?;
        classify.modulation = modulation.clone();
        Ok(GpuScene {
            volume,
            classify,
            passes,
            spectrum,
        })
    }
}
