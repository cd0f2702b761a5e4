//! 2D image processing on the CPU, with no Vulkan: the references that the image-space style
//! passes (`render/post/`) are tested against, and the saliency metric of the two-level paper's
//! evaluation.
//!
//! Images are rows top to bottom, x fastest. Colour layers are premultiplied RGBA in float, as the
//! renderer writes them. Borders are clamped (a pixel outside reads its nearest edge pixel) in every
//! filter, on the GPU as here.

pub mod edges;
pub mod saliency;
pub mod stylise;

/// A single-channel float image.
#[derive(Clone, Debug, PartialEq)]
pub struct Plane {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// The `width`×`height` values, rows top to bottom, x fastest.
    pub data: Vec<f32>,
}

impl Plane {
    /// A plane of `width`×`height` zeros.
    pub fn new(width: usize, height: usize) -> Self {
        Plane {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    /// The value at (x, y), with coordinates clamped to the image.
    pub fn at(&self, x: i64, y: i64) -> f32 {
        let x = x.clamp(0, self.width as i64 - 1) as usize;
        let y = y.clamp(0, self.height as i64 - 1) as usize;
        self.data[y * self.width + x]
    }
}

/// Rec. 709 luma weights, applied to premultiplied colour (the layer over black).
pub(crate) const LUMA: [f32; 3] = [0.2126, 0.7152, 0.0722];

/// Luminance of a premultiplied RGBA pixel.
pub(crate) fn luminance(p: [f32; 4]) -> f32 {
    LUMA[0] * p[0] + LUMA[1] * p[1] + LUMA[2] * p[2]
}

/// The luminance plane of an RGBA layer.
pub fn luminance_plane(rgba: &[[f32; 4]], width: usize, height: usize) -> Plane {
    Plane {
        width,
        height,
        data: rgba.iter().map(|&p| luminance(p)).collect(),
    }
}

/// Normalised 1D Gaussian weights for σ (pixels) over −r..=r with r = ⌈3σ⌉, the same taps the
/// blur shader computes.
pub(crate) fn gaussian_weights(sigma: f32) -> Vec<f32> {
    let r = (3.0 * sigma).ceil().max(1.0) as i64;
    let w: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f32 = w.iter().sum();
    w.iter().map(|x| x / sum).collect()
}

/// Separable Gaussian blur of `p` with σ in pixels (clamped borders), x then y.
pub(crate) fn blur(p: &Plane, sigma: f32) -> Plane {
    let w = gaussian_weights(sigma);
    let r = (w.len() / 2) as i64;
    let pass = |src: &Plane, dx: i64, dy: i64| {
        let mut out = Plane::new(src.width, src.height);
        for y in 0..src.height as i64 {
            for x in 0..src.width as i64 {
                let mut acc = 0.0f32;
                for (k, wk) in w.iter().enumerate() {
                    let o = k as i64 - r;
                    acc += wk * src.at(x + o * dx, y + o * dy);
                }
                out.data[y as usize * src.width + x as usize] = acc;
            }
        }
        out
    };
    pass(&pass(p, 1, 0), 0, 1)
}
