#version 460
// OS3: the occlusion spectrum, the 2D histogram of (intensity, occlusion), both in [0, 1], with
// one atomic increment per voxel.
#include "occlusion.glsl"

layout(local_size_x = OCCLUSION_LOCAL_X, local_size_y = OCCLUSION_LOCAL_Y, local_size_z = OCCLUSION_LOCAL_Z) in;

layout(set = 0, binding = 0, r32f) uniform readonly image3D intensity;
layout(set = 0, binding = 1, r32f) uniform readonly image3D occlusion;
layout(set = 0, binding = 2) buffer Histogram { uint counts[]; };

layout(push_constant) uniform Push { SpectrumPush pc; };

void main() {
    ivec3 p = ivec3(gl_GlobalInvocationID);
    if (any(greaterThanEqual(p, pc.dims))) {
        return;
    }
    float s = imageLoad(intensity, p).r;
    float o = imageLoad(occlusion, p / pc.stride).r;
    int bx = clamp(int(s * float(pc.bins_x)), 0, pc.bins_x - 1);
    int by = clamp(int(o * float(pc.bins_y)), 0, pc.bins_y - 1);
    atomicAdd(counts[by * pc.bins_x + bx], 1u);
}
