//! One type of scene overrides, filled by the command line's flags (clap, in the binary) and by
//! the Python keywords (PyO3) alike. Each flag and its keyword fill one field here, already read
//! as a value (`--size 512x512` and `size=(512, 512)` both become `[512, 512]`), and
//! [`SceneOverrides::apply`] is the one place that puts them over a scene: which combinations are
//! refused, what a flag keeps of the scene file's value, and the messages, which name the option
//! as the front end that filled it spells it ([`Front`]).

use crate::classify::channels::{ChannelSpec, Mix};
use crate::classify::labels::LabelSpec;
use crate::classify::modulation::{
    ApplyTo, ColorMode, ColorModulation, ModulateLighting, Modulation, OpacityModulation, Stipple,
};
use crate::classify::Focus;
use crate::render::camera::Camera;
use crate::render::raycast::Sampling;
use crate::render::scene::{ClassificationSpec, InputSpec, NamedView, RawInput, Scene, StyleSpec};
use crate::render::style::{EdgeKind, LineSmooth, StyleDef};
use crate::render::view::RayOptions;
use vellum_error::{Error, Result};

/// A channel's transfer function written `C=PRESET|FILE`: the channel and the function.
pub fn parse_channel_tf(s: &str) -> Result<(usize, String)> {
    let bad = || {
        invalid(format!(
            "channel transfer function {s:?} is not C=PRESET|FILE; expected a channel and a preset or file, such as 1=grey"
        ))
    };
    let (c, tf) = s.split_once('=').ok_or_else(bad)?;
    let c: usize = c.trim().parse().map_err(|_| bad())?;
    match tf.trim() {
        "" => Err(bad()),
        tf => Ok((c, tf.to_string())),
    }
}

/// A segment's colour written `ID=#RRGGBB` (or `ID=RRGGBB`): the id and its RGB.
pub fn parse_label_colour(s: &str) -> Result<(u32, [u8; 3])> {
    let bad = || {
        invalid(format!(
            "label colour {s:?} is not ID=#RRGGBB; expected an id and a hex colour, such as 3=#ff8000"
        ))
    };
    let (id, hex) = s.split_once('=').ok_or_else(bad)?;
    let id: u32 = id.trim().parse().map_err(|_| bad())?;
    let hex = hex.trim().trim_start_matches('#');
    if hex.len() != 6 || !hex.is_ascii() {
        return Err(bad());
    }
    let byte = |i: usize| u8::from_str_radix(&hex[i..i + 2], 16).map_err(|_| bad());
    Ok((id, [byte(0)?, byte(2)?, byte(4)?]))
}

/// Which front end filled the overrides, so that a message names an option as its user typed
/// it: `--edge-threshold` on the command line, `edge_threshold=` in Python.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Front {
    /// The `vellum` command line.
    #[default]
    Cli,
    /// The Python package's keyword arguments.
    Python,
}

impl Front {
    /// The option `key` (snake case, as in Python) as this front end spells it: `--edge-threshold`
    /// or `edge_threshold`.
    pub fn name(self, key: &str) -> String {
        match self {
            Front::Cli => format!("--{}", key.replace('_', "-")),
            Front::Python => key.to_string(),
        }
    }

    /// The option `key` given `value`, as this front end's user writes it: `--renderer raycast`
    /// or `renderer="raycast"` (a word is quoted in Python, a pattern such as `N|NAME` is not).
    pub(crate) fn with(self, key: &str, value: &str) -> String {
        match self {
            Front::Cli => format!("{} {value}", self.name(key)),
            Front::Python if value.chars().all(|c| c.is_ascii_alphabetic() || c == '-') => {
                format!("{key}=\"{value}\"")
            }
            Front::Python => format!("{key}={value}"),
        }
    }
}

/// The camera's angles as given: azimuth and elevation in degrees and, when given, the distance
/// in bounding-sphere radii. Without a distance the volume is framed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraAngles {
    /// Azimuth in degrees.
    pub azimuth: f32,
    /// Elevation in degrees, in [−90, 90].
    pub elevation: f32,
    /// Distance of the eye in bounding-sphere radii (> 1), or none to frame the volume.
    pub distance: Option<f32>,
}

