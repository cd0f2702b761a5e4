// Shared-memory Stockham FFT of one line, mixed radix 2, 3, 4, 5 (issue 16). Include after the
// push constants (`pc`, an FftPush) and define FFT_TWIDDLE_BINDING first.
//
// Stage s combines r sub-transforms of length ns into transforms of length ns·r (autosort, so no
// bit reversal): butterfly j reads line[j + i·n/r], multiplies input i by w^(i·k) with
// k = j mod ns and w = exp(∓2πi/(ns·r)), takes the r-point DFT and writes line[(j/ns)·ns·r + k +
// i·ns]. Each invocation keeps its butterflies' outputs in registers between the two barriers of a
// stage, so one shared array is enough (4096 points = 32 KiB, lavapipe's limit).
#ifndef VELLUM_FFT_GLSL
#define VELLUM_FFT_GLSL

#define FFT_MAX_N 4096
// Values one invocation holds in a stage: ceil(n / (r · FFT_LOCAL)) · r <= n / FFT_LOCAL + r.
#define FFT_MAXV (FFT_MAX_N / FFT_LOCAL + 8)

shared vec2 line[FFT_MAX_N];

// Forward twiddles exp(-2πi·i·k/(ns·r)) of every stage of every length, from the CPU in double
// precision: the entry of (stage with ns, k, i) is at twiddle_base + ns - 1 + k·(r - 1) + i - 1.
layout(set = 0, binding = FFT_TWIDDLE_BINDING) readonly buffer Twiddles { vec2 twiddle[]; };

vec2 cmul(vec2 a, vec2 b) {
    return vec2(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

int fft_radix(int s) {
    int word = s < 8 ? pc.radices0 : pc.radices1;
    return (word >> (4 * (s & 7))) & 15;
}

// The r-point DFT of a[0..r) in place; dir -1 forward, +1 inverse.
void fft_butterfly(inout vec2 a[5], int r, float dir) {
    if (r == 2) {
        vec2 t = a[0];
        a[0] = t + a[1];
        a[1] = t - a[1];
    } else if (r == 4) {
        vec2 t0 = a[0] + a[2], t1 = a[0] - a[2], t2 = a[1] + a[3], d = a[1] - a[3];
        vec2 t3 = vec2(-dir * d.y, dir * d.x);   // d · exp(dir·iπ/2)
        a[0] = t0 + t2;
        a[2] = t0 - t2;
        a[1] = t1 + t3;
        a[3] = t1 - t3;
    } else if (r == 3) {
        vec2 s = a[1] + a[2], d = a[1] - a[2];
        vec2 m = a[0] - 0.5 * s;
        vec2 t = (0.86602540378443865 * dir) * vec2(-d.y, d.x);
        a[0] = a[0] + s;
        a[1] = m + t;
        a[2] = m - t;
    } else if (r == 5) {
        const float c1 = 0.30901699437494742, c2 = -0.80901699437494742;
        const float s1 = 0.95105651629515357, s2 = 0.58778525229247313;
        vec2 w[5] = vec2[5](vec2(1.0, 0.0), vec2(c1, dir * s1), vec2(c2, dir * s2),
                            vec2(c2, -dir * s2), vec2(c1, -dir * s1));
        vec2 b[5];
        for (int q = 0; q < 5; ++q) {
            vec2 acc = a[0];
            for (int i = 1; i < 5; ++i) {
                acc += cmul(a[i], w[(i * q) % 5]);
            }
            b[q] = acc;
        }
        for (int q = 0; q < 5; ++q) {
            a[q] = b[q];
        }
    }
}

// Transforms line[0..n) in place (unnormalised). Every invocation of the workgroup must call it;
// it starts and ends with a barrier.
void fft_shared(int n, float dir) {
    int t = int(gl_LocalInvocationID.x);
    int ns = 1;
    barrier();
    for (int s = 0; s < pc.stages; ++s) {
        int r = fft_radix(s);
        int m = n / r;
        vec2 v[FFT_MAXV];
        int c = 0;
        for (int j = t; j < m; j += FFT_LOCAL) {
            vec2 a[5];
            int k = j % ns;
            a[0] = line[j];
            for (int i = 1; i < r; ++i) {
                vec2 w = twiddle[pc.twiddle_base + ns - 1 + k * (r - 1) + i - 1];
                // The table holds forward twiddles; the inverse takes their conjugates.
                a[i] = cmul(line[j + i * m], vec2(w.x, -dir * w.y));
            }
            fft_butterfly(a, r, dir);
            for (int i = 0; i < r; ++i) {
                v[c + i] = a[i];
            }
            c += r;
        }
        barrier();
        c = 0;
        for (int j = t; j < m; j += FFT_LOCAL) {
            int k = j % ns;
            int base = (j / ns) * ns * r + k;
            for (int i = 0; i < r; ++i) {
                line[base + i * ns] = v[c + i];
            }
            c += r;
        }
        barrier();
        ns *= r;
    }
}

#endif
