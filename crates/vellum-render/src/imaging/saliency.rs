//! The saliency metric of Itti, Koch and Niebur (1998), "A model of saliency-based visual attention
//! for rapid scene analysis", which the two-level paper's evaluation (§4) uses to show that styles
//! raise the focus's saliency and lower the context's.
//!
//! Following the paper:
//! - dyadic Gaussian pyramids (5-tap binomial filter, levels 0..=8) of intensity I = (r+g+b)/3,
//!   of the broadly tuned colours R, G, B, Y (hue normalised by I where I > max I / 10), and of
//!   orientation: Gabor responses at 0°, 45°, 90°, 135° of each intensity level;
//! - centre–surround differences between centre levels c ∈ {2, 3, 4} and surrounds s = c + δ,
//!   δ ∈ {3, 4}: |I(c) ⊖ I(s)|, |(R−G)(c) ⊖ (G−R)(s)|, |(B−Y)(c) ⊖ (Y−B)(s)|, |O(c,θ) ⊖ O(s,θ)|;
//! - the normalisation operator N: scale to [0, 1], then multiply by (1 − m̄)², m̄ being the mean of
//!   the local maxima other than the global one;
//! - conspicuity maps summed across scales at level 4, and S = (N(Ī) + N(C̄) + N(Ō)) / 3.
//!
//! The map is returned at the input's size (bilinear from level 4).

use super::Plane;

/// Pyramid levels; the surround of the coarsest centre (4 + 4) is the last.
const LEVELS: usize = 9;
const CENTRES: [usize; 3] = [2, 3, 4];
const DELTAS: [usize; 2] = [3, 4];
/// The level at which maps are summed.
const SUM_LEVEL: usize = 4;

/// 5-tap binomial blur then every other pixel (one pyramid step).
fn reduce(p: &Plane) -> Plane {
    const K: [f32; 5] = [1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];
    let (w, h) = ((p.width / 2).max(1), (p.height / 2).max(1));
    let mut horiz = Plane::new(p.width, p.height);
    for y in 0..p.height as i64 {
        for x in 0..p.width as i64 {
            horiz.data[y as usize * p.width + x as usize] =
                (0..5).map(|k| K[k] * p.at(x + k as i64 - 2, y)).sum();
        }
    }
    let mut out = Plane::new(w, h);
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            out.data[y as usize * w + x as usize] = (0..5)
                .map(|k| K[k] * horiz.at(2 * x, 2 * y + k as i64 - 2))
                .sum();
        }
    }
    out
}

fn pyramid(p: Plane) -> Vec<Plane> {
    let mut levels = vec![p];
    while levels.len() < LEVELS {
        let next = reduce(levels.last().expect("one level at least"));
        levels.push(next);
    }
    levels
}

/// Bilinear resampling of `p` to `w`×`h` (pixel centres aligned).
fn resize(p: &Plane, w: usize, h: usize) -> Plane {
    let mut out = Plane::new(w, h);
    let sx = p.width as f32 / w as f32;
    let sy = p.height as f32 / h as f32;
    for y in 0..h {
        for x in 0..w {
            let fx = ((x as f32 + 0.5) * sx - 0.5).max(0.0);
            let fy = ((y as f32 + 0.5) * sy - 0.5).max(0.0);
            let (x0, y0) = (fx.floor() as i64, fy.floor() as i64);
            let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
            let v = |dx: i64, dy: i64| p.at(x0 + dx, y0 + dy);
            out.data[y * w + x] = (1.0 - ty) * ((1.0 - tx) * v(0, 0) + tx * v(1, 0))
                + ty * ((1.0 - tx) * v(0, 1) + tx * v(1, 1));
        }
    }
    out
}

/// |a ⊖ b|: `b` (coarser) brought to `a`'s size, pointwise absolute difference.
fn across_difference(a: &Plane, b: &Plane) -> Plane {
    let b = resize(b, a.width, a.height);
    Plane {
        width: a.width,
        height: a.height,
        data: a
            .data
            .iter()
            .zip(&b.data)
            .map(|(x, y)| (x - y).abs())
            .collect(),
    }
}

fn combine(a: &Plane, b: &Plane, f: impl Fn(f32, f32) -> f32) -> Plane {
    Plane {
        width: a.width,
        height: a.height,
        data: a.data.iter().zip(&b.data).map(|(&x, &y)| f(x, y)).collect(),
    }
}

