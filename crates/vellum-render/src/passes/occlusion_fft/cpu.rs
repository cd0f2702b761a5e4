//! The FFT method on the CPU: realfft/rustfft 1D transforms, parallel with rayon over lines.
//!
//! The half spectrum is stored x fastest: `s[kx + half·(y + Py·z)]`, half = Px/2 + 1.
//! - **x** (real-to-complex) runs on contiguous rows.
//! - **y** runs inside one z-plane at a time (a plane is a few hundred KiB, so it stays in cache):
//!   [`CHUNK`] neighbouring kx columns are gathered into a contiguous buffer, transformed, scattered.
//! - **z** gathers the same chunks across planes, one y at a time.
//!
//! Zero padding is pruned: rows that are all zero are never transformed, and the inverse
//! computes only the planes, rows and columns the output samples. The forward z transform, the
//! product with the kernel spectrum and the inverse z transform are fused per line, so the
//! product never makes a pass of its own and the data spectrum stays intact for reuse (a radius
//! sweep transforms the data once).

use super::{Denominator, Kernel};
use rayon::prelude::*;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::num_complex::Complex32;
use rustfft::Fft;
use std::sync::Arc;

/// Columns transformed together along y and z.
pub(crate) const CHUNK: usize = 16;

/// A raw pointer shared by tasks that write disjoint lines of one buffer.
#[derive(Clone, Copy)]
struct Lines(*mut Complex32);
// SAFETY: every task that holds a copy writes only the lines it owns (a distinct y, or a
// distinct z-plane), and nothing reads those lines until the parallel loop has joined.
unsafe impl Send for Lines {}
unsafe impl Sync for Lines {}

/// Plans for one padded size.
pub(crate) struct CpuFft {
    /// The padded size (Px, Py, Pz) in voxels that the plans transform.
    pub pad: [usize; 3],
    /// Px/2 + 1: the number of x coefficients a real-to-complex row keeps.
    pub half: usize,
    r2c: Arc<dyn RealToComplex<f32>>,
    c2r: Arc<dyn ComplexToReal<f32>>,
    y: [Arc<dyn Fft<f32>>; 2],
    z: [Arc<dyn Fft<f32>>; 2],
}

/// A half spectrum and the padded size it belongs to.
pub(crate) struct HalfSpectrum {
    /// The half·Py·Pz coefficients, x fastest (`s[kx + half·(y + Py·z)]`); z is untransformed when
    /// [`CpuFft::forward`] ran without `full`.
    pub data: Vec<Complex32>,
}

impl CpuFft {
    /// Plans the x, y and z transforms, forward and inverse, for the padded size `pad`.
    pub fn new(pad: [usize; 3]) -> Self {
        let mut real = RealFftPlanner::<f32>::new();
        let mut complex = rustfft::FftPlanner::<f32>::new();
        CpuFft {
            pad,
            half: pad[0] / 2 + 1,
            r2c: real.plan_fft_forward(pad[0]),
            c2r: real.plan_fft_inverse(pad[0]),
            y: [
                complex.plan_fft_forward(pad[1]),
                complex.plan_fft_inverse(pad[1]),
            ],
            z: [
                complex.plan_fft_forward(pad[2]),
                complex.plan_fft_inverse(pad[2]),
            ],
        }
    }

    /// Transforms along y, in place, the columns of every z-plane in `planes` (all y rows; the
    /// caller's zero rows stay zero). `dir` 0 forward, 1 inverse.
    fn y_pass(&self, data: &mut [Complex32], live_z: &(dyn Fn(usize) -> bool + Sync), dir: usize) {
        let (half, py) = (self.half, self.pad[1]);
        let fft = &self.y[dir];
        data.par_chunks_mut(half * py)
            .enumerate()
            .filter(|(z, _)| live_z(*z))
            .for_each_init(
                || {
                    (
                        vec![Complex32::default(); CHUNK * py],
                        vec![Complex32::default(); fft.get_inplace_scratch_len()],
                    )
                },
                |(buf, scratch), (_, plane)| {
                    for x0 in (0..half).step_by(CHUNK) {
                        let w = CHUNK.min(half - x0);
                        for y in 0..py {
                            for b in 0..w {
                                buf[b * py + y] = plane[x0 + b + half * y];
                            }
                        }
                        fft.process_with_scratch(&mut buf[..w * py], scratch);
                        for y in 0..py {
                            for b in 0..w {
                                plane[x0 + b + half * y] = buf[b * py + y];
                            }
                        }
                    }
                },
            );
    }

