//! Edge detectors on the focus layer's luminance (two-level paper §3, stage 2; SPEC TL4): Sobel,
//! difference of Gaussians (with XDoG's soft threshold), and Canny. Each returns an edge strength
//! in [0, 1] per pixel. The GPU passes in `glsl/post/` implement the same arithmetic in f32.

use super::{blur, Plane};

/// Sobel gradient (gx, gy) at (x, y): x to the right, y down the image.
pub(crate) fn sobel_at(p: &Plane, x: i64, y: i64) -> (f32, f32) {
    let v = |dx: i64, dy: i64| p.at(x + dx, y + dy);
    let gx = (v(1, -1) + 2.0 * v(1, 0) + v(1, 1)) - (v(-1, -1) + 2.0 * v(-1, 0) + v(-1, 1));
    let gy = (v(-1, 1) + 2.0 * v(0, 1) + v(1, 1)) - (v(-1, -1) + 2.0 * v(0, -1) + v(1, -1));
    (gx, gy)
}

/// The largest Sobel magnitude of an image in [0, 1]: magnitudes are divided by it.
pub(crate) const SOBEL_MAX: f32 = 4.0 * std::f32::consts::SQRT_2;

/// Sobel magnitude, normalised to [0, 1].
pub fn sobel_magnitude(p: &Plane) -> Plane {
    let mut out = Plane::new(p.width, p.height);
    for y in 0..p.height {
        for x in 0..p.width {
            let (gx, gy) = sobel_at(p, x as i64, y as i64);
            out.data[y * p.width + x] = (gx * gx + gy * gy).sqrt() / SOBEL_MAX;
        }
    }
    out
}

/// Sobel edges: 1 where the normalised magnitude reaches `threshold`, else 0.
pub fn sobel_edges(luminance: &Plane, threshold: f32) -> Plane {
    let mut m = sobel_magnitude(luminance);
    for v in &mut m.data {
        *v = if *v >= threshold { 1.0 } else { 0.0 };
    }
    m
}

/// Parameters of the difference of Gaussians.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct DogParams {
    /// σ of the narrower Gaussian, pixels.
    pub sigma: f32,
    /// Ratio of the wider σ (1.6 approximates a Laplacian of Gaussian).
    pub k: f32,
    /// XDoG's τ: D = G_σ − τ·G_kσ (1 is the plain DoG).
    pub tau: f32,
    /// Threshold ε: edges where D < −ε.
    pub threshold: f32,
    /// Sharpness φ of the soft threshold.
    pub phi: f32,
}

/// DoG edge strength: tanh(φ·(−ε − D)) where D = G_σ − τ·G_kσ < −ε, else 0 (XDoG's soft
/// threshold, Winnemöller 2011, as an edge strength).
pub(crate) fn dog_strength(d: f32, p: &DogParams) -> f32 {
    let u = -p.threshold - d;
    if u > 0.0 {
        (p.phi * u).tanh()
    } else {
        0.0
    }
}

/// DoG edges of the luminance plane.
pub fn dog_edges(luminance: &Plane, p: &DogParams) -> Plane {
    let narrow = blur(luminance, p.sigma);
    let wide = blur(luminance, p.k * p.sigma);
    let mut out = Plane::new(luminance.width, luminance.height);
    for i in 0..out.data.len() {
        out.data[i] = dog_strength(narrow.data[i] - p.tau * wide.data[i], p);
    }
    out
}

/// Parameters of the Canny detector.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct CannyParams {
    /// σ of the smoothing Gaussian, pixels.
    pub sigma: f32,
    /// High threshold on the normalised gradient magnitude.
    pub high: f32,
    /// Low threshold as a fraction of the high one.
    pub low_ratio: f32,
}

/// tan 22.5° and tan 67.5°: the direction sectors of non-maximum suppression.
const TAN_22_5: f32 = 0.414_213_57;
const TAN_67_5: f32 = 2.414_213_6;

/// The two neighbour offsets along the gradient direction, quantised to 0°, 45°, 90° or 135°.
pub(crate) fn gradient_neighbours(gx: f32, gy: f32) -> [(i64, i64); 2] {
    let (ax, ay) = (gx.abs(), gy.abs());
    if ay <= TAN_22_5 * ax {
        [(1, 0), (-1, 0)]
    } else if ay >= TAN_67_5 * ax {
        [(0, 1), (0, -1)]
    } else if gx * gy > 0.0 {
        [(1, 1), (-1, -1)]
    } else {
        [(1, -1), (-1, 1)]
    }
}

