#version 460
// The renderer's normalised intensity (R16_UNORM, sampled) packed four x-neighbours per RGBA32F
// texel for the Gaussian passes, rows padded with their last voxel as passes::importance::pack_rows
// does on the host. ΔD computed from it is in normalised intensity units.
#include "importance.glsl"

layout(local_size_x = IMPORTANCE_LOCAL_X, local_size_y = IMPORTANCE_LOCAL_Y, local_size_z = IMPORTANCE_LOCAL_Z) in;

layout(set = 0, binding = 0) uniform sampler3D normalised;
layout(set = 0, binding = 1, rgba32f) uniform writeonly image3D packed;

layout(push_constant) uniform Push { SubtractPush pc; };

void main() {
    ivec3 p = ivec3(gl_GlobalInvocationID);
    if (any(greaterThanEqual(p, ivec3((pc.dims.x + 3) / 4, pc.dims.yz)))) {
        return;
    }
    vec4 texel;
    for (int i = 0; i < 4; ++i) {
        int x = min(4 * p.x + i, pc.dims.x - 1);
        texel[i] = texelFetch(normalised, ivec3(x, p.yz), 0).r;
    }
    imageStore(packed, p, texel);
}