/// The perceptual style and its parameters (SPEC TL4–TL7), each over the scene's value.
#[derive(Clone, Debug, Default)]
pub struct StyleOverrides {
    /// A style of the two-level paper by number (1–15) or name.
    pub style: Option<String>,
    /// Edge colour, R, G, B in 0..1.
    pub edge_color: Option<[f32; 3]>,
    /// Edge opacity in [0, 1].
    pub edge_opacity: Option<f32>,
    /// Edge width in pixels.
    pub edge_width: Option<u32>,
    /// The threshold of the style's edge detector (Sobel's, DoG's ε or Canny's high one).
    pub edge_threshold: Option<f32>,
    /// σ in pixels of the DoG's narrow Gaussian and of Canny's smoothing.
    pub sigma: Option<f32>,
    /// Ratio of the DoG's wide σ to its narrow one.
    pub dog_k: Option<f32>,
    /// Kuwahara radius in pixels, 1..=16.
    pub kuwahara_radius: Option<i64>,
    /// Saturation factor of the context (style 14).
    pub saturation: Option<f32>,
    /// θ_c of suggestive contours, in degrees.
    pub line_angle: Option<f32>,
    /// The least D_w κ_r of a suggestive contour, per mm².
    pub line_threshold: Option<f32>,
    /// How far behind the focus surface a line still shows, in voxels.
    pub line_bias: Option<f32>,
    /// Visit every Nth cell.
    pub line_stride: Option<u32>,
    /// Smoothing of the volume before the lines.
    pub line_smooth: Option<LineSmooth>,
    /// Lines by the seeded traversal.
    pub line_seeded: bool,
}

/// Importance modulation (SPEC IM3–IM5), each over the scene's value.
#[derive(Clone, Debug, Default)]
pub struct ModulationOverrides {
    /// Colour modulation by raw ΔD (eq. 3) or |ΔD| (eq. 4): `raw` or `abs`.
    pub color_mod: Option<String>,
    /// γ of colour modulation, per normalised-intensity unit of ΔD.
    pub gamma: Option<f32>,
    /// Opacity modulation (eq. 5): t_l, t_h, k_l, k_h.
    pub opacity_mod: Option<[f32; 4]>,
    /// Stippling (eq. 6): threshold t and density factor f.
    pub stipple: Option<[f32; 2]>,
    /// Seed of the stipple pattern.
    pub seed: Option<u32>,
    /// The stipple's light colour, R, G, B in 0..1.
    pub stipple_white: Option<[f32; 3]>,
    /// The stipple's dark colour, R, G, B in 0..1.
    pub stipple_black: Option<[f32; 3]>,
    /// Radius R of the importance map's Gaussian, in voxels.
    pub importance_radius: Option<u32>,
    /// Which level is modulated: `focus`, `context` or `both`.
    pub modulate: Option<String>,
    /// What colour modulation adds to: `ambient` or `phong`.
    pub modulate_lighting: Option<String>,
}

