//! Occlusion transfer functions (SPEC OS4, OS5; occlusion paper §4). Colour and opacity come from
//! a 2D table indexed by (intensity, occlusion), both normalised to [0, 1]. A JSON file describes
//! it in one of two ways:
//!
//! - **Tagged regions** of the spectrum: rectangles and Gaussian blobs, each with an RGBA.
//! - **The decoupled model** of eq. 7: α(x) = α_s(s) · α_o(s, O). α_s and the colour come from an
//!   ordinary 1D transfer function (a preset or a file). α_o is a set of Gaussian occlusion curves,
//!   each spanning an intensity interval with a mean and width over occlusion. Intensities under
//!   no curve keep α_o = 1.
//!
//! ```json
//! {"name": "brain", "radius": 16, "mapping": "ramp",
//!  "transfer": "mri-brain",
//!  "curves": [{"intensity": [0.3, 1.0], "mean": 0.6, "width": 0.08}],
//!  "regions": [{"rect": {"intensity": [0.1, 0.2], "occlusion": [0.0, 0.3]}, "rgba": [1, 0.8, 0.6, 0.1]}]}
//! ```
//! Regions, when present, are composited over the decoupled table (their colour replaces it where
//! their alpha is higher). `radius`, `mapping` and `stride` say how to compute the occlusion volume.

use crate::classify::transfer::TransferFunction;
use serde::{Deserialize, Serialize};
use std::path::Path;
use vellum_error::{Error, Result};

/// The largest occlusion radius in voxels, and output stride, the occlusion pass takes.
pub(crate) const MAX_OCCLUSION_RADIUS: u32 = 1024;
/// The largest output stride of the occlusion volume, in voxels.
pub(crate) const MAX_OCCLUSION_STRIDE: u32 = 64;

/// Table size along intensity and occlusion.
pub(crate) const TABLE_SIZE: usize = 256;

/// A Gaussian occlusion curve of the decoupled model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Curve {
    /// Normalised intensity interval the curve spans.
    pub intensity: [f32; 2],
    /// Mean and standard deviation over occlusion.
    pub mean: f32,
    /// Standard deviation of the curve over normalised occlusion; greater than 0.
    pub width: f32,
}

/// A shape tagged on the spectrum.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase", deny_unknown_fields)]
pub enum Shape {
    /// A rectangle of the spectrum: weight 1 inside it (edges included), 0 outside.
    Rect {
        /// Normalised intensity interval [lo, hi] within [0, 1].
        intensity: [f32; 2],
        /// Normalised occlusion interval [lo, hi] within [0, 1].
        occlusion: [f32; 2],
    },
    /// A Gaussian blob: centre (intensity, occlusion) and standard deviations.
    Blob {
        /// Centre (intensity, occlusion), normalised to [0, 1].
        centre: [f32; 2],
        /// Standard deviations along normalised intensity and occlusion; greater than 0.
        sigma: [f32; 2],
    },
}

/// A tagged region.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Region {
    /// Where on the spectrum the region lies (JSON: a `rect` or `blob` key beside `rgba`).
    #[serde(flatten)]
    pub shape: Shape,
    /// Straight RGBA in [0, 1]; its alpha is scaled by the shape's weight (1 inside a rect, the
    /// Gaussian of a blob).
    pub rgba: [f32; 4],
}

/// An occlusion transfer function as stored in JSON.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OcclusionTf {
    /// A name for the function; optional, empty by default.
    #[serde(default)]
    pub name: String,
    /// Occlusion radius in voxels.
    #[serde(default = "default_radius")]
    pub radius: u32,
    /// Visibility mapping, as `vellum occlusion --mapping`.
    #[serde(default = "default_mapping")]
    pub mapping: String,
    /// Output stride of the occlusion volume (0: radius / 16, at least 1).
    #[serde(default)]
    pub stride: u32,
    /// The 1D transfer function of the decoupled model (preset name or JSON path); none means
    /// only the regions define the table.
    #[serde(default)]
    pub transfer: Option<String>,
    /// The occlusion curves that make α_o of eq. 7; none means α_o = 1 everywhere.
    #[serde(default)]
    pub curves: Vec<Curve>,
    /// Tagged regions, composited over the decoupled table where their alpha is higher.
    #[serde(default)]
    pub regions: Vec<Region>,
}

