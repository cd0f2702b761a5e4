//! The 15 styles of the two-level paper's study (§4, SPEC TL7), by number and name, and their
//! parameters. One table says what each style is made of; `render/post.rs` records the passes.
//!
//! Styles 4–12 draw object-space lines (silhouettes, suggestive contours; `volume::lines`,
//! `passes::lines`) into the same edge layer as the image-space detectors, depth-tested against
//! the focus, so the composite draws both in the edge colour.

use serde::{Deserialize, Serialize};
use vellum_error::{Error, Result};

/// An image-space edge detector on the focus layer (TL4).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum EdgeKind {
    /// Thresholded Sobel gradient magnitude of the luminance (`sobel_threshold`).
    Sobel,
    /// Difference of Gaussians with XDoG's soft threshold (the `dog_*` parameters).
    Dog,
    /// Canny: non-maximum suppression, double threshold and hysteresis (the `canny_*` parameters).
    Canny,
}

/// Object-space lines (TL5).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum LineKind {
    /// Silhouettes of the isosurface: where n·v = 0.
    Silhouettes,
    /// Suggestive contours: κ_r = 0 with D_w κ_r > t_d, on the front-facing surface.
    SuggestiveContours,
}

/// Abstraction of the context layer (TL6).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(crate) enum Abstraction {
    /// The four-quadrant Kuwahara filter of radius `kuwahara_radius` pixels.
    Kuwahara,
    /// Saturation variation of the context colours by the factor `saturation`.
    Saturation,
}

/// One style of the table.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct StyleDef {
    /// The paper's number, 1–15.
    pub number: u32,
    /// Its name: lower case, parts joined by `+`.
    pub name: &'static str,
    /// The image-space edge detector run on the focus layer, if any.
    pub edges: Option<EdgeKind>,
    /// The object-space lines drawn into the edge layer, if any.
    pub lines: Option<LineKind>,
    /// The abstraction applied to the context layer, if any.
    pub(crate) abstraction: Option<Abstraction>,
}

const fn style(
    number: u32,
    name: &'static str,
    edges: Option<EdgeKind>,
    lines: Option<LineKind>,
    abstraction: Option<Abstraction>,
) -> StyleDef {
    StyleDef {
        number,
        name,
        edges,
        lines,
        abstraction,
    }
}

use Abstraction::*;
use EdgeKind::*;
use LineKind::*;

/// The paper's 15 styles, in its order.
pub const STYLES: [StyleDef; 15] = [
    style(1, "sobel", Some(Sobel), None, None),
    style(2, "dog", Some(Dog), None, None),
    style(3, "canny", Some(Canny), None, None),
    style(4, "silhouettes", None, Some(Silhouettes), None),
    style(
        5,
        "suggestive-contours",
        None,
        Some(SuggestiveContours),
        None,
    ),
    style(6, "sobel+silhouettes", Some(Sobel), Some(Silhouettes), None),
    style(7, "dog+silhouettes", Some(Dog), Some(Silhouettes), None),
    style(8, "canny+silhouettes", Some(Canny), Some(Silhouettes), None),
    style(
        9,
        "sobel+suggestive-contours",
        Some(Sobel),
        Some(SuggestiveContours),
        None,
    ),
    style(
        10,
        "dog+suggestive-contours",
        Some(Dog),
        Some(SuggestiveContours),
        None,
    ),
    style(
        11,
        "canny+suggestive-contours",
        Some(Canny),
        Some(SuggestiveContours),
        None,
    ),
    style(
        12,
        "dog+suggestive-contours+kuwahara",
        Some(Dog),
        Some(SuggestiveContours),
        Some(Kuwahara),
    ),
    style(13, "kuwahara", None, None, Some(Kuwahara)),
    style(14, "saturation", None, None, Some(Saturation)),
    style(15, "none", None, None, None),
];

