//! Importance modulation (SPEC IM3–IM5, importance paper §4): the spatial importance map ΔD
//! modulates each sample's colour (eq. 3, 4), its opacity (eq. 5) and the density of stipple dots
//! (eq. 6).
//!
//! ## Units
//! ΔD is computed from the volume *normalised* to [0, 1] over its data range (the renderer's
//! texture), so it is in normalised intensity units: γ means the same for u8, u16 and float data.
//! The paper's γ values (−10…20) were on its own intensity scale and are not comparable one to one.
//! n = |ΔD| / max|ΔD| over the volume, in [0, 1], with the maximum from a GPU reduction.
//!
//! ## Order
//! Per sample: the transfer function gives (colour, A); eq. 5 turns A into A′, clamped to [0, 1];
//! the opacity correction for the sampling distance comes after. Colour: eq. 3 or 4 adds ΔD·γ (or
//! |ΔD|·γ) to the base colour, which is the unlit transfer-function colour (`ambient`) or the
//! Phong-lit one (`phong`), floored at 0 (never clamped above, so γ = 0 changes nothing). A stippled
//! sample takes one of two flat colours by eq. 6 and keeps its (modulated) opacity.
//!
//! These functions are the CPU reference; `glsl/common/classify.glsl` holds their GPU twins, which
//! `tests/modulation.rs` runs through a probe shader and compares.

use serde::{Deserialize, Serialize};
use vellum_error::{Error, Result};

/// Eq. 3 (raw ΔD) or eq. 4 (|ΔD|).
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ColorMode {
    /// Eq. 3: add ΔD·γ, so positive and negative ΔD shift the colour in opposite directions.
    Raw,
    /// Eq. 4: add |ΔD|·γ, the same shift whichever the sign of ΔD.
    Abs,
}

/// The colour that colour modulation adds to.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ModulateLighting {
    /// The transfer function's colour, unlit (the paper's "ambient lighting").
    Ambient,
    /// The Phong-lit colour (the paper's "local illumination").
    #[default]
    Phong,
}

/// Which level of a two-level frame is modulated (a one-pass frame is all context).
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ApplyTo {
    /// Only the focus level.
    Focus,
    /// Only the context level (and every sample of a one-pass frame).
    Context,
    /// Both levels; the default.
    #[default]
    Both,
}

/// Colour modulation (eq. 3, 4).
#[derive(Copy, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColorModulation {
    /// Whether ΔD enters with its sign (eq. 3) or as |ΔD| (eq. 4).
    pub mode: ColorMode,
    /// γ, in colour units per normalised-intensity unit of ΔD; may be negative.
    pub gamma: f32,
}

/// Opacity modulation (eq. 5).
#[derive(Copy, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OpacityModulation {
    /// Lower threshold t_l on n in [0, 1]: below it the opacity becomes A·k_l·n.
    pub t_low: f32,
    /// Upper threshold t_h on n in [0, 1], at least t_l: above it the opacity becomes A·k_h·n.
    pub t_high: f32,
    /// Factor k_l ≥ 0 applied to samples with n < t_l.
    pub k_low: f32,
    /// Factor k_h ≥ 0 applied to samples with n > t_h.
    pub k_high: f32,
}

/// Stippling (eq. 6).
#[derive(Copy, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Stipple {
    /// Threshold t in [0, 1]: samples with n ≥ t are white.
    pub t: f32,
    /// Density factor f ≥ 0: a sample is white when f·n ≥ r(s).
    pub f: f32,
    /// Seed of the per-sample random numbers r(s).
    #[serde(default)]
    pub seed: u32,
    /// The two colours; the paper's white and black by default.
    #[serde(default = "white")]
    pub white: [f32; 3],
    /// The RGB colour, in [0, 1], of a sample that eq. 6 does not make white; black by default.
    #[serde(default)]
    pub black: [f32; 3],
}

fn white() -> [f32; 3] {
    [1.0; 3]
}

/// Default importance radius R in voxels, as in every figure of the paper.
pub const DEFAULT_IMPORTANCE_RADIUS: u32 = 10;

fn default_radius() -> u32 {
    DEFAULT_IMPORTANCE_RADIUS
}

/// Everything importance modulation needs; all effects off by default.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Modulation {
    /// Colour modulation (eq. 3, 4), or none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color: Option<ColorModulation>,
    /// Opacity modulation (eq. 5), or none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub opacity: Option<OpacityModulation>,
    /// Stippling (eq. 6), or none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stipple: Option<Stipple>,
    /// Radius R of the Gaussian behind ΔD, in voxels (σ = R/3).
    #[serde(default = "default_radius")]
    pub importance_radius: u32,
    /// Which level of a two-level frame the effects apply to; both by default.
    #[serde(default)]
    pub apply_to: ApplyTo,
    /// The base colour that colour modulation adds to; the Phong-lit one by default.
    #[serde(default)]
    pub lighting: ModulateLighting,
}

impl Default for Modulation {
    fn default() -> Self {
        Modulation {
            color: None,
            opacity: None,
            stipple: None,
            importance_radius: DEFAULT_IMPORTANCE_RADIUS,
            apply_to: ApplyTo::Both,
            lighting: ModulateLighting::Phong,
        }
    }
}