    /// The half spectrum of a real field given row by row: `fill(y, z, row)` writes row (y, z)
    /// (length Px, zeroed beforehand) for the rows where `live_y(y) && live_z(z)`; every other
    /// row is zero. With `full`, all three axes are transformed; without, z is left to
    /// [`CpuFft::convolve`], which fuses it with the product.
    pub fn forward(
        &self,
        live_y: &(dyn Fn(usize) -> bool + Sync),
        live_z: &(dyn Fn(usize) -> bool + Sync),
        fill: &(dyn Fn(usize, usize, &mut [f32]) + Sync),
        full: bool,
    ) -> HalfSpectrum {
        let [px, py, pz] = self.pad;
        let half = self.half;
        let mut data = vec![Complex32::default(); half * py * pz];
        // x: real rows to half spectra.
        let r2c = &self.r2c;
        data.par_chunks_mut(half * py)
            .enumerate()
            .filter(|(z, _)| live_z(*z))
            .for_each_init(
                || (vec![0f32; px], r2c.make_scratch_vec()),
                |(row, scratch), (z, plane)| {
                    for y in (0..py).filter(|&y| live_y(y)) {
                        row.iter_mut().for_each(|v| *v = 0.0);
                        fill(y, z, row);
                        // Lengths are right by construction; realfft only reports wrong lengths.
                        let _ = r2c.process_with_scratch(
                            row,
                            &mut plane[y * half..(y + 1) * half],
                            scratch,
                        );
                    }
                },
            );
        self.y_pass(&mut data, live_z, 0);
        if full {
            let lines = Lines(data.as_mut_ptr());
            let fft = &self.z[0];
            (0..py).into_par_iter().for_each_init(
                || {
                    (
                        vec![Complex32::default(); CHUNK * pz],
                        vec![Complex32::default(); fft.get_inplace_scratch_len()],
                    )
                },
                |(buf, scratch), y| {
                    let p = lines;
                    for x0 in (0..half).step_by(CHUNK) {
                        let w = CHUNK.min(half - x0);
                        for z in 0..pz {
                            for b in 0..w {
                                // SAFETY: this task owns every line with this y.
                                buf[b * pz + z] = unsafe { *p.0.add(x0 + b + half * (y + py * z)) };
                            }
                        }
                        fft.process_with_scratch(&mut buf[..w * pz], scratch);
                        for z in 0..pz {
                            for b in 0..w {
                                unsafe { *p.0.add(x0 + b + half * (y + py * z)) = buf[b * pz + z] };
                            }
                        }
                    }
                },
            );
        }
        HalfSpectrum { data }
    }

    /// The real spectrum of `kernel` (even, so its DFT is real), wrapped around the origin and cut
    /// at the reach of `dims`.
    pub(crate) fn kernel_spectrum(&self, kernel: Kernel, dims: [usize; 3]) -> Vec<f32> {
        let [px, py, pz] = self.pad;
        let r = kernel.radius();
        let e = dims.map(|n| super::reach(r, n));
        // Offset of padded coordinate c along an axis of size p, or None when beyond the reach.
        let offset = |c: usize, p: usize, e: usize| -> Option<i64> {
            if c <= e {
                Some(c as i64)
            } else if c >= p - e {
                Some(c as i64 - p as i64)
            } else {
                None
            }
        };
        let fill = |y: usize, z: usize, row: &mut [f32]| {
            let (Some(dy), Some(dz)) = (offset(y, py, e[1]), offset(z, pz, e[2])) else {
                return;
            };
            for (x, v) in row.iter_mut().enumerate() {
                if let Some(dx) = offset(x, px, e[0]) {
                    *v = kernel.weight([dx, dy, dz]);
                }
            }
        };
        let s = self.forward(
            &|y| offset(y, py, e[1]).is_some(),
            &|z| offset(z, pz, e[2]).is_some(),
            &fill,
            true,
        );
        s.data.into_par_iter().map(|c| c.re).collect()
    }