impl StyleDef {
    /// Looks a style up by number or by name (case and spaces ignored; "suggestive" stands for
    /// "suggestive-contours").
    pub fn find(s: &str) -> Result<&'static StyleDef> {
        let key: String = s
            .trim()
            .to_lowercase()
            .chars()
            .filter(|c| !c.is_whitespace())
            .collect();
        let found = match key.parse::<u32>() {
            Ok(n) => STYLES.iter().find(|d| d.number == n),
            Err(_) => {
                let key = key.replace("suggestive-contours", "suggestive");
                STYLES
                    .iter()
                    .find(|d| d.name.replace("suggestive-contours", "suggestive") == key)
            }
        };
        found.ok_or_else(|| {
            Error::Invalid(format!(
                "style {s:?} is unknown; expected a number 1-15 or one of: {}",
                STYLES
                    .iter()
                    .map(|d| format!("{} {}", d.number, d.name))
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })
    }

    /// Whether this build can render the style (all 15 since the object-space lines landed).
    pub fn available(&self) -> bool {
        self.unavailable_reason().is_none()
    }

    /// Why the style cannot be rendered, if it cannot (kept for front ends that list styles).
    pub fn unavailable_reason(&self) -> Option<String> {
        None
    }

    /// Whether the style works on the focus layer (and so needs a focus).
    pub fn needs_focus(&self) -> bool {
        self.edges.is_some() || self.lines.is_some()
    }
}

/// How object-space lines smooth the volume before extraction. In files and on the command line:
/// `"auto"` or a radius in voxels.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "SmoothRepr", into = "SmoothRepr")]
pub enum LineSmooth {
    /// By the data's quantisation (`volume::lines::auto_smooth_radius`).
    #[default]
    Auto,
    /// A Gaussian of this radius in voxels (σ = R/3); 0 = none.
    Radius(u32),
}

impl LineSmooth {
    /// Parses `auto` or a radius.
    pub fn parse(s: &str) -> Result<Self> {
        match s.trim() {
            "auto" => Ok(LineSmooth::Auto),
            r => r.parse().map(LineSmooth::Radius).map_err(|_| {
                Error::Invalid(format!(
                    "line smoothing {s:?} is invalid; expected auto or a radius in voxels"
                ))
            }),
        }
    }

    /// The radius for a volume whose `auto` radius is `auto`.
    pub fn radius(self, auto: u32) -> u32 {
        match self {
            LineSmooth::Auto => auto,
            LineSmooth::Radius(r) => r,
        }
    }
}

/// The JSON form of [`LineSmooth`]: a number or a name.
#[derive(Serialize, Deserialize)]
#[serde(untagged)]
enum SmoothRepr {
    Radius(u32),
    Name(String),
}

impl TryFrom<SmoothRepr> for LineSmooth {
    type Error = String;
    fn try_from(r: SmoothRepr) -> std::result::Result<Self, String> {
        match r {
            SmoothRepr::Radius(r) => Ok(LineSmooth::Radius(r)),
            SmoothRepr::Name(n) => LineSmooth::parse(&n).map_err(|e| e.to_string()),
        }
    }
}

impl From<LineSmooth> for SmoothRepr {
    fn from(s: LineSmooth) -> Self {
        match s {
            LineSmooth::Auto => SmoothRepr::Name("auto".into()),
            LineSmooth::Radius(r) => SmoothRepr::Radius(r),
        }
    }
}

/// Parameters of the styles; every field has the default the gallery uses.
#[derive(Copy, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StyleParams {
    /// Edge colour (RGB in [0, 1]), opacity in [0, 1] and line width in pixels (1–15).
    pub edge_color: [f32; 3],
    /// Edge opacity in [0, 1]: scales the edge strength into the line's alpha.
    pub edge_opacity: f32,
    /// Edge line width in pixels, 1–15.
    pub edge_width: u32,
    /// Sobel: threshold on the normalised gradient magnitude, in [0, 1].
    pub sobel_threshold: f32,
    /// DoG: σ in pixels, the ratio k of the wider σ, XDoG's τ (1 = plain DoG), the threshold ε in
    /// [0, 1] and the sharpness φ of the soft threshold.
    pub dog_sigma: f32,
    /// DoG: ratio k of the wider σ to `dog_sigma`, in (0, 8], with k·σ at most 16 pixels.
    pub dog_k: f32,
    /// DoG: XDoG's τ in D = G_σ − τ·G_kσ, in (0, 2]; 1 is the plain DoG.
    pub dog_tau: f32,
    /// DoG: threshold ε in [0, 1]; edges where D < −ε.
    pub dog_threshold: f32,
    /// DoG: sharpness φ of the soft threshold tanh(φ·(−ε − D)), in (0, 10⁴].
    pub dog_phi: f32,
    /// Canny: smoothing σ in pixels, the high threshold in [0, 1], and the low one as a fraction
    /// of it.
    pub canny_sigma: f32,
    /// Canny: high threshold on the normalised gradient magnitude, in [0, 1].
    pub canny_high: f32,
    /// Canny: low threshold as a fraction of `canny_high`, in [0, 1].
    pub canny_low_ratio: f32,
    /// Kuwahara radius in pixels (1–16).
    pub kuwahara_radius: u32,
    /// Saturation factor of the context (0 grey, 1 unchanged; at most 4).
    pub saturation: f32,
    /// Object-space lines: θ_c in degrees (suggestive contours closer than this to facing the
    /// viewer are dropped), the derivative threshold t_d, the depth bias in voxels behind the
    /// focus within which a line still shows, and the cell stride (1 all cells; 2 the cheaper
    /// interactive mode).
    pub line_angle: f32,
    /// Object-space lines: t_d; a suggestive contour shows only where D_w κ_r > t_d.
    pub line_derivative_threshold: f32,
    /// Object-space lines: how far behind the focus a line still shows, in voxels, in (0, 64].
    pub line_depth_bias: f32,
    /// Object-space lines: cell stride of the extraction, 1–8 (1 all cells; 2 interactive).
    pub line_stride: u32,
    /// Draw both kinds of lines whatever the style's kind (`vellum lines --kind both`).
    pub line_both: bool,
    /// Object-space lines: the radius in voxels of the Gaussian (σ = R/3) the volume is smoothed
    /// with before extraction, or `auto` (the default: by the data's quantisation,
    /// `volume::lines::auto_smooth_radius`). Suggestive contours need it on measured data.
    pub line_smooth: LineSmooth,
    /// Object-space lines by the seeded traversal (`LineParams::seeded`), the viewer's
    /// interactive mode: lines followed from the previous frame's and a sparse grid of seeds.
    pub line_seeded: bool,
}