impl Modulation {
    /// Whether any effect is on (and ΔD is needed).
    pub fn is_active(&self) -> bool {
        self.color.is_some() || self.opacity.is_some() || self.stipple.is_some()
    }

    /// Checks every parameter; each failure is one sentence naming the value and what was expected.
    pub fn validate(&self) -> Result<()> {
        let bad = |msg: String| Err(Error::Invalid(msg));
        if let Some(c) = &self.color {
            if !c.gamma.is_finite() {
                return bad(format!("gamma {} is not a finite number", c.gamma));
            }
        }
        if let Some(o) = &self.opacity {
            let all = [o.t_low, o.t_high, o.k_low, o.k_high];
            if !all.iter().all(|v| v.is_finite()) {
                return bad(format!("opacity modulation {all:?} must be finite numbers"));
            }
            if o.t_low > o.t_high {
                return bad(format!(
                    "opacity modulation needs t_l <= t_h, got t_l = {} and t_h = {}",
                    o.t_low, o.t_high
                ));
            }
            if o.k_low < 0.0 || o.k_high < 0.0 {
                return bad(format!(
                    "opacity modulation needs k_l, k_h >= 0, got {} and {}",
                    o.k_low, o.k_high
                ));
            }
        }
        if let Some(s) = &self.stipple {
            if !(0.0..=1.0).contains(&s.t) {
                return bad(format!("stipple threshold t = {} is outside [0, 1]", s.t));
            }
            if !(s.f.is_finite() && s.f >= 0.0) {
                return bad(format!(
                    "stipple factor f = {} must be a finite number >= 0",
                    s.f
                ));
            }
            for c in s.white.iter().chain(&s.black) {
                if !(0.0..=1.0).contains(c) {
                    return bad(format!(
                        "stipple colours {:?} and {:?} need components in [0, 1]",
                        s.white, s.black
                    ));
                }
            }
        }
        if self.is_active() && self.importance_radius == 0 {
            return bad(
                "importance modulation needs an importance radius of at least 1 voxel".into(),
            );
        }
        Ok(())
    }
}

/// Eq. 3 / eq. 4: `rgb` plus ΔD·γ (or |ΔD|·γ) in every channel, floored at 0.
pub fn modulate_color(rgb: [f32; 3], delta_d: f32, c: &ColorModulation) -> [f32; 3] {
    let d = match c.mode {
        ColorMode::Raw => delta_d,
        ColorMode::Abs => delta_d.abs(),
    };
    rgb.map(|x| (x + d * c.gamma).max(0.0))
}

/// Eq. 5: the opacity `a` for normalised importance `n`, clamped to [0, 1].
pub fn modulate_opacity(a: f32, n: f32, o: &OpacityModulation) -> f32 {
    if n < o.t_low {
        (a * o.k_low * n).clamp(0.0, 1.0)
    } else if n > o.t_high {
        (a * o.k_high * n).clamp(0.0, 1.0)
    } else {
        a
    }
}

/// Eq. 6: whether a sample of normalised importance `n` and random number `r` is white.
pub fn stipple_is_white(n: f32, r: f32, s: &Stipple) -> bool {
    n >= s.t || s.f * n >= r
}

/// Sub-voxel steps per voxel of the stipple grid: a sample's random number depends on its
/// position quantised to 1/16 voxel, so that it is the same wherever the same point is sampled.
pub(crate) const STIPPLE_GRID: f32 = 16.0;

/// PCG3D (Jarzynski and Olano 2020, "Hash functions for GPU rendering"), as in classify.glsl.
pub(crate) fn pcg3d(v: [u32; 3]) -> [u32; 3] {
    let [mut x, mut y, mut z] = v.map(|c| c.wrapping_mul(1664525).wrapping_add(1013904223));
    x = x.wrapping_add(y.wrapping_mul(z));
    y = y.wrapping_add(z.wrapping_mul(x));
    z = z.wrapping_add(x.wrapping_mul(y));
    x ^= x >> 16;
    y ^= y >> 16;
    z ^= z >> 16;
    x = x.wrapping_add(y.wrapping_mul(z));
    y = y.wrapping_add(z.wrapping_mul(x));
    z = z.wrapping_add(x.wrapping_mul(y));
    [x, y, z]
}