/// Everything a front end may set over a scene: the command line's scene flags and the Python
/// keywords of `render` and `Renderer`, one field each. Left at its default, a field keeps the
/// scene's value.
#[derive(Clone, Debug, Default)]
pub struct SceneOverrides {
    /// Who filled these, for the messages.
    pub front: Front,
    /// The input (a file, a DICOM folder, a store or a phantom spec), replacing the scene's.
    pub input: Option<String>,
    /// How to read a headerless input (the scene's input, or the one given).
    pub raw: Option<RawInput>,
    /// The time point of a store with a t axis.
    pub time: Option<usize>,
    /// The channels of a store with a c axis: one is read as the volume; several are mixed in
    /// one ray.
    pub channels: Option<Vec<usize>>,
    /// How several channels are mixed: `over`, `add` or `max`.
    pub mix: Option<String>,
    /// Transfer functions by channel (a preset or a JSON file).
    pub channel_tfs: Vec<(usize, String)>,
    /// The channel the two levels, shading and the passes work on (default: the first listed).
    pub focus_channel: Option<usize>,
    /// A transfer function: `auto`, a preset or a JSON file.
    pub tf: Option<String>,
    /// An occlusion transfer function (JSON file).
    pub otf: Option<String>,
    /// A feature map (features.json).
    pub features: Option<String>,
    /// The focus as an interval [lo, hi] of data values.
    pub focus: Option<[f64; 2]>,
    /// The focus as an isovalue in data units.
    pub iso: Option<f64>,
    /// The camera's angles.
    pub camera: Option<CameraAngles>,
    /// A named view of an oriented volume.
    pub view: Option<NamedView>,
    /// Orthographic projection.
    pub ortho: bool,
    /// Pan, x right and y up, in bounding-sphere radii.
    pub pan: Option<[f32; 2]>,
    /// Image size in pixels.
    pub size: Option<[u32; 2]>,
    /// Number of slice planes.
    pub slices: Option<u32>,
    /// One level instead of two.
    pub one_pass: Option<bool>,
    /// The renderer: `slicer` or `raycast`.
    pub renderer: Option<String>,
    /// The ray caster's jitter seed.
    pub jitter: Option<u32>,
    /// The ray caster's early-termination opacity, in (0, 1].
    pub ert: Option<f32>,
    /// The ray caster without empty-space skipping.
    pub no_skip_empty: bool,
    /// The ray caster refines an isosurface's hit between planes.
    pub refine_iso: bool,
    /// The ray caster's sampling: `planes` or `world-steps`.
    pub sampling: Option<String>,
    /// The background, R, G, B in 0..1.
    pub background: Option<[f32; 3]>,
    /// A label volume beside the input: a file, a store, or the name of a label image in the
    /// input store's `labels` group.
    pub labels: Option<String>,
    /// Label ids not drawn.
    pub hide_labels: Option<Vec<u32>>,
    /// Label ids drawn as the focus level, every other segment as the context.
    pub focus_labels: Option<Vec<u32>>,
    /// Segments' colours, each `ID=#RRGGBB` ([`parse_label_colour`]).
    pub label_colours: Vec<(u32, [u8; 3])>,
    /// Importance modulation.
    pub modulation: ModulationOverrides,
    /// The style.
    pub style: StyleOverrides,
}

impl SceneOverrides {
    /// `scene` with every override given put over it, checked.
    pub fn apply(&self, mut scene: Scene) -> Result<Scene> {
        let f = self.front;
        if let Some(path) = &self.input {
            scene.input = InputSpec::new(path.clone());
        }
        if let Some(raw) = &self.raw {
            scene.input.raw = Some(raw.clone());
        }
        self.apply_pick(&mut scene)?;
        self.apply_classification(&mut scene);
        match (self.focus, self.iso) {
            (Some(_), Some(_)) => {
                return Err(invalid(format!(
                    "give either {} or {}, not both",
                    f.with("focus", "LO:HI"),
                    f.with("iso", "V")
                )))
            }
            (None, Some(v)) if !v.is_finite() => {
                return Err(invalid(format!("{} needs a finite value", f.name("iso"))))
            }
            (None, Some(v)) => scene.focus = Focus::Iso(v),
            (Some([lo, hi]), None) if lo.partial_cmp(&hi).is_none_or(|o| o.is_gt()) => {
                return Err(invalid(format!(
                    "{} {lo}:{hi} is not an interval of data values with LO <= HI",
                    f.name("focus")
                )))
            }
            (Some([lo, hi]), None) => scene.focus = Focus::Range { lo, hi },
            (None, None) => {}
        }
        self.apply_labels(&mut scene)?;
        self.apply_camera(&mut scene)?;
        if let Some(size) = self.size {
            scene.size = size;
        }
        if let Some(n) = self.slices {
            scene.slices = Some(n);
        }
        if let Some(one) = self.one_pass {
            scene.one_pass = one;
        }
        self.apply_renderer(&mut scene)?;
        if let Some(b) = self.background {
            scene.background = b;
        }
        if scene.one_pass && matches!(scene.focus, Focus::Range { .. }) {
            return Err(invalid(format!(
                "{} draws a single level, which a {} interval would not change; drop one of them ({} does work in one pass: it makes the surface opaque)",
                f.name("one_pass"),
                f.with("focus", "LO:HI"),
                f.with("iso", "V")
            )));
        }
        scene.modulation = self.modulation.apply(f, scene.modulation.take())?;
        scene.style = self.style.apply(f, scene.style.take())?;
        self.check_projection(&mut scene)?;
        scene.validate()?;
        Ok(scene)
    }

