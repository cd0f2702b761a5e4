#version 460
// The first pass of the line extraction: the cells whose corners straddle τ, compacted into a
// list through an atomic counter. The list's header is the indirect dispatch of extract.comp (64
// cells per workgroup, at most MAX_GROUPS workgroups: extract.comp strides over the rest). Only
// 8 texel fetches per cell here; the heavy per-vertex work then runs on dense workgroups of
// surface cells instead of on every cell of the volume, most of which are far from the surface
// and would leave SIMD lanes idle beside the few that are not.
#include "lines.glsl"

layout(local_size_x = 4, local_size_y = 4, local_size_z = 4) in;

layout(set = 0, binding = 0) uniform sampler3D volume;

layout(set = 0, binding = 1) buffer Cells {
    uint groups;
    uint one_y;
    uint one_z;
    uint count;
    uint cells[];
};

layout(push_constant) uniform Push { LinesPush pc; };

float at(ivec3 q) {
    return texelFetch(volume, clamp(q, ivec3(0), pc.dims - 1), 0).r;
}

void main() {
    ivec3 c = ivec3(gl_GlobalInvocationID) * pc.stride;
    if (any(greaterThanEqual(c, pc.dims - 1))) {
        return;
    }
    int inside = 0;
    for (int i = 0; i < 8; ++i) {
        inside += at(c + ivec3(i & 1, (i >> 1) & 1, (i >> 2) & 1)) >= pc.iso ? 1 : 0;
    }
    if (inside == 0 || inside == 8) {
        return;
    }
    uint i = atomicAdd(count, 1u);
    if (i < pc.cell_capacity) {
        if (i % 64u == 0u && i / 64u < LINES_MAX_GROUPS) {
            atomicAdd(groups, 1u);
        }
        cells[i] = uint(c.x) + uint(pc.dims.x) * (uint(c.y) + uint(pc.dims.y) * uint(c.z));
    }
}
