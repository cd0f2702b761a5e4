#version 460
// Pass 1 of ball occlusion: M = visibility(intensity) and its running sum along x,
// P(x, y, z) = sum of M(0..x, y, z). One invocation per (y, z) row.
#include "occlusion.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(set = 0, binding = 0, r32f) uniform readonly image3D intensity;
layout(set = 0, binding = 1, r32f) uniform writeonly image3D prefix;
layout(set = 0, binding = 2, r32f) uniform writeonly image3D mapped;   // M itself (for the Gaussian path)

layout(push_constant) uniform Push { OcclusionPush pc; };

#include "mapping.glsl"

void main() {
    int row = int(gl_GlobalInvocationID.x);
    if (row >= pc.dims.y * pc.dims.z) {
        return;
    }
    int y = row % pc.dims.y;
    int z = row / pc.dims.y;
    float sum = 0.0;
    for (int x = 0; x < pc.dims.x; ++x) {
        float m = visibility(imageLoad(intensity, ivec3(x, y, z)).r, pc);
        sum += m;
        imageStore(prefix, ivec3(x, y, z), vec4(sum));
        imageStore(mapped, ivec3(x, y, z), vec4(m));
    }
}