    /// `labels`, `hide_labels`, `focus_labels` and `label_colour`: segments from a label volume.
    fn apply_labels(&self, scene: &mut Scene) -> Result<()> {
        let f = self.front;
        if let Some(path) = &self.labels {
            scene.labels = Some(LabelSpec {
                path: path.clone(),
                ..Default::default()
            });
        }
        let given = [
            ("hide_labels", self.hide_labels.is_some()),
            ("focus_labels", self.focus_labels.is_some()),
            ("label_colour", !self.label_colours.is_empty()),
        ];
        let Some(spec) = scene.labels.as_mut() else {
            return match given.iter().find(|g| g.1) {
                Some((key, _)) => Err(invalid(format!(
                    "{} picks segments of a label volume; add {}",
                    f.name(key),
                    f.with("labels", "PATH|NAME")
                ))),
                None => Ok(()),
            };
        };
        if let Some(h) = &self.hide_labels {
            spec.hide = h.clone();
        }
        if let Some(ids) = &self.focus_labels {
            spec.focus = ids.clone();
        }
        for &(id, rgb) in &self.label_colours {
            spec.colours.retain(|c| c.0 != id);
            spec.colours.push((id, rgb));
        }
        if !spec.focus.is_empty() && scene.focus != Focus::None {
            return Err(invalid(format!(
                "{} and the focus interval or isovalue both choose the focus level; give {}, {} or {}",
                f.name("focus_labels"),
                f.name("focus_labels"),
                f.with("focus", "LO:HI"),
                f.with("iso", "V")
            )));
        }
        Ok(())
    }

    /// `time` and `channels`: which time point and channel of a store to read.
    fn apply_pick(&self, scene: &mut Scene) -> Result<()> {
        let f = self.front;
        if let Some(t) = self.time {
            scene.input.time = Some(t);
        }
        let needs_several = [
            ("mix", self.mix.is_some()),
            ("channel_tf", !self.channel_tfs.is_empty()),
            ("focus_channel", self.focus_channel.is_some()),
        ];
        match self.channels.as_deref() {
            None | Some([]) => {}
            Some([c]) => {
                scene.input.channel = Some(*c);
                scene.channels = None;
            }
            Some(several) => {
                let mix = match &self.mix {
                    Some(m) => Mix::parse(m)?,
                    None => Mix::default(),
                };
                let focus = self.focus_channel.unwrap_or(several[0]);
                if !several.contains(&focus) {
                    return Err(invalid(format!(
                        "{} {focus} is not among {} {several:?}; expected one of them",
                        f.name("focus_channel"),
                        f.name("channels")
                    )));
                }
                scene.input.channel = Some(focus);
                scene.channels = Some(ChannelSpec {
                    channels: several.to_vec(),
                    mix,
                    tfs: self.channel_tfs.clone(),
                    scales: Vec::new(),
                });
                return Ok(());
            }
        }
        if scene.channels.is_none() {
            if let Some((key, _)) = needs_several.iter().find(|n| n.1) {
                return Err(invalid(format!(
                    "{} mixes several channels of a store; add {}",
                    f.name(key),
                    f.with("channels", "0,1")
                )));
            }
        }
        Ok(())
    }

    /// `mix add` and `mix max` are projections of one level: they refuse what works on two.
    fn check_projection(&self, scene: &mut Scene) -> Result<()> {
        let f = self.front;
        let Some(mix) = scene
            .channels
            .as_ref()
            .map(|c| c.mix)
            .filter(|m| *m != Mix::Over)
        else {
            return Ok(());
        };
        if scene.focus != Focus::None || scene.style.is_some() || scene.labels.is_some() {
            let name = if mix == Mix::Add { "add" } else { "max" };
            return Err(invalid(format!(
                "{} projects the channels on one level, without a focus, styles or labels; drop those, or mix by over",
                f.with("mix", name)
            )));
        }
        scene.one_pass = true;
        Ok(())
    }

