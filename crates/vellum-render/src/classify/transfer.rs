//! 1D transfer functions: data value → colour and opacity, uploaded as a 1D texture.
//!
//! Control points live on the *normalised* data range [0, 1], where 0 is the volume's minimum and
//! 1 its maximum, so one preset serves 8- and 16-bit data alike. Between points the function is
//! piecewise linear; outside them it is clamped to the end points. Colours are straight (not
//! premultiplied) linear RGB. Alpha is the opacity of one sample at the reference sampling distance
//! of one voxel; renderers that sample at another spacing apply `correct_opacity`.

use serde::{Deserialize, Serialize};
use std::path::Path;
use vellum_error::{Error, Result};

/// One control point: data value `x` in [0, 1] of the normalised range and its RGBA, all in [0, 1].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlPoint {
    /// Normalised data value: 0 = volume minimum, 1 = volume maximum.
    pub x: f32,
    /// Straight linear RGB and opacity per voxel-length sample.
    pub rgba: [f32; 4],
}

/// A piecewise-linear transfer function. Points are sorted by `x`; two points with the same `x`
/// make a step (the later one applies from `x` on).
///
/// JSON form: `{"name": "bone", "points": [{"x": 0.0, "rgba": [r, g, b, a]}, ...]}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransferFunction {
    /// Shown in logs and benchmark tables; a file without one takes its file stem.
    #[serde(default)]
    pub name: String,
    /// At least one point, sorted by `x` (sorted on construction).
    pub points: Vec<ControlPoint>,
}

/// Entries of the 1D transfer-function table on the GPU.
pub(crate) const TF_SIZE: usize = 256;

/// Names accepted by [`TransferFunction::preset`].
pub const PRESETS: &[&str] = &["grey", "ct-bone", "ct-skin-bone", "mri-brain"];

const fn cp(x: f32, rgba: [f32; 4]) -> ControlPoint {
    ControlPoint { x, rgba }
}

/// `grey`: colour and opacity both equal the normalised value, the neutral default for any data.
const GREY: &[ControlPoint] = &[cp(0.0, [0.0, 0.0, 0.0, 0.0]), cp(1.0, [1.0, 1.0, 1.0, 1.0])];

/// `ct-bone`: bone only, opaque ivory. Tuned on the Stanford CT head (0..3272), where air is below
/// 0.1, soft tissue peaks at 0.32–0.34 (≈1050–1110) and bone starts above 0.35 (≈1150). Everything
/// up to 0.34 is transparent; opacity ramps to 0.5 per voxel by 0.40 and to 0.9 by 0.55, so a
/// skull a few voxels thick is opaque. Colour below the ramp matches its start, which avoids dark
/// fringes where the texture filter blends across it.
const CT_BONE: &[ControlPoint] = &[
    cp(0.00, [0.80, 0.70, 0.55, 0.0]),
    cp(0.34, [0.80, 0.70, 0.55, 0.0]),
    cp(0.40, [0.93, 0.88, 0.78, 0.5]),
    cp(0.55, [1.00, 0.98, 0.92, 0.9]),
    cp(1.00, [1.00, 1.00, 1.00, 0.95]),
];

/// `ct-skin-bone`: `ct-bone` plus soft tissue as a faint skin-coloured veil (opacity 0.03 per
/// voxel on the soft-tissue peak 0.31–0.34 of the CT head), so the skin surface is visible and the
/// skull shows through it.
const CT_SKIN_BONE: &[ControlPoint] = &[
    cp(0.00, [0.85, 0.55, 0.45, 0.0]),
    cp(0.27, [0.85, 0.55, 0.45, 0.0]),
    cp(0.31, [0.90, 0.60, 0.50, 0.03]),
    cp(0.34, [0.90, 0.60, 0.50, 0.03]),
    cp(0.36, [0.93, 0.88, 0.78, 0.05]),
    cp(0.42, [0.95, 0.92, 0.82, 0.6]),
    cp(0.55, [1.00, 0.98, 0.92, 0.9]),
    cp(1.00, [1.00, 1.00, 1.00, 0.95]),
];