fn default_radius() -> u32 {
    16
}
fn default_mapping() -> String {
    "ramp".into()
}

impl OcclusionTf {
    /// Reads and checks a JSON file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = vellum_volume::io::read_text(path)?;
        let otf: OcclusionTf = serde_json::from_str(&text)
            .map_err(|e| Error::format(path, format!("not an occlusion transfer function ({e}); see the format in src/classify/otf.rs or docs/cli.md")))?;
        otf.validate()
            .map_err(|e| Error::format(path, e.to_string()))?;
        // What the file names must resolve too, so that its errors name the file.
        crate::classify::mapping::parse_mapping(&otf.mapping)
            .map_err(|e| Error::format(path, format!("\"mapping\": {e}")))?;
        if let Some(t) = &otf.transfer {
            TransferFunction::from_arg(t)
                .map_err(|e| Error::format(path, format!("\"transfer\": {e}")))?;
        }
        Ok(otf)
    }

    fn validate(&self) -> Result<()> {
        // The occlusion pass's limits, checked here so that the error names the file.
        if !(1..=MAX_OCCLUSION_RADIUS).contains(&self.radius) {
            return Err(Error::Invalid(format!(
                "`radius` {} is invalid; expected 1..={MAX_OCCLUSION_RADIUS} voxels",
                self.radius
            )));
        }
        if self.stride > MAX_OCCLUSION_STRIDE {
            return Err(Error::Invalid(format!(
                "`stride` {} is invalid; expected 0 (radius / 16) or 1..={MAX_OCCLUSION_STRIDE}",
                self.stride
            )));
        }
        let unit = |v: f32| v.is_finite() && (0.0..=1.0).contains(&v);
        let interval = |i: [f32; 2]| unit(i[0]) && unit(i[1]) && i[0] <= i[1];
        if self.transfer.is_none() && self.regions.is_empty() {
            return Err(Error::Invalid(
                "an occlusion transfer function needs a `transfer` or at least one region".into(),
            ));
        }
        for c in &self.curves {
            if !interval(c.intensity) || !unit(c.mean) || !c.width.is_finite() || c.width <= 0.0 {
                return Err(Error::Invalid("each curve needs an intensity interval within [0,1], a mean in [0,1] and a positive width".into()));
            }
        }
        for r in &self.regions {
            let ok = r.rgba.iter().all(|&v| unit(v))
                && match r.shape {
                    Shape::Rect {
                        intensity,
                        occlusion,
                    } => interval(intensity) && interval(occlusion),
                    Shape::Blob { centre, sigma } => {
                        unit(centre[0])
                            && unit(centre[1])
                            && sigma.iter().all(|s| s.is_finite() && *s > 0.0)
                    }
                };
            if !ok {
                return Err(Error::Invalid("each region needs rgba in [0,1] and a rect or blob within [0,1] (blob sigmas > 0)".into()));
            }
        }
        Ok(())
    }

    /// α_o(s, O) of the decoupled model: the largest curve response over curves spanning s, or 1.
    pub(crate) fn occlusion_opacity(&self, s: f32, o: f32) -> f32 {
        let spanning: Vec<&Curve> = self
            .curves
            .iter()
            .filter(|c| s >= c.intensity[0] && s <= c.intensity[1])
            .collect();
        if spanning.is_empty() {
            return 1.0;
        }
        spanning
            .iter()
            .map(|c| (-(o - c.mean).powi(2) / (2.0 * c.width * c.width)).exp())
            .fold(0.0, f32::max)
    }

    /// The 256×256 table, row-major by occlusion: `table[o * 256 + s]`, straight RGBA.
    pub fn table(&self) -> Result<Vec<[f32; 4]>> {
        let tf = self
            .transfer
            .as_deref()
            .map(TransferFunction::from_arg)
            .transpose()?;
        let mut table = vec![[0f32; 4]; TABLE_SIZE * TABLE_SIZE];
        let at = |i: usize| i as f32 / (TABLE_SIZE - 1) as f32; // knots, as `TransferFunction::table`
        for oi in 0..TABLE_SIZE {
            for si in 0..TABLE_SIZE {
                let (s, o) = (at(si), at(oi));
                let mut c = match &tf {
                    Some(tf) => {
                        let mut c = tf.sample(s);
                        c[3] *= self.occlusion_opacity(s, o);
                        c
                    }
                    None => [0.0; 4],
                };
                for r in &self.regions {
                    let weight = match r.shape {
                        Shape::Rect {
                            intensity,
                            occlusion,
                        } => f32::from(
                            s >= intensity[0]
                                && s <= intensity[1]
                                && o >= occlusion[0]
                                && o <= occlusion[1],
                        ),
                        Shape::Blob { centre, sigma } => (-0.5
                            * (((s - centre[0]) / sigma[0]).powi(2)
                                + ((o - centre[1]) / sigma[1]).powi(2)))
                        .exp(),
                    };
                    let a = r.rgba[3] * weight;
                    if a > c[3] {
                        c = [r.rgba[0], r.rgba[1], r.rgba[2], a];
                    }
                }
                table[oi * TABLE_SIZE + si] = c;
            }
        }
        Ok(table)
    }

    /// The stride to compute occlusion at (explicit, or radius / 16 and at least 1).
    pub(crate) fn effective_stride(&self) -> u32 {
        if self.stride > 0 {
            self.stride
        } else {
            (self.radius / 16).max(1)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(s: &str) -> Result<OcclusionTf> {
        let otf: OcclusionTf =
            serde_json::from_str(s).map_err(|e| Error::Invalid(e.to_string()))?;
        otf.validate()?;
        Ok(otf)
    }

    #[test]
    fn decoupled_model_multiplies_opacities() {
        let otf = parse(r#"{"transfer": "grey", "curves": [{"intensity": [0.5, 1.0], "mean": 0.8, "width": 0.05}]}"#).unwrap();
        let t = otf.table().unwrap();
        let at = |s: usize, o: usize| t[o * TABLE_SIZE + s];
        // Under the curve: opaque near occlusion 0.8, transparent far from it.
        assert!(at(200, 204)[3] > 0.7 && at(200, 50)[3] < 1e-3);
        // Outside the curve's interval, α_o = 1: the grey ramp's alpha is untouched.
        assert!((at(64, 10)[3] - (64.0 / 255.0)).abs() < 1e-6);
    }

    #[test]
    fn regions_tag_the_spectrum() {
        let otf = parse(r#"{"regions": [{"rect": {"intensity": [0.2, 0.4], "occlusion": [0.5, 1.0]}, "rgba": [1, 0, 0, 0.9]},
                                        {"blob": {"centre": [0.8, 0.2], "sigma": [0.05, 0.05]}, "rgba": [0, 0, 1, 1]}]}"#)
            .unwrap();
        let t = otf.table().unwrap();
        assert_eq!(t[200 * TABLE_SIZE + 77], [1.0, 0.0, 0.0, 0.9]);
        assert!(t[10 * TABLE_SIZE + 77][3] < 1e-6, "outside every region");
        assert!(t[51 * TABLE_SIZE + 204][3] > 0.9);
    }

    #[test]
    fn bad_files_are_refused() {
        assert!(parse(r#"{"curves": []}"#).is_err());
        assert!(parse(r#"{"transfer": "grey", "curves": [{"intensity": [0.5, 0.2], "mean": 0.5, "width": 0.1}]}"#).is_err());
        assert!(parse(r#"{"regions": [{"rect": {"intensity": [0, 1], "occlusion": [0, 1]}, "rgba": [2, 0, 0, 1]}]}"#).is_err());
        assert!(parse(r#"{"transfer": "grey", "colour": 1}"#).is_err());
    }
}
