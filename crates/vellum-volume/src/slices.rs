//! Pictures of volumes: the three middle slices side by side, coloured by a colour map. Used for
//! the importance map's thermal slices (SPEC IM2, paper Fig. 2).

use crate::Volume;

/// A diverging "thermal" colour map for signed data, symmetric about zero: cool blues for negative
/// values, a neutral near-white at zero, warm reds and yellows for positive ones. `t` in [-1, 1].
pub(crate) fn thermal(t: f64) -> [u8; 3] {
    // Control points from cold to hot; zero sits at the middle point.
    const STOPS: [(f64, [f64; 3]); 7] = [
        (-1.0, [0.02, 0.05, 0.35]),
        (-0.6, [0.10, 0.30, 0.85]),
        (-0.25, [0.45, 0.75, 0.98]),
        (0.0, [0.96, 0.96, 0.96]),
        (0.25, [0.99, 0.80, 0.45]),
        (0.6, [0.90, 0.30, 0.10]),
        (1.0, [0.50, 0.02, 0.05]),
    ];
    let t = if t.is_finite() {
        t.clamp(-1.0, 1.0)
    } else {
        0.0
    };
    let i = STOPS
        .windows(2)
        .position(|w| t <= w[1].0)
        .unwrap_or(STOPS.len() - 2);
    let (t0, c0) = STOPS[i];
    let (t1, c1) = STOPS[i + 1];
    let f = (t - t0) / (t1 - t0);
    std::array::from_fn(|k| ((c0[k] + f * (c1[k] - c0[k])) * 255.0).round() as u8)
}

/// Middle slices of `v` normal to x, y and z, as (width, height, values) with rows top to bottom.
/// The x slice shows (y, z), the y slice (x, z), the z slice (x, y); z grows upwards.
pub(crate) fn middle_slices(v: &Volume) -> [(usize, usize, Vec<f64>); 3] {
    let [nx, ny, nz] = v.dims;
    let (cx, cy, cz) = (nx / 2, ny / 2, nz / 2);
    let grab = |w: usize, h: usize, at: &dyn Fn(usize, usize) -> usize| {
        let mut out = Vec::with_capacity(w * h);
        for row in 0..h {
            for col in 0..w {
                out.push(v.data.get_f64(at(col, row)));
            }
        }
        (w, h, out)
    };
    [
        grab(ny, nz, &|c, r| v.index(cx, c, nz - 1 - r)),
        grab(nx, nz, &|c, r| v.index(c, cy, nz - 1 - r)),
        grab(nx, ny, &|c, r| v.index(c, ny - 1 - r, cz)),
    ]
}

/// An RGB picture of the three middle slices of signed data side by side, coloured by `thermal`
/// with the scale symmetric about zero at ±`limit`, and a colour bar underneath. Returns
/// (width, height, rgb bytes).
pub fn thermal_slices(v: &Volume, limit: f64) -> (u32, u32, Vec<u8>) {
    let slices = middle_slices(v);
    let gap = 4;
    let width = slices.iter().map(|s| s.0).sum::<usize>() + gap * 4;
    let bar = 12;
    let height = slices.iter().map(|s| s.1).max().unwrap_or(1) + gap * 3 + bar;
    let mut rgb = vec![40u8; width * height * 3];
    let limit = if limit > 0.0 && limit.is_finite() {
        limit
    } else {
        1.0
    };
    let mut x0 = gap;
    for (w, h, vals) in &slices {
        for r in 0..*h {
            for c in 0..*w {
                let px = ((gap + r) * width + x0 + c) * 3;
                rgb[px..px + 3].copy_from_slice(&thermal(vals[r * w + c] / limit));
            }
        }
        x0 += w + gap;
    }
    let y0 = height - gap - bar;
    for c in gap..width - gap {
        let t = 2.0 * (c - gap) as f64 / (width - 2 * gap - 1).max(1) as f64 - 1.0;
        for r in y0..y0 + bar {
            let px = (r * width + c) * 3;
            rgb[px..px + 3].copy_from_slice(&thermal(t));
        }
    }
    (width as u32, height as u32, rgb)
}

/// The `q` quantile (0..1) of |values|, a robust symmetric limit for colour scales.
pub fn abs_quantile(values: impl Iterator<Item = f64>, q: f64) -> f64 {
    let mut a: Vec<f64> = values.filter(|x| x.is_finite()).map(f64::abs).collect();
    if a.is_empty() {
        return 0.0;
    }
    let k = ((a.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    *a.select_nth_unstable_by(k, f64::total_cmp).1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thermal_is_diverging() {
        let cold = thermal(-1.0);
        let zero = thermal(0.0);
        let hot = thermal(1.0);
        assert!(cold[2] > cold[0], "negative is blue");
        assert!(hot[0] > hot[2], "positive is red");
        assert!(zero.iter().all(|&c| c > 230), "zero is neutral");
        assert_eq!(thermal(f64::NAN), zero);
    }

    #[test]
    fn quantile_of_abs() {
        let q = abs_quantile([-4.0, 1.0, 2.0, -3.0, 0.0].into_iter(), 1.0);
        assert_eq!(q, 4.0);
    }
}