/// `mri-brain`: for 8-bit T1 MRI (0..255). Background and noise below 0.08 are transparent; CSF,
/// skin and scalp (0.15–0.25) are a faint veil (0.015 per voxel); grey matter (≈0.35) is pinkish
/// grey at 0.1 and white matter (≈0.55) lighter at 0.35, so the brain stands out inside the head.
const MRI_BRAIN: &[ControlPoint] = &[
    cp(0.00, [0.60, 0.45, 0.40, 0.0]),
    cp(0.08, [0.60, 0.45, 0.40, 0.0]),
    cp(0.15, [0.75, 0.55, 0.50, 0.015]),
    cp(0.25, [0.75, 0.55, 0.50, 0.015]),
    cp(0.35, [0.80, 0.68, 0.68, 0.1]),
    cp(0.55, [0.92, 0.85, 0.85, 0.35]),
    cp(1.00, [1.00, 0.95, 0.92, 0.5]),
];

impl TransferFunction {
    /// Validates and sorts `points` (stable, so equal-`x` steps keep their order). Every value must
    /// be finite and in [0, 1], and there must be at least one point.
    pub fn new(name: impl Into<String>, mut points: Vec<ControlPoint>) -> Result<Self> {
        let name = name.into();
        if points.is_empty() {
            return Err(Error::Invalid(format!(
                "transfer function {name:?} has no control points; expected at least one"
            )));
        }
        for (i, p) in points.iter().enumerate() {
            let unit = |v: f32| (0.0..=1.0).contains(&v); // false for NaN
            if !unit(p.x) || !p.rgba.iter().all(|&c| unit(c)) {
                return Err(Error::Invalid(format!(
                    "transfer function {name:?}, point {i}: x = {} and rgba = {:?} must all be finite numbers in [0, 1]",
                    p.x, p.rgba
                )));
            }
        }
        points.sort_by(|a, b| a.x.total_cmp(&b.x));
        Ok(TransferFunction { name, points })
    }

    /// A named preset; see [`PRESETS`] and the constants' docs for each one's intent.
    pub fn preset(name: &str) -> Result<Self> {
        let points = match name {
            "grey" => GREY,
            "ct-bone" => CT_BONE,
            "ct-skin-bone" => CT_SKIN_BONE,
            "mri-brain" => MRI_BRAIN,
            _ => {
                return Err(Error::Invalid(format!(
                    "unknown transfer function preset {name:?}; expected one of {}",
                    PRESETS.join(", ")
                )))
            }
        };
        TransferFunction::new(name, points.to_vec())
    }

    /// A preset name, or else a path to a JSON transfer function file.
    pub fn from_arg(s: &str) -> Result<Self> {
        if PRESETS.contains(&s) {
            return Self::preset(s);
        }
        let path = Path::new(s);
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"))
        {
            return Self::load(path);
        }
        Err(Error::Invalid(format!(
            "transfer function {s:?} is neither a preset ({}) nor a .json file",
            PRESETS.join(", ")
        )))
    }

    /// Parses and validates the JSON form (see the type's doc).
    pub fn from_json_str(json: &str) -> Result<Self> {
        let raw: TransferFunction = serde_json::from_str(json).map_err(|e| {
            Error::Invalid(format!(
                "transfer function JSON: {e}; expected {{\"name\": \"..\", \"points\": [{{\"x\": 0.0, \"rgba\": [r, g, b, a]}}, ..]}}"
            ))
        })?;
        TransferFunction::new(raw.name, raw.points)
    }

    /// Reads a JSON file; an unnamed function takes the file stem as its name.
    pub fn load(path: &Path) -> Result<Self> {
        let text = vellum_volume::io::read_text(path)?;
        let mut tf = Self::from_json_str(&text).map_err(|e| match e {
            Error::Invalid(msg) => Error::format(path, msg),
            other => other,
        })?;
        if tf.name.is_empty() {
            tf.name = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
        }
        Ok(tf)
    }

    /// The JSON form, pretty-printed.
    pub fn to_json(&self) -> String {
        // Serialising plain structs of finite floats and strings cannot fail.
        serde_json::to_string_pretty(self).expect("transfer function serialises")
    }

    /// RGBA at normalised value `x`: linear between the neighbouring points, clamped outside them.
    pub fn sample(&self, x: f32) -> [f32; 4] {
        let pts = &self.points;
        // First point strictly right of x; a step at x therefore takes its later point.
        let i = pts.partition_point(|p| p.x <= x);
        if i == 0 {
            return pts[0].rgba;
        }
        if i == pts.len() {
            return pts[i - 1].rgba;
        }
        let (a, b) = (&pts[i - 1], &pts[i]);
        let t = (x - a.x) / (b.x - a.x); // b.x > x >= a.x
        std::array::from_fn(|c| a.rgba[c] + t * (b.rgba[c] - a.rgba[c]))
    }

