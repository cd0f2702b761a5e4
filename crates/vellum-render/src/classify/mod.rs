//! The classification layer: how a sample of (value, occlusion, importance) gets colour and
//! opacity, shared by every renderer and by the passes that need it (the occlusion pass maps
//! intensity to visibility through a transfer function).
//!
//! It sits beneath both `passes/` and `render/` and holds:
//! - the data: 1D transfer functions ([`transfer`]), occlusion transfer functions ([`otf`]) and
//!   their visibility mappings ([`mapping`]), feature-map transfer functions ([`features`]) and
//!   their composition with an occlusion transfer function (`compose`), the
//!   focus of a two-level frame ([`Focus`]), importance modulation ([`modulation`]) and the
//!   segments of a label volume ([`labels`]);
//! - their persistent GPU state ([`textures::GpuClassification`]): textures re-uploaded only when
//!   their contents change, focus and modulation as per-frame uniforms;
//! - in GLSL, `glsl/common/classify.glsl` and `glsl/common/shading.glsl`: pure functions of
//!   (value, occlusion, ΔD) and of (normal, light, view), with no bindings inside, so that slice
//!   shaders and compute shaders include the same code.
//!
//! Command-line grammar (`--focus LO:HI`, `tf:FILE`) is parsed by the binary; this layer takes
//! typed values. File formats (transfer-function and occlusion-TF JSON) are parsed here.

pub mod channels;
pub(crate) mod compose;
pub mod features;
pub mod labels;
pub mod mapping;
pub mod modulation;
pub mod otf;
pub mod textures;
pub mod transfer;
pub mod window;

use otf::OcclusionTf;
use serde::{Deserialize, Serialize};
use transfer::TransferFunction;
use vellum_volume::feature::FeatureMap;

/// What the first level of a two-level frame renders.
#[derive(Copy, Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Focus {
    /// No focus: everything is context.
    #[default]
    None,
    /// Samples whose data value lies in [lo, hi] (data units), with the transfer function's opacity.
    Range {
        /// Lower end of the interval, in data units.
        lo: f64,
        /// Upper end of the interval, in data units; at least `lo`.
        hi: f64,
    },
    /// Samples at or above the data value: an opaque isosurface.
    Iso(f64),
}

impl Focus {
    /// (lo, hi, mode) on the normalised range of `data_range`; mode 0 none, 1 range, 2 iso (the
    /// `focus` uniform of the shaders).
    pub(crate) fn normalised(&self, data_range: [f64; 2]) -> [f32; 3] {
        let n = |v: f64| {
            if data_range[1] > data_range[0] {
                ((v - data_range[0]) / (data_range[1] - data_range[0])) as f32
            } else {
                0.0
            }
        };
        match *self {
            Focus::None => [0.0, 0.0, 0.0],
            Focus::Range { lo, hi } => [n(lo), n(hi), 1.0],
            Focus::Iso(v) => [n(v), f32::INFINITY, 2.0],
        }
    }

    /// Refuses a focus that selects nothing, or everything, of data in `range` (min, max): an
    /// isovalue outside the range, or an interval that misses it.
    pub fn check_in(&self, range: [f64; 2]) -> vellum_error::Result<()> {
        let [min, max] = range;
        let outside = match *self {
            Focus::None => false,
            Focus::Iso(v) => v < min || v > max,
            Focus::Range { lo, hi } => hi < min || lo > max,
        };
        if outside {
            let what = match *self {
                Focus::Iso(v) => format!("the isovalue {v}"),
                Focus::Range { lo, hi } => format!("the focus interval {lo}:{hi}"),
                Focus::None => unreachable!("no focus is never outside"),
            };
            return Err(vellum_error::Error::Invalid(format!(
                "{what} lies outside the data range {min} .. {max}; expected a value within it"
            )));
        }
        Ok(())
    }

    /// Checks the values: finite, and lo <= hi.
    pub fn validate(&self) -> vellum_error::Result<()> {
        let ok = match *self {
            Focus::None => true,
            Focus::Range { lo, hi } => lo.is_finite() && hi.is_finite() && lo <= hi,
            Focus::Iso(v) => v.is_finite(),
        };
        if ok {
            Ok(())
        } else {
            Err(vellum_error::Error::Invalid(format!(
                "focus {self:?} is invalid; expected finite data values with lo <= hi"
            )))
        }
    }
}

/// How samples get colour and opacity.
#[derive(Clone, Debug)]
pub enum Classification {
    /// The default: the grey ramp over the data's histogram window ([`window`]), found when the
    /// volume is known.
    Auto,
    /// A 1D transfer function.
    Transfer(TransferFunction),
    /// A feature map: each feature's private interval in its colour (FM6).
    Features(FeatureMap),
    /// An occlusion transfer function; its occlusion volume is computed when a scene is prepared.
    Occlusion(OcclusionTf),
    /// A feature map composed with an occlusion transfer function (`compose`): the features in
    /// their colours, the context by intensity and occlusion.
    Composed(FeatureMap, OcclusionTf),
}
