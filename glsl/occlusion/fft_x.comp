#version 460
// FFT method, pass 1: the forward real-to-complex transform along x of M (the visibility of the
// intensity) or of the wrapped kernel. Two real rows ride in one complex transform, (y, y + 1) as
// real and imaginary parts, and are separated after it. Rows at or beyond pc.live are not
// written: the later passes read them as zero.
#include "occlusion.glsl"

layout(local_size_x = FFT_LOCAL, local_size_y = 1, local_size_z = 1) in;

layout(set = 0, binding = 0, r32f) uniform readonly image3D intensity;
layout(set = 0, binding = 1, rg32f) uniform writeonly image3D spectrum;

layout(push_constant) uniform Push { FftPush pc; };

#define FFT_TWIDDLE_BINDING 2
#include "fft.glsl"
#include "mapping.glsl"

// Offset of padded coordinate c along an axis of size p, or a value beyond the reach.
int wrapped(int c, int p, int e) {
    if (c <= e) return c;
    if (c >= p - e) return c - p;
    return 1 << 20;
}

float gauss(int d) {
    float sigma = max(float(pc.radius) / 3.0, 1e-3);
    return exp(-float(d * d) / (2.0 * sigma * sigma));
}

float value(int x, int y, int z) {
    if (pc.mode == 0) {
        if (x >= pc.dims.x || y >= pc.dims.y || z >= pc.dims.z) return 0.0;
        OcclusionPush op;
        op.mapping = pc.mapping;
        op.t0 = pc.t0;
        op.t1 = pc.t1;
        return visibility(imageLoad(intensity, ivec3(x, y, z)).r, op);
    }
    ivec3 d = ivec3(wrapped(x, pc.pad.x, pc.reach.x), wrapped(y, pc.pad.y, pc.reach.y),
                    wrapped(z, pc.pad.z, pc.reach.z));
    if (any(greaterThan(abs(d), pc.reach))) return 0.0;
    if (pc.mode == 1) {
        return dot(d, d) <= pc.radius * pc.radius ? 1.0 : 0.0;
    }
    return gauss(d.x) * gauss(d.y) * gauss(d.z);
}

void main() {
    int t = int(gl_LocalInvocationID.x);
    int y0 = int(gl_WorkGroupID.x) * 2;
    int z = int(gl_WorkGroupID.y);
    int n = pc.n;
    for (int x = t; x < n; x += FFT_LOCAL) {
        float b = y0 + 1 < pc.live.y ? value(x, y0 + 1, z) : 0.0;
        line[x] = vec2(value(x, y0, z), b);
    }
    fft_shared(n, -1.0);
    // Z = X1 + i X2 with X1, X2 Hermitian: X1[k] = (Z[k] + conj Z[n-k]) / 2,
    // X2[k] = (Z[k] - conj Z[n-k]) / 2i.
    for (int k = t; k <= n / 2; k += FFT_LOCAL) {
        vec2 a = line[k];
        vec2 b = line[(n - k) % n];
        vec2 bc = vec2(b.x, -b.y);
        vec2 d = 0.5 * (a - bc);
        imageStore(spectrum, ivec3(k, y0, z), vec4(0.5 * (a + bc), 0.0, 0.0));
        if (y0 + 1 < pc.live.y) {
            imageStore(spectrum, ivec3(k, y0 + 1, z), vec4(d.y, -d.x, 0.0, 0.0));
        }
    }
}
