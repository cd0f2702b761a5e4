#version 460
// FFT method, last pass: the inverse complex-to-real transform along x of two sampled rows at
// once (X1 + i X2, each extended by Hermitian symmetry), then O = numerator / denominator at the
// sampled voxels. The denominator is exact: a table over per-axis boundary classes
// (passes/occlusion_fft/mod.rs).
#include "occlusion.glsl"

layout(local_size_x = FFT_LOCAL, local_size_y = 1, local_size_z = 1) in;

layout(set = 0, binding = 0, rg32f) uniform readonly image3D result;
layout(set = 0, binding = 1, r32f) uniform writeonly image3D occlusion;
// Class of each x, then of each y, then of each z, then the table (float bits).
layout(set = 0, binding = 3) readonly buffer Denominator { uint den[]; };

layout(push_constant) uniform Push { FftPush pc; };

#define FFT_TWIDDLE_BINDING 2
#include "fft.glsl"

vec2 half_spectrum(int k, int y, int oz) {
    int n = pc.n;
    bool mirrored = k > n / 2;
    vec2 v = imageLoad(result, ivec3(mirrored ? n - k : k, y, oz)).xy;
    // The DC and Nyquist terms of a real row are real; drop their round-off.
    if (k == 0 || 2 * k == n) v.y = 0.0;
    return mirrored ? vec2(v.x, -v.y) : v;
}

void main() {
    int t = int(gl_LocalInvocationID.x);
    int oy0 = int(gl_WorkGroupID.x) * 2;
    int oz = int(gl_WorkGroupID.y);
    bool second = oy0 + 1 < pc.out_dims.y;
    int y0 = oy0 * pc.stride, y1 = (oy0 + 1) * pc.stride;
    int n = pc.n;
    for (int k = t; k < n; k += FFT_LOCAL) {
        vec2 a = half_spectrum(k, y0, oz);
        vec2 b = second ? half_spectrum(k, y1, oz) : vec2(0.0);
        line[k] = vec2(a.x - b.y, a.y + b.x);   // a + i b
    }
    fft_shared(n, 1.0);
    int z = oz * pc.stride;
    int base_y = pc.dims.x, base_z = pc.dims.x + pc.dims.y;
    int table = pc.dims.x + pc.dims.y + pc.dims.z;
    uint cz = den[base_z + z];
    for (int ox = t; ox < pc.out_dims.x; ox += FFT_LOCAL) {
        int x = ox * pc.stride;
        vec2 v = line[x] * pc.norm;
        uint cx = den[x];
        for (int row = 0; row < 2; ++row) {
            if (row == 1 && !second) break;
            int y = row == 0 ? y0 : y1;
            uint cy = den[base_y + y];
            float d = uintBitsToFloat(den[table + cx + pc.classes.x * (cy + pc.classes.y * cz)]);
            float num = row == 0 ? v.x : v.y;
            imageStore(occlusion, ivec3(ox, oy0 + row, oz), vec4(clamp(num / max(d, 1e-30), 0.0, 1.0)));
        }
    }
}