    /// `tf`, `otf` and `features`: the occlusion TF and the feature map given together compose.
    fn apply_classification(&self, scene: &mut Scene) {
        if let Some(tf) = &self.tf {
            scene.classification = ClassificationSpec::Transfer(tf.clone());
        }
        match (&self.otf, &self.features) {
            (Some(o), Some(f)) => {
                scene.classification = ClassificationSpec::Composed {
                    features: f.clone(),
                    occlusion: o.clone(),
                }
            }
            (Some(o), None) => scene.classification = ClassificationSpec::Occlusion(o.clone()),
            (None, Some(f)) => scene.classification = ClassificationSpec::Features(f.clone()),
            (None, None) => {}
        }
    }

    /// `camera`, `view`, `ortho` and `pan`.
    fn apply_camera(&self, scene: &mut Scene) -> Result<()> {
        let f = self.front;
        if self.camera.is_some() && self.view.is_some() {
            return Err(invalid(format!(
                "give either {} or {}, not both",
                f.with("camera", "AZ,EL[,DIST]"),
                f.with("view", "NAME")
            )));
        }
        if let Some(c) = self.camera {
            Camera {
                azimuth_deg: c.azimuth,
                elevation_deg: c.elevation,
                distance: c.distance.unwrap_or(Camera::default().distance),
                ..Camera::default()
            }
            .validate()?;
            scene.camera.view = None;
            scene.camera.azimuth = Some(c.azimuth);
            scene.camera.elevation = Some(c.elevation);
            // Without a distance the volume is framed.
            scene.camera.distance = c.distance;
        }
        if let Some(v) = self.view {
            scene.camera.view = Some(v);
            scene.camera.azimuth = None;
            scene.camera.elevation = None;
        }
        if self.ortho {
            scene.camera.ortho = true;
        }
        if let Some(p) = self.pan {
            if !p.iter().all(|c| c.is_finite()) {
                return Err(invalid(format!(
                    "{} {p:?} is not X,Y in bounding-sphere radii",
                    f.name("pan")
                )));
            }
            scene.camera.pan = p;
        }
        Ok(())
    }

    /// `renderer` and the ray caster's options, which need the ray caster.
    fn apply_renderer(&self, scene: &mut Scene) -> Result<()> {
        let f = self.front;
        match self.renderer.as_deref() {
            None => {}
            Some("slicer") => scene.raycast = None,
            Some("raycast") => scene.raycast = Some(scene.raycast.unwrap_or_default()),
            Some(other) => {
                return Err(invalid(format!(
                    "{} {other:?} is unknown; expected slicer or raycast",
                    f.name("renderer")
                )))
            }
        }
        let ray_options = self.jitter.is_some()
            || self.ert.is_some()
            || self.no_skip_empty
            || self.refine_iso
            || self.sampling.is_some();
        let Some(r) = &mut scene.raycast else {
            if !ray_options {
                return Ok(());
            }
            let names = ["jitter", "ert", "no_skip_empty", "refine_iso"].map(|k| f.name(k));
            return Err(invalid(format!(
                "{} and {} set the ray caster; add {}",
                names.join(", "),
                f.name("sampling"),
                f.with("renderer", "raycast")
            )));
        };
        apply_ray_options(self, r)
    }
}

/// The ray caster's options over `r`, checked.
fn apply_ray_options(o: &SceneOverrides, r: &mut RayOptions) -> Result<()> {
    if let Some(seed) = o.jitter {
        r.jitter = Some(seed);
    }
    if let Some(ert) = o.ert {
        r.ert = ert;
    }
    if o.no_skip_empty {
        r.skip_empty = false;
    }
    if o.refine_iso {
        r.refine_iso = true;
    }
    if let Some(s) = &o.sampling {
        r.sampling = Sampling::parse(s)?;
    }
    r.validate()
}

impl StyleOverrides {
    /// Whether any of the style's parameters is given.
    fn params_given(&self) -> bool {
        self.edge_color.is_some()
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
            || self.line_smooth.is_some()
    }