    /// `n` entries sampled at the knots `i / (n − 1)`, so that entry 0 is the function at 0 and
    /// the last at 1. The shaders read the texture at `(s (n − 1) + 0.5) / n` (`tf_coord` in
    /// glsl/common/classify.glsl), which interpolates linearly between knots: a value of 0 gets
    /// exactly the function's opacity at 0, not the opacity half a texel above it.
    pub fn table(&self, n: usize) -> Vec<[f32; 4]> {
        let last = n.saturating_sub(1).max(1) as f32;
        (0..n).map(|i| self.sample(i as f32 / last)).collect()
    }
}

/// Per texel i of a 256-texel transfer function, the larger opacity of texels i and i + 1: a
/// bound on every opacity linear filtering returns for intensities between their knots i / 255
/// and (i + 1) / 255 (`tf_pair` in glsl/common/classify.glsl picks the entry). The ray caster's
/// walk tests samples against it before classifying them (`render::raycast`; per channel,
/// `classify::channels`).
pub(crate) fn opacity_bounds(table: &[[f32; 4]]) -> [f32; 256] {
    let mut out = [0.0f32; 256];
    let n = table.len();
    for (i, o) in out.iter_mut().enumerate() {
        let a = |j: usize| table.get(j.min(n.saturating_sub(1))).map_or(0.0, |t| t[3]);
        *o = a(i).max(a(i + 1));
    }
    out
}