impl Default for StyleParams {
    fn default() -> Self {
        StyleParams {
            edge_color: [0.0; 3],
            edge_opacity: 1.0,
            edge_width: 1,
            sobel_threshold: 0.08,
            dog_sigma: 1.0,
            dog_k: 1.6,
            dog_tau: 1.0,
            dog_threshold: 0.005,
            dog_phi: 100.0,
            canny_sigma: 1.0,
            canny_high: 0.1,
            canny_low_ratio: 0.4,
            kuwahara_radius: 4,
            saturation: 0.2,
            line_angle: 20.0,
            line_derivative_threshold: 1e-4,
            line_depth_bias: 1.5,
            line_stride: 1,
            line_both: false,
            line_smooth: LineSmooth::Auto,
            line_seeded: false,
        }
    }
}

impl StyleParams {
    /// Checks every value; one sentence naming it when one is out of range.
    pub fn validate(&self) -> Result<()> {
        let unit = |name: &str, v: f32| {
            if (0.0..=1.0).contains(&v) {
                Ok(())
            } else {
                Err(Error::Invalid(format!("{name} {v} is outside [0, 1]")))
            }
        };
        let positive = |name: &str, v: f32, max: f32| {
            if v.is_finite() && v > 0.0 && v <= max {
                Ok(())
            } else {
                Err(Error::Invalid(format!(
                    "{name} {v} is invalid; expected a number in (0, {max}]"
                )))
            }
        };
        for (c, v) in self.edge_color.iter().enumerate() {
            unit(&format!("edge colour component {c}"), *v)?;
        }
        unit("edge opacity", self.edge_opacity)?;
        unit("the Sobel threshold", self.sobel_threshold)?;
        unit("the DoG threshold", self.dog_threshold)?;
        unit("the Canny high threshold", self.canny_high)?;
        unit("the Canny low ratio", self.canny_low_ratio)?;
        positive("the DoG σ", self.dog_sigma, 16.0)?;
        positive("the DoG k", self.dog_k, 8.0)?;
        positive("the DoG τ", self.dog_tau, 2.0)?;
        positive("the DoG φ", self.dog_phi, 1.0e4)?;
        positive("the Canny σ", self.canny_sigma, 16.0)?;
        if self.dog_k * self.dog_sigma > 16.0 {
            return Err(Error::Invalid(format!(
                "the DoG's wider σ k·σ = {} is larger than 16 pixels",
                self.dog_k * self.dog_sigma
            )));
        }
        if !(1..=15).contains(&self.edge_width) {
            return Err(Error::Invalid(format!(
                "edge width {} is invalid; expected 1..=15 pixels",
                self.edge_width
            )));
        }
        if !(1..=16).contains(&self.kuwahara_radius) {
            return Err(Error::Invalid(format!(
                "Kuwahara radius {} is invalid; expected 1..=16 pixels",
                self.kuwahara_radius
            )));
        }
        if !(self.line_angle.is_finite() && (0.0..90.0).contains(&self.line_angle)) {
            return Err(Error::Invalid(format!(
                "line angle {} is invalid; expected 0 <= θ_c < 90 degrees",
                self.line_angle
            )));
        }
        if !self.line_derivative_threshold.is_finite() {
            return Err(Error::Invalid(
                "the line derivative threshold must be a finite number".into(),
            ));
        }
        positive("the line depth bias", self.line_depth_bias, 64.0)?;
        if let LineSmooth::Radius(r @ 17..) = self.line_smooth {
            return Err(Error::Invalid(format!(
                "line smoothing radius {r} is invalid; expected auto or 0..=16 voxels"
            )));
        }
        if !(1..=8).contains(&self.line_stride) {
            return Err(Error::Invalid(format!(
                "line stride {} is invalid; expected 1..=8 cells",
                self.line_stride
            )));
        }
        if !(self.saturation.is_finite() && (0.0..=4.0).contains(&self.saturation)) {
            return Err(Error::Invalid(format!(
                "saturation factor {} is invalid; expected 0..=4",
                self.saturation
            )));
        }
        Ok(())
    }
}