    /// The style over `spec` (the scene's), checked; a style given keeps the scene's parameters.
    pub fn apply(&self, f: Front, spec: Option<StyleSpec>) -> Result<Option<StyleSpec>> {
        let given = self.params_given();
        let mut spec = match (&self.style, spec) {
            (Some(s), old) => StyleSpec {
                style: serde_json::Value::String(s.clone()),
                params: old.map(|o| o.params).unwrap_or_default(),
            },
            // Checked with the scene file's name when the view is made.
            (None, Some(old)) if !given => return Ok(Some(old)),
            (None, Some(old)) => old,
            (None, None) if given => {
                return Err(invalid(format!(
                    "the style {} need {}",
                    match f {
                        Front::Cli => "flags",
                        Front::Python => "keywords",
                    },
                    f.with("style", "N|NAME")
                )))
            }
            (None, None) => return Ok(None),
        };
        let name = match &spec.style {
            serde_json::Value::String(s) => s.clone(),
            other => other.to_string(),
        };
        let def = StyleDef::find(&name)?;
        self.set_params(f, def, &mut spec)?;
        spec.resolve()?;
        Ok(Some(spec))
    }

    /// The parameters given, over `spec`'s, for the style `def`.
    fn set_params(&self, f: Front, def: &StyleDef, spec: &mut StyleSpec) -> Result<()> {
        let p = &mut spec.params;
        if let Some(c) = self.edge_color {
            check_rgb(f, "edge_color", c)?;
            p.edge_color = c;
        }
        set(&mut p.edge_opacity, self.edge_opacity);
        set(&mut p.edge_width, self.edge_width);
        if let Some(t) = self.edge_threshold {
            match def.edges {
                Some(EdgeKind::Sobel) => p.sobel_threshold = t,
                Some(EdgeKind::Dog) => p.dog_threshold = t,
                Some(EdgeKind::Canny) => p.canny_high = t,
                None => {
                    return Err(invalid(format!(
                        "{} has no effect on style {} ({}), which draws no image-space edges",
                        f.name("edge_threshold"),
                        def.number,
                        def.name
                    )))
                }
            }
        }
        if let Some(v) = self.sigma {
            p.dog_sigma = v;
            p.canny_sigma = v;
        }
        set(&mut p.dog_k, self.dog_k);
        if let Some(r) = self.kuwahara_radius {
            if !(1..=16).contains(&r) {
                return Err(invalid(format!(
                    "Kuwahara radius {r} is invalid; expected 1..=16 pixels"
                )));
            }
            p.kuwahara_radius = r as u32;
        }
        set(&mut p.saturation, self.saturation);
        set(&mut p.line_angle, self.line_angle);
        set(&mut p.line_derivative_threshold, self.line_threshold);
        set(&mut p.line_depth_bias, self.line_bias);
        set(&mut p.line_stride, self.line_stride);
        set(&mut p.line_smooth, self.line_smooth);
        if self.line_seeded {
            p.line_seeded = true;
        }
        Ok(())
    }
}

impl ModulationOverrides {
    /// Whether any modulation option is given.
    fn given(&self) -> bool {
        self.color_mod.is_some()
            || self.gamma.is_some()
            || self.opacity_mod.is_some()
            || self.stipple.is_some()
            || self.seed.is_some()
            || self.stipple_white.is_some()
            || self.stipple_black.is_some()
            || self.importance_radius.is_some()
            || self.modulate.is_some()
            || self.modulate_lighting.is_some()
    }