/// Opacity of a sample taken `ratio` times the reference distance apart: `1 − (1 − alpha)^ratio`.
///
/// The standard opacity correction for a changed sampling distance (Lacroute & Levoy, "Fast volume
/// rendering using a shear-warp factorization", SIGGRAPH 1994; Engel et al., *Real-Time Volume
/// Graphics*, 2006): it keeps the accumulated opacity along a ray
/// independent of how finely the ray is sampled. `ratio` = actual sample distance / reference
/// distance (one voxel).
#[cfg(test)]
pub(crate) fn correct_opacity(alpha: f32, ratio: f32) -> f32 {
    1.0 - (1.0 - alpha.clamp(0.0, 1.0)).powf(ratio)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: [f32; 4], b: [f32; 4]) -> bool {
        a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6)
    }

    #[test]
    fn interpolates_linearly_and_clamps() {
        let tf = TransferFunction::new(
            "t",
            vec![cp(0.8, [1.0, 1.0, 1.0, 1.0]), cp(0.2, [0.0, 0.5, 1.0, 0.0])],
        )
        .unwrap();
        assert_eq!(tf.points[0].x, 0.2, "sorted on construction");
        assert!(close(tf.sample(0.0), [0.0, 0.5, 1.0, 0.0]));
        assert!(close(tf.sample(0.2), [0.0, 0.5, 1.0, 0.0]));
        assert!(close(tf.sample(0.5), [0.5, 0.75, 1.0, 0.5]));
        assert!(close(tf.sample(1.0), [1.0; 4]));
        let single = TransferFunction::new("one", vec![cp(0.3, [0.1, 0.2, 0.3, 0.4])]).unwrap();
        assert!(close(single.sample(0.9), [0.1, 0.2, 0.3, 0.4]));
    }

    #[test]
    fn equal_x_makes_a_step() {
        let tf = TransferFunction::new(
            "step",
            vec![
                cp(0.0, [0.0; 4]),
                cp(0.5, [0.0; 4]),
                cp(0.5, [1.0; 4]),
                cp(1.0, [1.0; 4]),
            ],
        )
        .unwrap();
        assert!(close(tf.sample(0.4999), [0.0; 4]));
        assert!(close(tf.sample(0.5), [1.0; 4]));
    }

    #[test]
    fn table_samples_knots() {
        let grey = TransferFunction::preset("grey").unwrap();
        let t = grey.table(4);
        assert_eq!(t.len(), 4);
        for (i, v) in t.iter().enumerate() {
            let x = i as f32 / 3.0;
            assert!(close(*v, [x; 4]));
        }
        // A ramp from 0 is transparent at 0: empty space adds nothing.
        assert_eq!(grey.table(256)[0][3], 0.0);
        assert_eq!(grey.table(256)[255][3], 1.0);
        assert!(grey.table(0).is_empty());
    }

    #[test]
    fn presets_are_valid_and_do_what_they_say() {
        for name in PRESETS {
            let tf = TransferFunction::preset(name).unwrap();
            assert_eq!(tf.name, *name);
            assert_eq!(TransferFunction::from_arg(name).unwrap(), tf);
        }
        let e = TransferFunction::preset("bone").unwrap_err().to_string();
        assert!(e.contains("ct-bone") && e.contains("mri-brain"), "{e}");

        // CT head, 0..3272: soft tissue (1080) invisible, bone (1600) nearly opaque per voxel.
        let bone = TransferFunction::preset("ct-bone").unwrap();
        assert_eq!(bone.sample(1080.0 / 3272.0)[3], 0.0);
        assert!(bone.sample(1600.0 / 3272.0)[3] > 0.7);
        let skin = TransferFunction::preset("ct-skin-bone").unwrap();
        let tissue = skin.sample(1080.0 / 3272.0)[3];
        assert!(tissue > 0.0 && tissue < 0.1, "{tissue}");
        assert!(skin.sample(1600.0 / 3272.0)[3] > 0.7);
        let mri = TransferFunction::preset("mri-brain").unwrap();
        assert_eq!(mri.sample(0.02)[3], 0.0, "background");
        assert!(mri.sample(0.55)[3] > mri.sample(0.2)[3]);
    }

    #[test]
    fn json_round_trips() {
        let tf = TransferFunction::preset("ct-skin-bone").unwrap();
        let back = TransferFunction::from_json_str(&tf.to_json()).unwrap();
        assert_eq!(back, tf);

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mine.json");
        std::fs::write(
            &path,
            r#"{"points": [{"x": 1, "rgba": [1,0,0,1]}, {"x": 0, "rgba": [0,0,0,0]}]}"#,
        )
        .unwrap();
        let loaded = TransferFunction::from_arg(path.to_str().unwrap()).unwrap();
        assert_eq!(loaded.name, "mine");
        assert!(close(loaded.sample(0.5), [0.5, 0.0, 0.0, 0.5]));
    }

    #[test]
    fn json_errors_say_what_was_expected() {
        for (json, needle) in [
            (r#"{"name": "x", "points": []}"#, "no control points"),
            (
                r#"{"name": "x", "points": [{"x": 1.5, "rgba": [0,0,0,0]}]}"#,
                "in [0, 1]",
            ),
            (
                r#"{"name": "x", "points": [{"x": 0.5, "rgba": [0,0,0,-0.1]}]}"#,
                "in [0, 1]",
            ),
            (
                r#"{"name": "x", "points": [{"x": 0.5, "rgba": [0,0,0]}]}"#,
                "expected {",
            ),
            (
                r#"{"name": "x", "points": [{"x": 0.5, "rgb": [0,0,0,1]}]}"#,
                "expected {",
            ),
            (r#"{"name": "x"}"#, "expected {"),
            ("not json", "expected {"),
        ] {
            let e = TransferFunction::from_json_str(json)
                .unwrap_err()
                .to_string();
            assert!(e.contains(needle), "{json}: {e}");
        }
        let missing = TransferFunction::from_arg("/nonexistent/tf.json").unwrap_err();
        assert!(matches!(missing, Error::Io { .. }), "{missing}");
        let neither = TransferFunction::from_arg("bonez").unwrap_err().to_string();
        assert!(neither.contains("neither a preset"), "{neither}");
    }

    #[test]
    fn opacity_correction() {
        for a in [0.0, 0.1, 0.5, 0.9, 1.0] {
            assert!((correct_opacity(a, 1.0) - a).abs() < 1e-6);
            let twice = 1.0 - (1.0 - a) * (1.0 - a);
            assert!((correct_opacity(a, 2.0) - twice).abs() < 1e-6);
        }
        // Two half-distance samples accumulate to one full-distance sample.
        let half = correct_opacity(0.3, 0.5);
        assert!((1.0 - (1.0 - half) * (1.0 - half) - 0.3).abs() < 1e-6);
    }
}