/// The normalisation operator N(·).
pub(crate) fn normalise(p: &Plane) -> Plane {
    let max = p.data.iter().copied().fold(0.0f32, f32::max);
    if max <= 0.0 {
        return p.clone();
    }
    let scaled: Vec<f32> = p.data.iter().map(|v| v / max).collect();
    let s = Plane {
        width: p.width,
        height: p.height,
        data: scaled,
    };
    // Local maxima: at least every 8-neighbour, and above a small floor (flat zero regions are no
    // maxima). The global maximum (1) is left out of the mean.
    let (mut sum, mut n) = (0.0f64, 0usize);
    for y in 0..s.height as i64 {
        for x in 0..s.width as i64 {
            let v = s.at(x, y);
            if v <= 0.01 || v >= 1.0 {
                continue;
            }
            let is_max = (-1..=1)
                .all(|dy| (-1..=1).all(|dx| (dx == 0 && dy == 0) || s.at(x + dx, y + dy) <= v));
            if is_max {
                sum += v as f64;
                n += 1;
            }
        }
    }
    let mean = if n > 0 { (sum / n as f64) as f32 } else { 0.0 };
    let k = (1.0 - mean) * (1.0 - mean);
    Plane {
        width: s.width,
        height: s.height,
        data: s.data.iter().map(|v| v * k).collect(),
    }
}

/// Sum of maps brought to the size of `like`.
fn across_sum(maps: &[Plane], like: &Plane) -> Plane {
    let mut out = Plane::new(like.width, like.height);
    for m in maps {
        let r = resize(m, like.width, like.height);
        for (o, v) in out.data.iter_mut().zip(&r.data) {
            *o += v;
        }
    }
    out
}

/// Real Gabor kernel at angle `theta` (radians): wavelength 4, σ 2, 9×9 taps, zero mean.
fn gabor_kernel(theta: f32) -> Vec<(i64, i64, f32)> {
    let (lambda, sigma) = (4.0f32, 2.0f32);
    let mut k = Vec::new();
    for dy in -4..=4i64 {
        for dx in -4..=4i64 {
            let (x, y) = (dx as f32, dy as f32);
            let u = x * theta.cos() + y * theta.sin();
            let g = (-(x * x + y * y) / (2.0 * sigma * sigma)).exp()
                * (2.0 * std::f32::consts::PI * u / lambda).cos();
            k.push((dx, dy, g));
        }
    }
    let mean = k.iter().map(|t| t.2).sum::<f32>() / k.len() as f32;
    k.iter().map(|&(x, y, g)| (x, y, g - mean)).collect()
}

fn gabor(p: &Plane, kernel: &[(i64, i64, f32)]) -> Plane {
    let mut out = Plane::new(p.width, p.height);
    for y in 0..p.height as i64 {
        for x in 0..p.width as i64 {
            let v: f32 = kernel
                .iter()
                .map(|&(dx, dy, g)| g * p.at(x + dx, y + dy))
                .sum();
            out.data[y as usize * p.width + x as usize] = v.abs();
        }
    }
    out
}

/// The saliency map of an RGB image (`rgb` in [0, 1], rows top to bottom), at the image's size
/// and scaled to [0, 1].
pub fn saliency(rgb: &[[f32; 3]], width: usize, height: usize) -> Plane {
    let intensity: Vec<f32> = rgb.iter().map(|p| (p[0] + p[1] + p[2]) / 3.0).collect();
    let max_i = intensity.iter().copied().fold(0.0f32, f32::max);
    let channel = |f: &dyn Fn([f32; 3]) -> f32| Plane {
        width,
        height,
        data: rgb
            .iter()
            .zip(&intensity)
            .map(|(&p, &i)| {
                if i > max_i / 10.0 && i > 0.0 {
                    f(p.map(|c| c / i)).max(0.0)
                } else {
                    0.0
                }
            })
            .collect(),
    };
    let r = pyramid(channel(&|p| p[0] - (p[1] + p[2]) / 2.0));
    let g = pyramid(channel(&|p| p[1] - (p[0] + p[2]) / 2.0));
    let b = pyramid(channel(&|p| p[2] - (p[0] + p[1]) / 2.0));
    let y = pyramid(channel(&|p| {
        (p[0] + p[1]) / 2.0 - (p[0] - p[1]).abs() / 2.0 - p[2]
    }));
    let i = pyramid(Plane {
        width,
        height,
        data: intensity.clone(),
    });
    let base = &i[SUM_LEVEL];
    let pairs: Vec<(usize, usize)> = CENTRES
        .iter()
        .flat_map(|&c| DELTAS.iter().map(move |&d| (c, c + d)))
        .collect();

    let i_maps: Vec<Plane> = pairs
        .iter()
        .map(|&(c, s)| normalise(&across_difference(&i[c], &i[s])))
        .collect();
    let c_maps: Vec<Plane> = pairs
        .iter()
        .map(|&(c, s)| {
            let rg = across_difference(
                &combine(&r[c], &g[c], |a, b| a - b),
                &combine(&g[s], &r[s], |a, b| a - b),
            );
            let by = across_difference(
                &combine(&b[c], &y[c], |a, b| a - b),
                &combine(&y[s], &b[s], |a, b| a - b),
            );
            combine(&normalise(&rg), &normalise(&by), |a, b| a + b)
        })
        .collect();
    let mut o_bar = Plane::new(base.width, base.height);
    for k in 0..4 {
        let kernel = gabor_kernel(k as f32 * std::f32::consts::FRAC_PI_4);
        let o: Vec<Plane> = i.iter().map(|level| gabor(level, &kernel)).collect();
        let maps: Vec<Plane> = pairs
            .iter()
            .map(|&(c, s)| normalise(&across_difference(&o[c], &o[s])))
            .collect();
        let n = normalise(&across_sum(&maps, base));
        for (acc, v) in o_bar.data.iter_mut().zip(&n.data) {
            *acc += v;
        }
    }
    let i_bar = across_sum(&i_maps, base);
    let c_bar = across_sum(&c_maps, base);
    let (ni, nc, no) = (normalise(&i_bar), normalise(&c_bar), normalise(&o_bar));
    let s = Plane {
        width: base.width,
        height: base.height,
        data: (0..ni.data.len())
            .map(|k| (ni.data[k] + nc.data[k] + no.data[k]) / 3.0)
            .collect(),
    };
    let mut full = resize(&s, width, height);
    let max = full.data.iter().copied().fold(0.0f32, f32::max);
    if max > 0.0 {
        full.data.iter_mut().for_each(|v| *v /= max);
    }
    full
}

