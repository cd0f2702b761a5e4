//! A small RGB canvas for figures written as PNG: the occlusion spectrum (a log-scaled 2D
//! histogram with axes) and line plots such as the radius sensitivity. Labels use a built-in 3×5
//! pixel font (digits, upper-case letters and a few signs), so no font files are needed.

/// An RGB image being drawn on.
pub struct Canvas {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// The pixels as 8-bit RGB triples, rows top to bottom, x fastest (`width`×`height`×3 bytes).
    pub rgb: Vec<u8>,
}

/// 3×5 glyphs, one row of 3 bits per entry, top row first.
fn glyph(c: char) -> [u8; 5] {
    match c.to_ascii_uppercase() {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 2, 2],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        'A' => [2, 5, 7, 5, 5],
        'B' => [6, 5, 6, 5, 6],
        'C' => [3, 4, 4, 4, 3],
        'D' => [6, 5, 5, 5, 6],
        'E' => [7, 4, 6, 4, 7],
        'F' => [7, 4, 6, 4, 4],
        'G' => [3, 4, 5, 5, 3],
        'H' => [5, 5, 7, 5, 5],
        'I' => [7, 2, 2, 2, 7],
        'J' => [1, 1, 1, 5, 2],
        'K' => [5, 5, 6, 5, 5],
        'L' => [4, 4, 4, 4, 7],
        'M' => [5, 7, 7, 5, 5],
        'N' => [6, 5, 5, 5, 5],
        'O' => [2, 5, 5, 5, 2],
        'P' => [6, 5, 6, 4, 4],
        'Q' => [2, 5, 5, 6, 3],
        'R' => [6, 5, 6, 5, 5],
        'S' => [3, 4, 2, 1, 6],
        'T' => [7, 2, 2, 2, 2],
        'U' => [5, 5, 5, 5, 7],
        'V' => [5, 5, 5, 5, 2],
        'W' => [5, 5, 7, 7, 5],
        'X' => [5, 5, 2, 5, 5],
        'Y' => [5, 5, 2, 2, 2],
        'Z' => [7, 1, 2, 4, 7],
        '.' => [0, 0, 0, 0, 2],
        '-' => [0, 0, 7, 0, 0],
        '+' => [0, 2, 7, 2, 0],
        '=' => [0, 7, 0, 7, 0],
        ':' => [0, 2, 0, 2, 0],
        '(' => [1, 2, 2, 2, 1],
        ')' => [4, 2, 2, 2, 4],
        '/' => [1, 1, 2, 4, 4],
        _ => [0; 5],
    }
}

impl Canvas {
    /// A canvas filled with `background`.
    pub fn new(width: usize, height: usize, background: [u8; 3]) -> Self {
        Canvas {
            width,
            height,
            rgb: background
                .iter()
                .copied()
                .cycle()
                .take(width * height * 3)
                .collect(),
        }
    }

    /// Sets one pixel (ignored outside the canvas).
    pub fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            let i = (y as usize * self.width + x as usize) * 3;
            self.rgb[i..i + 3].copy_from_slice(&c);
        }
    }

    /// A filled rectangle.
    pub fn rect(&mut self, x: i64, y: i64, w: i64, h: i64, c: [u8; 3]) {
        for yy in y..y + h {
            for xx in x..x + w {
                self.set(xx, yy, c);
            }
        }
    }

    /// A line (Bresenham).
    pub fn line(&mut self, (x0, y0): (i64, i64), (x1, y1): (i64, i64), c: [u8; 3]) {
        let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
        let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
        let (mut x, mut y, mut err) = (x0, y0, dx + dy);
        loop {
            self.set(x, y, c);
            if x == x1 && y == y1 {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// Text with its top-left corner at (x, y), each font pixel `scale` pixels wide.
    pub fn text(&mut self, x: i64, y: i64, s: &str, scale: i64, c: [u8; 3]) {
        for (i, ch) in s.chars().enumerate() {
            let g = glyph(ch);
            for (row, bits) in g.iter().enumerate() {
                for col in 0..3 {
                    if bits >> (2 - col) & 1 == 1 {
                        self.rect(
                            x + (i as i64 * 4 + col) * scale,
                            y + row as i64 * scale,
                            scale,
                            scale,
                            c,
                        );
                    }
                }
            }
        }
    }

    /// Width in pixels of `s` drawn by [`Canvas::text`].
    pub fn text_width(s: &str, scale: i64) -> i64 {
        (s.chars().count() as i64 * 4 - 1) * scale
    }
}

/// A sequential colour map (black, purple, orange, pale yellow) for t in [0, 1].
pub fn heat(t: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 5] = [
        [0.0, 0.0, 0.02],
        [0.33, 0.06, 0.43],
        [0.73, 0.21, 0.33],
        [0.98, 0.55, 0.04],
        [0.99, 0.99, 0.75],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    } * (STOPS.len() - 1) as f64;
    let i = (t.floor() as usize).min(STOPS.len() - 2);
    let f = t - i as f64;
    std::array::from_fn(|k| {
        ((STOPS[i][k] + f * (STOPS[i + 1][k] - STOPS[i][k])) * 255.0).round() as u8
    })
}

/// Distinct line colours for plots.
pub(crate) const PALETTE: [[u8; 3]; 8] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
];

