//! Abstraction of the context layer (two-level paper §3; SPEC TL6) and the style composite, on
//! premultiplied RGBA: the classic four-quadrant Kuwahara filter, saturation variation, and edges
//! laid over the focus under the context.

#[cfg(test)]
use super::LUMA;
use super::{luminance, Plane};

/// Classic Kuwahara filter of radius `r`: each pixel takes the mean colour of whichever of its four
/// (r+1)×(r+1) quadrants (top-left, top-right, bottom-left, bottom-right, each including the pixel's
/// row and column) has the smallest luminance variance; the first such quadrant on ties.
pub fn kuwahara(rgba: &[[f32; 4]], width: usize, height: usize, r: usize) -> Vec<[f32; 4]> {
    let at = |x: i64, y: i64| {
        let x = x.clamp(0, width as i64 - 1) as usize;
        let y = y.clamp(0, height as i64 - 1) as usize;
        rgba[y * width + x]
    };
    let r = r as i64;
    let n = ((r + 1) * (r + 1)) as f32;
    let mut out = vec![[0.0f32; 4]; rgba.len()];
    for y in 0..height as i64 {
        for x in 0..width as i64 {
            let mut best = (f32::INFINITY, [0.0f32; 4]);
            for (qx, qy) in [(-r, -r), (0, -r), (-r, 0), (0, 0)] {
                let (mut sum, mut l1, mut l2) = ([0.0f32; 4], 0.0f32, 0.0f32);
                for dy in 0..=r {
                    for dx in 0..=r {
                        let p = at(x + qx + dx, y + qy + dy);
                        for c in 0..4 {
                            sum[c] += p[c];
                        }
                        let l = luminance(p);
                        l1 += l;
                        l2 += l * l;
                    }
                }
                let mean_l = l1 / n;
                let var = l2 / n - mean_l * mean_l;
                if var < best.0 {
                    best = (var, sum.map(|s| s / n));
                }
            }
            out[y as usize * width + x as usize] = best.1;
        }
    }
    out
}

/// Saturation variation: each colour moves towards its luminance Y by `factor` (0 grey, 1
/// unchanged, > 1 more saturated), Y kept, floored at 0; alpha unchanged.
pub fn saturate(p: [f32; 4], factor: f32) -> [f32; 4] {
    let y = luminance(p);
    let c = |v: f32| (y + factor * (v - y)).max(0.0);
    [c(p[0]), c(p[1]), c(p[2]), p[3]]
}

/// Sum of the luma weights, so that `saturate` keeps luminance exactly.
#[cfg(test)]
pub(crate) const LUMA_SUM: f32 = LUMA[0] + LUMA[1] + LUMA[2];

/// How edges are drawn.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct EdgeLook {
    /// Straight RGB of the edge lines, in [0, 1].
    pub color: [f32; 3],
    /// Scales edge strength; the product, clamped to [0, 1], is the line's alpha over the focus.
    pub opacity: f32,
    /// Line width in pixels: a pixel takes the strongest edge within (width − 1) / 2 pixels.
    pub width: u32,
}

/// The style composite: edges (strength `edges`, dilated to the line width) over the focus layer,
/// then the (abstracted) context over that, all premultiplied.
pub fn composite(
    focus: &[[f32; 4]],
    context: &[[f32; 4]],
    edges: Option<(&Plane, &EdgeLook)>,
) -> Vec<[f32; 4]> {
    focus
        .iter()
        .zip(context)
        .enumerate()
        .map(|(i, (&f, &c))| {
            let styled = match edges {
                Some((e, look)) => {
                    let (x, y) = ((i % e.width) as i64, (i / e.width) as i64);
                    let rho = (look.width.max(1) as i64 - 1) / 2;
                    let mut s = 0.0f32;
                    for dy in -rho..=rho {
                        for dx in -rho..=rho {
                            s = s.max(e.at(x + dx, y + dy));
                        }
                    }
                    let a = (s * look.opacity).clamp(0.0, 1.0);
                    [
                        look.color[0] * a + (1.0 - a) * f[0],
                        look.color[1] * a + (1.0 - a) * f[1],
                        look.color[2] * a + (1.0 - a) * f[2],
                        a + (1.0 - a) * f[3],
                    ]
                }
                None => f,
            };
            let k = 1.0 - c[3];
            [
                c[0] + k * styled[0],
                c[1] + k * styled[1],
                c[2] + k * styled[2],
                c[3] + k * styled[3],
            ]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn saturation_keeps_luminance_and_alpha() {
        let p = [0.6, 0.2, 0.1, 0.8];
        for f in [0.0, 0.3, 1.0] {
            let q = saturate(p, f);
            assert!((luminance(q) - luminance(p)).abs() < 1e-6);
            assert_eq!(q[3], 0.8);
        }
        let same = saturate(p, 1.0);
        assert!((0..4).all(|c| (same[c] - p[c]).abs() < 1e-6));
        let grey = saturate(p, 0.0);
        assert!((grey[0] - grey[1]).abs() < 1e-6 && (grey[1] - grey[2]).abs() < 1e-6);
        assert!((LUMA_SUM - 1.0).abs() < 1e-6);
    }

    #[test]
    fn kuwahara_keeps_a_step_sharp_and_flattens_noise() {
        let (w, h) = (12, 6);
        let img: Vec<[f32; 4]> = (0..w * h)
            .map(|i| {
                let v = if i % w >= 6 { 1.0 } else { 0.0 };
                let noise = if i % 3 == 0 { 0.05 } else { 0.0 };
                [v + noise, v + noise, v + noise, 1.0]
            })
            .collect();
        let k = kuwahara(&img, w, h, 2);
        for y in 0..h {
            assert!(
                k[y * w + 5][0] < 0.1 && k[y * w + 6][0] > 0.9,
                "row {y} step kept"
            );
        }
    }
}