/// Mean saliency inside and outside a mask (true = inside).
pub fn inside_outside(map: &Plane, mask: &[bool]) -> (f64, f64) {
    let (mut si, mut ni, mut so, mut no) = (0.0f64, 0usize, 0.0f64, 0usize);
    for (v, &m) in map.data.iter().zip(mask) {
        if m {
            si += *v as f64;
            ni += 1;
        } else {
            so += *v as f64;
            no += 1;
        }
    }
    (si / ni.max(1) as f64, so / no.max(1) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Discs of one colour on grey, one of them another colour: the odd one is the most salient.
    fn discs(odd: usize, odd_colour: [f32; 3]) -> (Vec<[f32; 3]>, Vec<(f32, f32)>) {
        let (w, h) = (256usize, 256usize);
        let centres: Vec<(f32, f32)> = (0..16)
            .map(|k| (32.0 + 64.0 * (k % 4) as f32, 32.0 + 64.0 * (k / 4) as f32))
            .collect();
        let mut img = vec![[0.5f32; 3]; w * h];
        for (k, &(cx, cy)) in centres.iter().enumerate() {
            let c = if k == odd {
                odd_colour
            } else {
                [0.1, 0.2, 0.9]
            };
            for y in 0..h {
                for x in 0..w {
                    let (dx, dy) = (x as f32 + 0.5 - cx, y as f32 + 0.5 - cy);
                    if dx * dx + dy * dy <= 12.0 * 12.0 {
                        img[y * w + x] = c;
                    }
                }
            }
        }
        (img, centres)
    }

    #[test]
    fn the_odd_coloured_disc_is_the_most_salient_point() {
        for (odd, colour) in [(5, [0.9, 0.2, 0.1]), (10, [0.9, 0.9, 0.1])] {
            let (img, centres) = discs(odd, colour);
            let s = saliency(&img, 256, 256);
            let (mut best, mut at) = (f32::MIN, 0);
            for (i, &v) in s.data.iter().enumerate() {
                if v > best {
                    best = v;
                    at = i;
                }
            }
            let (x, y) = ((at % 256) as f32 + 0.5, (at / 256) as f32 + 0.5);
            let (cx, cy) = centres[odd];
            let d = ((x - cx).powi(2) + (y - cy).powi(2)).sqrt();
            assert!(
                d <= 20.0,
                "disc {odd}: the most salient point ({x}, {y}) is {d} px from it"
            );
        }
    }

    #[test]
    fn normalisation_promotes_a_single_peak_over_many() {
        let mut one = Plane::new(32, 32);
        one.data[16 * 32 + 16] = 1.0;
        let mut many = Plane::new(32, 32);
        for k in 0..16 {
            many.data[(2 * k) * 32 + 2 * k] = 1.0 - 0.01 * k as f32;
        }
        let (a, b) = (normalise(&one), normalise(&many));
        let peak = |p: &Plane| p.data.iter().copied().fold(0.0f32, f32::max);
        assert!(
            peak(&a) > 0.99 && peak(&b) < 0.1,
            "{} {}",
            peak(&a),
            peak(&b)
        );
    }
}