/// A 2D histogram as a log-scaled image with labelled axes: `counts[y * bins_x + x]`, y upwards.
/// `x_range` and `y_range` label the axes' ends.
pub fn histogram_2d(
    counts: &[u32],
    bins: [usize; 2],
    x_label: &str,
    x_range: [f64; 2],
    y_label: &str,
    y_range: [f64; 2],
) -> Canvas {
    let scale = (512 / bins[0].max(bins[1]).max(1)).max(1);
    let (pw, ph) = (bins[0] * scale, bins[1] * scale);
    let (left, bottom, top, right) = (44usize, 40usize, 12usize, 16usize);
    let mut c = Canvas::new(pw + left + right, ph + top + bottom, [255, 255, 255]);
    let max = counts.iter().copied().max().unwrap_or(0).max(1) as f64;
    for by in 0..bins[1] {
        for bx in 0..bins[0] {
            let n = counts[by * bins[0] + bx] as f64;
            let col = if n > 0.0 {
                heat(0.15 + 0.85 * (1.0 + n).ln() / (1.0 + max).ln())
            } else {
                [0, 0, 0]
            };
            c.rect(
                (left + bx * scale) as i64,
                (top + ph - (by + 1) * scale) as i64,
                scale as i64,
                scale as i64,
                col,
            );
        }
    }
    axes(
        &mut c,
        (left, top, pw, ph),
        x_label,
        x_range,
        y_label,
        y_range,
    );
    c
}

/// Axes with ticks at 0, ¼, ½, ¾ and 1 of each range around the plot area (x0, y0, w, h).
pub(crate) fn axes(
    c: &mut Canvas,
    (x0, y0, w, h): (usize, usize, usize, usize),
    x_label: &str,
    x_range: [f64; 2],
    y_label: &str,
    y_range: [f64; 2],
) {
    let ink = [30, 30, 30];
    let (x0, y0, w, h) = (x0 as i64, y0 as i64, w as i64, h as i64);
    c.line((x0 - 1, y0 + h), (x0 + w, y0 + h), ink);
    c.line((x0 - 1, y0), (x0 - 1, y0 + h), ink);
    let fmt = |v: f64| {
        if v.abs() >= 100.0 || v == v.round() {
            format!("{v:.0}")
        } else if v.abs() < 0.1 {
            format!("{v:.1e}")
        } else {
            format!("{v:.2}")
        }
    };
    for i in 0..=4 {
        let f = i as f64 / 4.0;
        let tx = x0 + (f * (w - 1) as f64) as i64;
        c.line((tx, y0 + h), (tx, y0 + h + 4), ink);
        let label = fmt(x_range[0] + f * (x_range[1] - x_range[0]));
        c.text(
            tx - Canvas::text_width(&label, 1) / 2,
            y0 + h + 7,
            &label,
            1,
            ink,
        );
        let ty = y0 + h - (f * (h - 1) as f64) as i64;
        c.line((x0 - 5, ty), (x0 - 1, ty), ink);
        let label = fmt(y_range[0] + f * (y_range[1] - y_range[0]));
        c.text(
            x0 - 7 - Canvas::text_width(&label, 1),
            ty - 2,
            &label,
            1,
            ink,
        );
    }
    c.text(
        x0 + w / 2 - Canvas::text_width(x_label, 2) / 2,
        y0 + h + 18,
        x_label,
        2,
        ink,
    );
    for (i, ch) in y_label.chars().enumerate() {
        c.text(
            4,
            y0 + h / 2 - (y_label.len() as i64 * 12) / 2 + i as i64 * 12,
            &ch.to_string(),
            2,
            ink,
        );
    }
}