    /// The modulation over `m` (the scene's), checked; one given must have an effect.
    pub fn apply(&self, f: Front, m: Option<Modulation>) -> Result<Option<Modulation>> {
        if !self.given() {
            return Ok(m);
        }
        let mut m = m.unwrap_or_default();
        self.apply_color(f, &mut m)?;
        if let Some([t_low, t_high, k_low, k_high]) = self.opacity_mod {
            m.opacity = Some(OpacityModulation {
                t_low,
                t_high,
                k_low,
                k_high,
            });
        }
        self.apply_stipple(f, &mut m)?;
        set(&mut m.importance_radius, self.importance_radius);
        if let Some(a) = &self.modulate {
            m.apply_to = match a.as_str() {
                "focus" => ApplyTo::Focus,
                "context" => ApplyTo::Context,
                "both" => ApplyTo::Both,
                other => return Err(unknown(f, "modulate", other, "focus, context or both")),
            };
        }
        if let Some(l) = &self.modulate_lighting {
            m.lighting = match l.as_str() {
                "ambient" => ModulateLighting::Ambient,
                "phong" => ModulateLighting::Phong,
                other => return Err(unknown(f, "modulate_lighting", other, "ambient or phong")),
            };
        }
        if !m.is_active() {
            return Err(invalid(format!(
                "the modulation {} need an effect: {} with {}, {} or {}",
                match f {
                    Front::Cli => "flags",
                    Front::Python => "keywords",
                },
                f.name("color_mod"),
                f.name("gamma"),
                f.name("opacity_mod"),
                f.name("stipple"),
            )));
        }
        m.validate()?;
        Ok(Some(m))
    }

    /// `color_mod` and `gamma`: a mode needs γ; γ alone changes the scene's colour modulation.
    fn apply_color(&self, f: Front, m: &mut Modulation) -> Result<()> {
        match (&self.color_mod, self.gamma) {
            (Some(mode), Some(gamma)) => {
                let mode = match mode.as_str() {
                    "raw" => ColorMode::Raw,
                    "abs" => ColorMode::Abs,
                    other => return Err(unknown(f, "color_mod", other, "raw or abs")),
                };
                m.color = Some(ColorModulation { mode, gamma });
            }
            (Some(_), None) => {
                return Err(invalid(format!(
                    "{} needs {}",
                    f.name("color_mod"),
                    f.with("gamma", "G")
                )))
            }
            (None, Some(gamma)) => match &mut m.color {
                Some(c) => c.gamma = gamma,
                None => {
                    return Err(invalid(format!(
                        "{} needs {}",
                        f.name("gamma"),
                        f.with("color_mod", "raw|abs")
                    )))
                }
            },
            (None, None) => {}
        }
        Ok(())
    }

    /// `stipple` and its seed and colours, which need a stipple.
    fn apply_stipple(&self, f: Front, m: &mut Modulation) -> Result<()> {
        if let Some([t, fac]) = self.stipple {
            let old = m.stipple;
            m.stipple = Some(Stipple {
                t,
                f: fac,
                seed: old.map_or(0, |s| s.seed),
                white: old.map_or([1.0; 3], |s| s.white),
                black: old.map_or([0.0; 3], |s| s.black),
            });
        }
        let needs = |key: &str| {
            invalid(format!(
                "{} needs {}",
                f.name(key),
                f.with("stipple", "T,F")
            ))
        };
        if let Some(seed) = self.seed {
            m.stipple.as_mut().ok_or_else(|| needs("seed"))?.seed = seed;
        }
        if let Some(c) = self.stipple_white {
            check_rgb(f, "stipple_white", c)?;
            m.stipple
                .as_mut()
                .ok_or_else(|| needs("stipple_white"))?
                .white = c;
        }
        if let Some(c) = self.stipple_black {
            check_rgb(f, "stipple_black", c)?;
            m.stipple
                .as_mut()
                .ok_or_else(|| needs("stipple_black"))?
                .black = c;
        }
        Ok(())
    }
}

/// Sets `slot` to `value` when one is given.
fn set<T>(slot: &mut T, value: Option<T>) {
    if let Some(v) = value {
        *slot = v;
    }
}

/// A colour given for `key` must have each channel in 0..1.
fn check_rgb(f: Front, key: &str, c: [f32; 3]) -> Result<()> {
    if c.iter().all(|v| (0.0..=1.0).contains(v)) {
        Ok(())
    } else {
        Err(invalid(format!(
            "{} {c:?} is not R,G,B with each in 0..1",
            f.name(key)
        )))
    }
}

fn unknown(f: Front, key: &str, value: &str, expected: &str) -> Error {
    invalid(format!(
        "{} '{value}' is unknown; expected {expected}",
        f.name(key)
    ))
}

fn invalid(message: String) -> Error {
    Error::Invalid(message)
}
