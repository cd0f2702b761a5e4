#version 460
// The Hessian of the line extraction's volume, once per voxel (`LineExtractor::record_hessian`):
// the same differences extract.comp takes at every cell corner, stored for extract_hessian.comp.
#include "lines.glsl"

layout(local_size_x = 4, local_size_y = 4, local_size_z = 4) in;

layout(set = 0, binding = 0) uniform sampler3D volume;
layout(set = 0, binding = 1, rgba32f) uniform writeonly image3D hessian_a;
layout(set = 0, binding = 2, rgba32f) uniform writeonly image3D hessian_b;

layout(push_constant) uniform Push { LinesPush pc; };

void main() {
    ivec3 q = ivec3(gl_GlobalInvocationID);
    if (any(greaterThanEqual(q, pc.dims))) {
        return;
    }
    vec4 h0;
    vec2 h1;
    hessian_at(volume, pc.dims, pc.spacing, q, h0, h1);
    imageStore(hessian_a, q, h0);
    imageStore(hessian_b, q, vec4(h1, 0.0, 0.0));
}
