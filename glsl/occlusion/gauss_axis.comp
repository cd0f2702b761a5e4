#version 460
// The Gaussian-weighted neighbourhood of SPEC OS2 as a normalised convolution: three separable
// passes over the pair (M, 1) with weights exp(-d^2 / 2 sigma^2), sigma = R/3, taps -R..R. Taps
// outside the volume are left out, so O = (G * M) / (G * 1) weights only voxels of the volume.
// Pass `axis` reads `src` (r = weighted M, g = weight), writes `dst`.
#include "occlusion.glsl"

layout(local_size_x = OCCLUSION_LOCAL_X, local_size_y = OCCLUSION_LOCAL_Y, local_size_z = OCCLUSION_LOCAL_Z) in;

layout(set = 0, binding = 0, r32f) uniform readonly image3D mapped;          // M, read by axis 0
layout(set = 0, binding = 1, rgba32f) uniform readonly image3D src;          // axes 1, 2
layout(set = 0, binding = 2, rgba32f) uniform writeonly image3D dst;

layout(push_constant) uniform Push { OcclusionPush pc; };

void main() {
    ivec3 p = ivec3(gl_GlobalInvocationID);
    if (any(greaterThanEqual(p, pc.dims))) {
        return;
    }
    int a = pc.axis;
    float sigma = max(float(pc.radius) / 3.0, 1e-3);
    vec2 acc = vec2(0.0);
    for (int k = -pc.radius; k <= pc.radius; ++k) {
        ivec3 q = p;
        q[a] += k;
        if (q[a] < 0 || q[a] >= pc.dims[a]) continue;
        float w = exp(-float(k * k) / (2.0 * sigma * sigma));
        vec2 v = a == 0 ? vec2(imageLoad(mapped, q).r, 1.0) : imageLoad(src, q).rg;
        acc += w * v;
    }
    imageStore(dst, p, vec4(acc, 0.0, 0.0));
}