    /// The forward transform (x and y; z is fused into [`CpuFft::convolve`]) of the field
    /// `values` (x fastest, `dims`), zero-padded.
    pub(crate) fn data_spectrum(&self, values: &[f32], dims: [usize; 3]) -> HalfSpectrum {
        let fill = |y: usize, z: usize, row: &mut [f32]| {
            let start = dims[0] * (y + dims[1] * z);
            row[..dims[0]].copy_from_slice(&values[start..start + dims[0]]);
        };
        self.forward(&|y| y < dims[1], &|z| z < dims[2], &fill, false)
    }

    /// O at the output grid of `stride`: the inverse of (data · kernel) divided by `den`, clamped
    /// to [0, 1] (a mean of values in [0, 1]; round-off may stray by ~1e-7).
    pub(crate) fn convolve(
        &self,
        data: &HalfSpectrum,
        kernel: &[f32],
        dims: [usize; 3],
        den: &Denominator,
        stride: usize,
    ) -> Vec<f32> {
        let [px, py, pz] = self.pad;
        let half = self.half;
        let out_dims = dims.map(|d| d.div_ceil(stride));
        let nzo = out_dims[2];
        // z: forward, product, inverse; only the sampled planes are kept.
        let mut t = vec![Complex32::default(); half * py * nzo];
        {
            let lines = Lines(t.as_mut_ptr());
            let (fwd, inv) = (&self.z[0], &self.z[1]);
            let src = &data.data;
            (0..py).into_par_iter().for_each_init(
                || {
                    (
                        vec![Complex32::default(); CHUNK * pz],
                        vec![
                            Complex32::default();
                            fwd.get_inplace_scratch_len()
                                .max(inv.get_inplace_scratch_len())
                        ],
                    )
                },
                |(buf, scratch), y| {
                    let p = lines;
                    for x0 in (0..half).step_by(CHUNK) {
                        let w = CHUNK.min(half - x0);
                        for z in 0..dims[2] {
                            for b in 0..w {
                                buf[b * pz + z] = src[x0 + b + half * (y + py * z)];
                            }
                        }
                        for b in 0..w {
                            buf[b * pz + dims[2]..(b + 1) * pz].fill(Complex32::default());
                        }
                        fwd.process_with_scratch(&mut buf[..w * pz], scratch);
                        for kz in 0..pz {
                            for b in 0..w {
                                buf[b * pz + kz] *= kernel[x0 + b + half * (y + py * kz)];
                            }
                        }
                        inv.process_with_scratch(&mut buf[..w * pz], scratch);
                        for oz in 0..nzo {
                            for b in 0..w {
                                // SAFETY: this task owns every line with this y.
                                unsafe {
                                    *p.0.add(x0 + b + half * (y + py * oz)) =
                                        buf[b * pz + oz * stride]
                                };
                            }
                        }
                    }
                },
            );
        }
        // y: inverse on the kept planes.
        self.y_pass(&mut t, &|_| true, 1);
        // x: complex to real on the sampled rows, then the division.
        let norm = 1.0 / (px as f64 * py as f64 * pz as f64);
        let mut out = vec![0f32; out_dims.iter().product()];
        let c2r = &self.c2r;
        out.par_chunks_mut(out_dims[0] * out_dims[1])
            .enumerate()
            .for_each_init(
                || {
                    (
                        vec![Complex32::default(); half],
                        vec![0f32; px],
                        c2r.make_scratch_vec(),
                    )
                },
                |(spec, row, scratch), (oz, plane)| {
                    let z = oz * stride;
                    for oy in 0..out_dims[1] {
                        let y = oy * stride;
                        let start = half * (y + py * oz);
                        spec.copy_from_slice(&t[start..start + half]);
                        // The DC (and, for even Px, Nyquist) terms of a real row are real;
                        // round-off gives them a tiny imaginary part, which c2r must not see.
                        spec[0].im = 0.0;
                        if px % 2 == 0 {
                            spec[half - 1].im = 0.0;
                        }
                        let _ = c2r.process_with_scratch(spec, row, scratch);
                        for ox in 0..out_dims[0] {
                            let x = ox * stride;
                            let num = row[x] as f64 * norm;
                            let d = den.at(x, y, z) as f64;
                            plane[ox + out_dims[0] * oy] =
                                (num / d.max(1e-30)).clamp(0.0, 1.0) as f32;
                        }
                    }
                },
            );
        out
    }
}
