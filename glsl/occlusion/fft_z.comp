#version 460
// FFT method: the transform along z, one line (kx, y) per workgroup. Planes at or beyond
// pc.live.z are read as zero.
// - mode 0 (kernel): the forward transform's real part is the kernel spectrum (the kernel is
//   real and even, so its DFT is real).
// - mode 1 (convolve): forward, the product with the kernel spectrum, inverse; only the planes
//   the output samples (z = oz · stride) are written, to `result`. The spectrum stays intact.
#include "occlusion.glsl"

layout(local_size_x = FFT_LOCAL, local_size_y = 1, local_size_z = 1) in;

layout(set = 0, binding = 0, rg32f) uniform readonly image3D spectrum;
layout(set = 0, binding = 1, r32f) uniform image3D kernel_hat;
layout(set = 0, binding = 3, rg32f) uniform writeonly image3D result;

layout(push_constant) uniform Push { FftPush pc; };

#define FFT_TWIDDLE_BINDING 2
#include "fft.glsl"

void main() {
    int t = int(gl_LocalInvocationID.x);
    ivec2 xy = ivec2(gl_WorkGroupID.xy);
    int n = pc.n;
    for (int z = t; z < n; z += FFT_LOCAL) {
        line[z] = z < pc.live.z ? imageLoad(spectrum, ivec3(xy, z)).xy : vec2(0.0);
    }
    fft_shared(n, -1.0);
    if (pc.mode == 0) {
        for (int z = t; z < n; z += FFT_LOCAL) {
            imageStore(kernel_hat, ivec3(xy, z), vec4(line[z].x));
        }
        return;
    }
    for (int z = t; z < n; z += FFT_LOCAL) {
        line[z] *= imageLoad(kernel_hat, ivec3(xy, z)).r;
    }
    fft_shared(n, 1.0);
    for (int oz = t; oz < pc.out_dims.z; oz += FFT_LOCAL) {
        imageStore(result, ivec3(xy, oz), vec4(line[oz * pc.stride], 0.0, 0.0));
    }
}