/// Canny classes before hysteresis: 2 strong, 1 weak, 0 none (non-maximum suppression and the
/// double threshold). A pixel survives suppression when its magnitude is greater than its first
/// neighbour along the gradient and at least its second, so plateaus keep one side.
pub(crate) fn canny_classes(luminance: &Plane, p: &CannyParams) -> Plane {
    let smooth = blur(luminance, p.sigma);
    let (w, h) = (smooth.width, smooth.height);
    let mut grad = vec![(0.0f32, 0.0f32, 0.0f32); w * h];
    for y in 0..h {
        for x in 0..w {
            let (gx, gy) = sobel_at(&smooth, x as i64, y as i64);
            grad[y * w + x] = (gx, gy, (gx * gx + gy * gy).sqrt() / SOBEL_MAX);
        }
    }
    let mag = |x: i64, y: i64| {
        let x = x.clamp(0, w as i64 - 1) as usize;
        let y = y.clamp(0, h as i64 - 1) as usize;
        grad[y * w + x].2
    };
    let low = p.high * p.low_ratio;
    let mut out = Plane::new(w, h);
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            let (gx, gy, m) = grad[(y as usize) * w + x as usize];
            let [a, b] = gradient_neighbours(gx, gy);
            let keep = m > mag(x + a.0, y + a.1) && m >= mag(x + b.0, y + b.1);
            out.data[y as usize * w + x as usize] = match (keep, m) {
                (true, m) if m >= p.high => 2.0,
                (true, m) if m >= low => 1.0,
                _ => 0.0,
            };
        }
    }
    out
}

/// Hysteresis: weak pixels 8-connected to a strong one become strong; then 1 for strong, 0 else.
pub(crate) fn hysteresis(classes: &Plane) -> Plane {
    let (w, h) = (classes.width, classes.height);
    let mut state = classes.data.clone();
    let mut stack: Vec<usize> = (0..w * h).filter(|&i| state[i] == 2.0).collect();
    while let Some(i) = stack.pop() {
        let (x, y) = ((i % w) as i64, (i / w) as i64);
        for dy in -1..=1 {
            for dx in -1..=1 {
                let (nx, ny) = (x + dx, y + dy);
                if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                    continue;
                }
                let j = ny as usize * w + nx as usize;
                if state[j] == 1.0 {
                    state[j] = 2.0;
                    stack.push(j);
                }
            }
        }
    }
    Plane {
        width: w,
        height: h,
        data: state
            .iter()
            .map(|&s| if s == 2.0 { 1.0 } else { 0.0 })
            .collect(),
    }
}

/// Canny edges of the luminance plane.
pub fn canny_edges(luminance: &Plane, p: &CannyParams) -> Plane {
    hysteresis(&canny_classes(luminance, p))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(w: usize, h: usize, at: usize) -> Plane {
        let mut p = Plane::new(w, h);
        for y in 0..h {
            for x in at..w {
                p.data[y * w + x] = 1.0;
            }
        }
        p
    }

    #[test]
    fn a_vertical_step_gives_vertical_edges() {
        let p = step(16, 8, 8);
        let s = sobel_edges(&p, 0.3);
        for y in 0..8 {
            let row: Vec<f32> = (0..16).map(|x| s.data[y * 16 + x]).collect();
            assert_eq!(&row[6..10], &[0.0, 1.0, 1.0, 0.0], "row {y}");
        }
        let c = canny_edges(
            &p,
            &CannyParams {
                sigma: 1.0,
                high: 0.2,
                low_ratio: 0.4,
            },
        );
        // One-pixel-wide line: exactly one edge pixel per row, beside the step.
        for y in 0..8 {
            let xs: Vec<usize> = (0..16).filter(|&x| c.data[y * 16 + x] == 1.0).collect();
            assert_eq!(xs.len(), 1, "row {y}: {xs:?}");
            assert!((7..=8).contains(&xs[0]));
        }
        let d = dog_edges(
            &p,
            &DogParams {
                sigma: 1.0,
                k: 1.6,
                tau: 1.0,
                threshold: 0.005,
                phi: 100.0,
            },
        );
        // DoG marks the dark side of the step.
        assert!(d.data[4 * 16 + 7] > 0.5 && d.data[4 * 16 + 9] == 0.0);
        assert!(d.data[4 * 16 + 2] == 0.0);
    }

    #[test]
    fn hysteresis_follows_weak_chains_from_strong_pixels_only() {
        let mut c = Plane::new(8, 3);
        c.data[8..16].copy_from_slice(&[2.0, 1.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0]);
        let e = hysteresis(&c);
        assert_eq!(&e.data[8..16], &[1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    }
}