/// r(s) in [0, 1) for a sample at `voxel` (continuous voxel coordinates) and `seed`: stateless,
/// so the same seed gives the same numbers on any device and in any renderer.
pub fn stipple_random(voxel: [f32; 3], seed: u32) -> f32 {
    let q = voxel.map(|c| (c * STIPPLE_GRID).floor() as i32 as u32);
    let salt = [0x9E37_79B9u32, 0x85EB_CA6B, 0xC2B2_AE35];
    let v = std::array::from_fn(|i| q[i].wrapping_add(seed.wrapping_mul(salt[i])));
    (pcg3d(v)[0] >> 8) as f32 / 16_777_216.0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opacity(t_low: f32, t_high: f32, k_low: f32, k_high: f32) -> OpacityModulation {
        OpacityModulation {
            t_low,
            t_high,
            k_low,
            k_high,
        }
    }

    #[test]
    fn eq5_case_by_case_with_the_thresholds_edges() {
        let o = opacity(0.2, 0.6, 2.0, 3.0);
        assert_eq!(modulate_opacity(0.5, 0.1, &o), 0.5 * 2.0 * 0.1); // n < t_l
        assert_eq!(modulate_opacity(0.5, 0.2, &o), 0.5); // n = t_l: otherwise
        assert_eq!(modulate_opacity(0.5, 0.4, &o), 0.5); // between
        assert_eq!(modulate_opacity(0.5, 0.6, &o), 0.5); // n = t_h: otherwise
        assert_eq!(
            modulate_opacity(0.5, 0.61, &o),
            (0.5f32 * 3.0 * 0.61).min(1.0)
        ); // n > t_h
        assert_eq!(modulate_opacity(0.9, 0.9, &o), 1.0); // clamped
                                                         // The identity parameters change nothing anywhere.
        let id = opacity(0.0, 1.0, 1.0, 1.0);
        for n in [0.0, 0.3, 1.0] {
            assert_eq!(modulate_opacity(0.37, n, &id), 0.37);
        }
        // The paper's Fig. 5: t_l = t_h = 1, so nearly every sample becomes A·k_l·n.
        let fig5 = opacity(1.0, 1.0, 5.0, 1.0);
        assert_eq!(modulate_opacity(0.1, 0.5, &fig5), 0.1 * 5.0 * 0.5);
        assert_eq!(modulate_opacity(0.1, 1.0, &fig5), 0.1);
    }

    #[test]
    fn colour_modulation_raw_and_absolute() {
        let raw = ColorModulation {
            mode: ColorMode::Raw,
            gamma: 10.0,
        };
        let abs = ColorModulation {
            mode: ColorMode::Abs,
            gamma: 10.0,
        };
        assert_eq!(modulate_color([0.5; 3], -0.02, &raw), [0.3; 3]);
        assert_eq!(modulate_color([0.5; 3], -0.02, &abs), [0.7; 3]);
        assert_eq!(
            modulate_color([0.1; 3], -0.05, &raw),
            [0.0; 3],
            "floored at 0"
        );
        let zero = ColorModulation {
            mode: ColorMode::Raw,
            gamma: 0.0,
        };
        assert_eq!(modulate_color([1.7, 0.2, 0.0], 0.3, &zero), [1.7, 0.2, 0.0]);
    }

    #[test]
    fn stipple_rule_and_random_numbers() {
        let s = Stipple {
            t: 0.1,
            f: 10.0,
            seed: 1,
            white: [1.0; 3],
            black: [0.0; 3],
        };
        assert!(stipple_is_white(0.1, 0.99, &s)); // n >= t
        assert!(stipple_is_white(0.05, 0.5, &s)); // f·n = 0.5 >= r
        assert!(!stipple_is_white(0.05, 0.51, &s));
        let rs: Vec<f32> = (0..10000)
            .map(|i| stipple_random([i as f32 * 0.37, (i % 7) as f32, 3.5], 7))
            .collect();
        assert!(rs.iter().all(|r| (0.0..1.0).contains(r)));
        let mean = rs.iter().sum::<f32>() / rs.len() as f32;
        assert!((mean - 0.5).abs() < 0.02, "mean {mean}");
        assert_eq!(
            stipple_random([1.2, 3.4, 5.6], 9),
            stipple_random([1.2, 3.4, 5.6], 9)
        );
        assert_ne!(
            stipple_random([1.2, 3.4, 5.6], 9),
            stipple_random([1.2, 3.4, 5.6], 10)
        );
    }

    #[test]
    fn bad_parameters_are_one_sentence_each() {
        let mut m = Modulation {
            opacity: Some(opacity(0.7, 0.2, 1.0, 1.0)),
            ..Modulation::default()
        };
        assert!(m.validate().unwrap_err().to_string().contains("t_l <= t_h"));
        m.opacity = None;
        m.color = Some(ColorModulation {
            mode: ColorMode::Raw,
            gamma: f32::NAN,
        });
        assert!(m
            .validate()
            .unwrap_err()
            .to_string()
            .contains("not a finite"));
        m.color = None;
        m.stipple = Some(Stipple {
            t: 1.5,
            f: 1.0,
            seed: 0,
            white: [1.0; 3],
            black: [0.0; 3],
        });
        assert!(m
            .validate()
            .unwrap_err()
            .to_string()
            .contains("outside [0, 1]"));
        m.stipple = Some(Stipple {
            t: 0.1,
            f: -1.0,
            seed: 0,
            white: [1.0; 3],
            black: [0.0; 3],
        });
        assert!(m.validate().unwrap_err().to_string().contains(">= 0"));
        m.stipple.as_mut().unwrap().f = 2.0;
        m.importance_radius = 0;
        assert!(m
            .validate()
            .unwrap_err()
            .to_string()
            .contains("importance radius"));
        m.importance_radius = 10;
        assert!(m.validate().is_ok());
    }
}
