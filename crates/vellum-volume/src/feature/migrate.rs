//! FM3, moving the ROI's density range (paper §3.3), and the whole migration: categorise (§3.2),
//! move (§3.3), reconstruct (§3.4), pick the output type.
//!
//! Definitions, from §3.3:
//! - (IN_low, IN_high) is "the range of the input data": the minimum and maximum of the *whole*
//!   input volume, ROI included. The new range is placed above it (the paper's second case, eq. 2),
//!   so no voxel of the input, wherever it ends up, has a value in the private interval unless it
//!   was moved there; voxels that reconstruction leaves unchanged are therefore never mistaken for
//!   the feature. When the input is a feature volume, IN_high includes every earlier private
//!   interval, so each new feature lands above all earlier ones.
//! - (ROI_low, ROI_high): the range of the category-2 and -3 voxels only (partial-volume voxels of
//!   category 1 are left out); ROI_width = ROI_high − ROI_low.
//! - ROI′ = [IN_high + ε, IN_high + ε + ROI_width] (eq. 2), Δ = IN_high + ε − ROI_low (eq. 4),
//!   δ′ = δ + Δ for categories 2 and 3 (eq. 5).
//!
//! ε is "a small number to provide a gap". By default it is 5 % of the input range: wide enough
//! that a transfer function sampled into a 256-entry table can put a step between the data and the
//! private interval. For integer voxel types it is rounded up to a whole number, so Δ is whole and
//! eq. 5 is exact.
//!
//! The output type is the input type when every output value fits it, else wider (the paper's
//! "longer datawords"): u8 → u16 → f32, and i16 → f32. Values of integer outputs are rounded to
//! the nearest integer (only eq. 10 produces fractions).

use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use super::categorise::{categorise, Categories, Category, CategoryCounts};
use super::reconstruct::{reconstruct, ReconstructionCounts, RegionGrow};
use super::roi::Roi;
use crate::{stats, Volume, VoxelData, VoxelType};
use vellum_error::{Error, Result};

/// Default ε as a fraction of the input range (IN_high − IN_low).
pub(crate) const DEFAULT_EPSILON_FRACTION: f64 = 0.05;

/// The knobs of a migration.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MigrateParams {
    /// ε of eq. 2 in data units; `None` for `DEFAULT_EPSILON_FRACTION` of the input range.
    pub epsilon: Option<f64>,
    /// The region grow of §3.4.
    pub grow: RegionGrow,
    /// Private intervals of earlier features in the input (a feature volume), kept private: see
    /// [`Overlap`].
    pub protected: Vec<[f64; 2]>,
    /// Keep eq. 10's values even where they fall inside a protected interval (only count them).
    pub allow_overlap: bool,
}

/// What the fuzzy boundary of a new feature did to one earlier private interval.
///
/// Eq. 10 ramps a boundary voxel from its surroundings δ_o up to the moved ROI, δ_i + Δ, which lies
/// above every earlier interval; so the ramp crosses them, and a few boundary voxels of the new
/// feature land inside an earlier feature's interval, where its transfer function would paint them
/// as that feature. The paper promises each feature a private interval, so by default such voxels
/// are moved just outside the interval, to whichever side is nearer, by half of this migration's
/// ε (the gap the transfer function leaves empty). That keeps the profile monotone, and so the
/// boundary's position, while the step inside the ramp costs a little smoothness on those voxels
/// only. With [`MigrateParams::allow_overlap`] they keep eq. 10's value and are only counted.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Overlap {
    /// The earlier feature's private interval.
    pub interval: [f64; 2],
    /// Boundary voxels of the new feature whose eq. 10 value fell inside it.
    pub voxels: usize,
    /// Of those, the ones moved out of it.
    pub moved: usize,
}

/// Wall-clock time of each stage, in milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Timings {
    /// Categorisation (§3.2).
    pub categorise_ms: f64,
    /// Ranges, Δ and eq. 5 (§3.3).
    pub migrate_ms: f64,
    /// Fuzzy boundary reconstruction (§3.4).
    pub reconstruct_ms: f64,
    /// Everything, including the output type conversion.
    pub total_ms: f64,
}

