#version 460
// FFT method: a complex transform along y, in place, one line (kx, z) per workgroup. Rows at or
// beyond pc.live.y are read as zero (the forward x pass never wrote them).
#include "occlusion.glsl"

layout(local_size_x = FFT_LOCAL, local_size_y = 1, local_size_z = 1) in;

layout(set = 0, binding = 0, rg32f) uniform image3D data;

layout(push_constant) uniform Push { FftPush pc; };

#define FFT_TWIDDLE_BINDING 1
#include "fft.glsl"

void main() {
    int t = int(gl_LocalInvocationID.x);
    ivec2 xz = ivec2(gl_WorkGroupID.xy);
    int n = pc.n;
    for (int y = t; y < n; y += FFT_LOCAL) {
        line[y] = y < pc.live.y ? imageLoad(data, ivec3(xz.x, y, xz.y)).xy : vec2(0.0);
    }
    fft_shared(n, pc.dir);
    for (int y = t; y < n; y += FFT_LOCAL) {
        imageStore(data, ivec3(xz.x, y, xz.y), vec4(line[y], 0.0, 0.0));
    }
}