/// A style with its parameters, ready to record.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Style {
    /// The style's entry in [`STYLES`].
    pub def: &'static StyleDef,
    /// Its parameters, checked by [`StyleParams::validate`].
    pub params: StyleParams,
}

impl Style {
    /// The style named `s` (number or name) with `params`, checked: unknown styles, styles that
    /// are not built and bad parameters are refused with one sentence.
    pub fn new(s: &str, params: StyleParams) -> Result<Style> {
        let def = StyleDef::find(s)?;
        if let Some(why) = def.unavailable_reason() {
            return Err(Error::Invalid(why));
        }
        params.validate()?;
        Ok(Style { def, params })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn styles_by_number_and_name() {
        assert_eq!(StyleDef::find("7").unwrap().name, "dog+silhouettes");
        assert_eq!(StyleDef::find("DoG + Silhouettes").unwrap().number, 7);
        assert_eq!(StyleDef::find("dog+suggestive").unwrap().number, 10);
        assert_eq!(StyleDef::find("none").unwrap().number, 15);
        for (i, d) in STYLES.iter().enumerate() {
            assert_eq!(d.number as usize, i + 1);
            assert_eq!(StyleDef::find(d.name).unwrap(), d);
        }
        let e = StyleDef::find("16").unwrap_err().to_string();
        assert!(e.contains("1 sobel") && e.contains("15 none"), "{e}");
        assert!(Style::new("dog+silhouettes", StyleParams::default()).is_ok());
        assert!(Style::new("13", StyleParams::default()).is_ok());
        assert_eq!(STYLES.iter().filter(|d| d.available()).count(), 15);
    }

    #[test]
    fn bad_parameters() {
        let bad = |f: fn(&mut StyleParams)| {
            let mut p = StyleParams::default();
            f(&mut p);
            p.validate().unwrap_err().to_string()
        };
        assert!(bad(|p| p.sobel_threshold = 1.5).contains("outside [0, 1]"));
        assert!(bad(|p| p.dog_sigma = -1.0).contains("DoG σ"));
        assert!(bad(|p| p.kuwahara_radius = 0).contains("Kuwahara radius"));
        assert!(bad(|p| p.canny_high = -0.1).contains("Canny high"));
        assert!(StyleParams::default().validate().is_ok());
    }
}