/// The numbers of one migration, for printing and for the feature map.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MigrationReport {
    /// (IN_low, IN_high): the whole input's range.
    pub in_range: [f64; 2],
    /// (ROI_low, ROI_high): the range of the category-2 and -3 voxels.
    pub roi_range: [f64; 2],
    /// ε of eq. 2, as used.
    pub epsilon: f64,
    /// Δ of eq. 4.
    pub delta: f64,
    /// ROI′ of eq. 2: the feature's private interval in output data units.
    pub interval: [f64; 2],
    /// Voxel type of the input.
    pub input_type: VoxelType,
    /// Voxel type of the feature volume.
    pub output_type: VoxelType,
    /// (min, max) of the feature volume.
    pub(crate) output_range: [f64; 2],
    /// ROI voxels.
    pub roi_voxels: usize,
    /// Voxels per category.
    pub categories: CategoryCounts,
    /// Fuzzy-boundary voxels that fell inside earlier private intervals, per protected interval.
    pub overlaps: Vec<Overlap>,
    /// How the category-1 voxels were reconstructed.
    pub reconstruction: ReconstructionCounts,
    /// Stage times.
    pub timings: Timings,
}

/// A feature volume and how it was made.
#[derive(Clone, Debug)]
pub struct Migration {
    /// The feature volume: the input with the ROI moved to its private interval.
    pub volume: Volume,
    /// The category of every voxel.
    pub categories: Categories,
    /// The numbers.
    pub report: MigrationReport,
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Migrates the ROI of `volume` into a private interval above the volume's range (§3.2–§3.4).
pub fn migrate(volume: &Volume, roi: &Roi, params: &MigrateParams) -> Result<Migration> {
    let start = Instant::now();
    if roi.dims() != volume.dims {
        let [a, b, c] = roi.dims();
        let [x, y, z] = volume.dims;
        return Err(Error::Invalid(format!(
            "the ROI is {a}x{b}x{c} but the volume is {x}x{y}x{z}; expected an ROI aligned voxel for voxel with the volume"
        )));
    }
    volume.check_finite("the volume to migrate")?;
    let roi_voxels = roi.count();
    if roi_voxels == 0 {
        return Err(Error::Invalid(
            "the ROI is empty; expected at least one ROI voxel (nonzero mask voxel or grown region)"
                .into(),
        ));
    }

    let t = Instant::now();
    let categories = categorise(roi);
    let counts = categories.counts();
    let categorise_ms = ms(t);

    let t = Instant::now();
    let values = volume.data.to_f32();
    let s = stats::stats(volume, 0);
    let in_range = [s.min, s.max];
    let roi_range = body_range(&categories.labels, &values).ok_or_else(|| {
        Error::Invalid(format!(
            "all {roi_voxels} ROI voxels lie on its fuzzy boundary (category 1), so the ROI has no range to migrate; expected an ROI at least 5 voxels thick somewhere, or one or two voxels thin"
        ))
    })?;
    let integer = volume.voxel_type() != VoxelType::F32;
    let epsilon = epsilon(params.epsilon, in_range, integer)?;
    // Eqs. 2 and 4.
    let low = in_range[1] + epsilon;
    let interval = [low, low + (roi_range[1] - roi_range[0])];
    let delta = low - roi_range[0];
    // Eq. 5 (category 1 is overwritten below).
    let mut out: Vec<f64> = values
        .par_iter()
        .zip(categories.labels.par_iter())
        .map(|(&v, &c)| v as f64 + if c.is_roi_body() { delta } else { 0.0 })
        .collect();
    let migrate_ms = ms(t);

    let t = Instant::now();
    let reconstruction = reconstruct(&categories, roi, &values, delta, &params.grow, &mut out);
    let gap = if integer {
        (epsilon / 2.0).ceil().max(1.0)
    } else {
        epsilon / 2.0
    };
    let overlaps = keep_private(&categories.labels, &values, &mut out, params, gap, integer);
    let reconstruct_ms = ms(t);

    let (data, output_range) = convert(volume.voxel_type(), &out);
    let output_type = data.voxel_type();
    if output_type == VoxelType::F32 {
        check_f32_resolution(params.epsilon, in_range, roi_range, interval, integer)?;
    }
    // Float voxels hold the interval's ends as f32; rounding is monotone, so the shifted voxels
    // stay inside the rounded interval.
    let interval = match output_type {
        VoxelType::F32 => interval.map(|v| v as f32 as f64),
        _ => interval,
    };
    let feature_volume =
        Volume::new(volume.dims, volume.spacing, data)?.with_geometry(volume.geometry)?;
    let report = MigrationReport {
        in_range,
        roi_range,
        epsilon,
        delta,
        interval,
        input_type: volume.voxel_type(),
        output_type,
        output_range,
        roi_voxels,
        categories: counts,
        overlaps,
        reconstruction,
        timings: Timings {
            categorise_ms,
            migrate_ms,
            reconstruct_ms,
            total_ms: ms(start),
        },
    };
    Ok(Migration {
        volume: feature_volume,
        categories,
        report,
    })
}

/// (ROI_low, ROI_high) over the category-2 and -3 voxels; `None` when there are none.
fn body_range(labels: &[Category], values: &[f32]) -> Option<[f64; 2]> {
    let (lo, hi) = labels
        .par_iter()
        .zip(values.par_iter())
        .filter(|(c, _)| c.is_roi_body())
        .map(|(_, &v)| (v, v))
        .reduce(
            || (f32::INFINITY, f32::NEG_INFINITY),
            |a, b| (a.0.min(b.0), a.1.max(b.1)),
        );
    (lo <= hi).then_some([lo as f64, hi as f64])
}

/// Finds, and unless allowed moves, fuzzy-boundary values inside protected intervals (see
/// [`Overlap`]). `gap` is how far outside an interval a moved voxel lands. A voxel that was in the
/// interval before the migration (one of the earlier feature's own) is left alone.
fn keep_private(
    labels: &[Category],
    before: &[f32],
    out: &mut [f64],
    params: &MigrateParams,
    gap: f64,
    integer: bool,
) -> Vec<Overlap> {
    // Integer outputs are rounded later: judge the value they will have.
    let inside = |v: f64, i: &[f64; 2]| {
        let v = if integer { v.round() } else { v };
        v >= i[0] && v <= i[1]
    };
    let free = |v: f64| !params.protected.iter().any(|i| inside(v, i));
    let mut overlaps: Vec<Overlap> = params
        .protected
        .iter()
        .map(|&interval| Overlap {
            interval,
            voxels: 0,
            moved: 0,
        })
        .collect();
    if overlaps.is_empty() {
        return overlaps;
    }
    for ((v, c), &old) in out.iter_mut().zip(labels).zip(before) {
        if *c != Category::FuzzyBoundary {
            continue;
        }
        let Some(k) = params.protected.iter().position(|i| inside(*v, i)) else {
            continue;
        };
        if inside(old as f64, &params.protected[k]) {
            continue;
        }
        overlaps[k].voxels += 1;
        if params.allow_overlap {
            continue;
        }
        let [a, b] = params.protected[k];
        let (below, above) = (a - gap, b + gap);
        let order = if *v - a <= b - *v {
            [below, above]
        } else {
            [above, below]
        };
        if let Some(&to) = order.iter().find(|&&t| free(t)) {
            *v = to;
            overlaps[k].moved += 1;
        }
    }
    overlaps
}

/// The spacing of f32 values near `m`.
fn f32_spacing(m: f64) -> f64 {
    let m = (m.abs() as f32).max(f32::MIN_POSITIVE);
    let next = f32::from_bits(m.to_bits() + 1);
    (next - m) as f64
}

/// Refuses a private interval placed so high (by a huge ε) that f32 cannot tell the feature's
/// values apart there, while it could in the input: for integer data, whole numbers must stay
/// exact; for float data, the spacing of f32 values must stay within 1/4096 of the ROI's range.
fn check_f32_resolution(
    given: Option<f64>,
    in_range: [f64; 2],
    roi_range: [f64; 2],
    interval: [f64; 2],
    integer: bool,
) -> Result<()> {
    let width = roi_range[1] - roi_range[0];
    let tolerance = if integer { 1.0 } else { width / 4096.0 };
    let step = f32_spacing(interval[0].abs().max(interval[1].abs()));
    let input_step = f32_spacing(in_range[0].abs().max(in_range[1].abs()));
    if width <= 0.0 || step <= tolerance || step <= input_step {
        return Ok(());
    }
    // The highest magnitude whose f32 spacing is at most the tolerance.
    let top = 2f64.powf(tolerance.log2().floor() + 24.0);
    let most = top - in_range[1] - width;
    let expected = if most > 0.0 {
        format!("expected epsilon below {most:.6e}")
    } else {
        "expected data whose magnitude is small against its range".into()
    };
    let what = match given {
        Some(e) => format!("epsilon {e} places"),
        None => "the default epsilon places".into(),
    };
    Err(Error::Invalid(format!(
        "{what} the private interval at {:.6e}, where 32-bit floats are {step:.3e} apart, so the feature's range of {width} would collapse to a few values; {expected}",
        interval[0]
    )))
}

/// ε as given (checked) or the default, rounded up to a whole number for integer data.
fn epsilon(given: Option<f64>, in_range: [f64; 2], integer: bool) -> Result<f64> {
    let e = match given {
        Some(e) if e.is_finite() && e > 0.0 => e,
        Some(e) => {
            return Err(Error::Invalid(format!(
                "epsilon {e} is invalid; expected a positive gap in data units"
            )))
        }
        None => {
            let width = in_range[1] - in_range[0];
            if width > 0.0 {
                DEFAULT_EPSILON_FRACTION * width
            } else {
                1.0
            }
        }
    };
    Ok(if integer { e.ceil() } else { e })
}

/// The output voxels in the narrowest type that holds them, starting from the input type, and
/// their range.
fn convert(input: VoxelType, out: &[f64]) -> (VoxelData, [f64; 2]) {
    let (lo, hi) = out.par_iter().map(|&v| (v, v)).reduce(
        || (f64::INFINITY, f64::NEG_INFINITY),
        |a, b| (a.0.min(b.0), a.1.max(b.1)),
    );
    let (rlo, rhi) = (lo.round(), hi.round());
    let fits = |min: f64, max: f64| rlo >= min && rhi <= max;
    let ty = match input {
        VoxelType::U8 if fits(0.0, u8::MAX as f64) => VoxelType::U8,
        VoxelType::U8 | VoxelType::U16 if fits(0.0, u16::MAX as f64) => VoxelType::U16,
        VoxelType::I16 if fits(i16::MIN as f64, i16::MAX as f64) => VoxelType::I16,
        _ => VoxelType::F32,
    };
    let round = |v: &f64| v.round();
    let data = match ty {
        VoxelType::U8 => VoxelData::U8(out.par_iter().map(|v| round(v) as u8).collect()),
        VoxelType::U16 => VoxelData::U16(out.par_iter().map(|v| round(v) as u16).collect()),
        VoxelType::I16 => VoxelData::I16(out.par_iter().map(|v| round(v) as i16).collect()),
        VoxelType::F32 => {
            // Integer input widened to float keeps whole values, so eq. 5 stays exact.
            if input == VoxelType::F32 {
                VoxelData::F32(out.par_iter().map(|&v| v as f32).collect())
            } else {
                VoxelData::F32(out.par_iter().map(|v| round(v) as f32).collect())
            }
        }
    };
    let range = match ty {
        VoxelType::F32 if input == VoxelType::F32 => [lo as f32 as f64, hi as f32 as f64],
        _ => [rlo, rhi],
    };
    (data, range)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_widens_only_when_needed() {
        let (d, r) = convert(VoxelType::U8, &[0.0, 254.6]);
        assert_eq!((d.voxel_type(), r), (VoxelType::U8, [0.0, 255.0]));
        let (d, r) = convert(VoxelType::U8, &[3.0, 255.5]);
        assert_eq!((d.voxel_type(), r), (VoxelType::U16, [3.0, 256.0]));
        assert_eq!(d, VoxelData::U16(vec![3, 256]));
        let (d, _) = convert(VoxelType::U8, &[0.0, 70000.0]);
        assert_eq!(d.voxel_type(), VoxelType::F32);
        let (d, _) = convert(VoxelType::U16, &[0.0, 65535.0]);
        assert_eq!(d.voxel_type(), VoxelType::U16);
        let (d, _) = convert(VoxelType::U16, &[0.0, 65536.0]);
        assert_eq!(d.voxel_type(), VoxelType::F32);
        let (d, _) = convert(VoxelType::I16, &[-1024.0, 32767.0]);
        assert_eq!(d.voxel_type(), VoxelType::I16);
        let (d, r) = convert(VoxelType::I16, &[-1024.0, 40000.2]);
        assert_eq!(
            (d, r),
            (VoxelData::F32(vec![-1024.0, 40000.0]), [-1024.0, 40000.0])
        );
        let (d, _) = convert(VoxelType::F32, &[0.25, 1.5]);
        assert_eq!(d, VoxelData::F32(vec![0.25, 1.5]));
    }

    #[test]
    fn epsilon_defaults_and_rounding() {
        assert_eq!(epsilon(None, [0.0, 255.0], true).unwrap(), 13.0);
        assert_eq!(epsilon(None, [0.0, 1.0], false).unwrap(), 0.05);
        assert_eq!(epsilon(None, [7.0, 7.0], true).unwrap(), 1.0);
        assert_eq!(epsilon(Some(2.5), [0.0, 255.0], true).unwrap(), 3.0);
        assert_eq!(epsilon(Some(2.5), [0.0, 255.0], false).unwrap(), 2.5);
        for bad in [0.0, -1.0, f64::NAN] {
            let e = epsilon(Some(bad), [0.0, 1.0], false)
                .unwrap_err()
                .to_string();
            assert!(e.contains("expected a positive gap"), "{e}");
        }
    }
}
