#version 460
// The importance map's Gaussian along x (SPEC IM1) for GPUs: the same result as gauss1d.comp's
// x pass, with workgroup tiles staged through shared memory. A workgroup of TILE × 2 × 2 lanes
// (the shape of subtract.comp, which runs near the memory bandwidth) loads its TILE texels of each
// of its four rows and the halo once, one texel per lane, so a warp's loads and stores are
// contiguous; each lane then filters its own texel (four voxels) from shared memory.
#include "importance.glsl"

layout(constant_id = 0) const int RADIUS = 1;
// Texels per row of the tile (the workgroup's width).
layout(constant_id = 1) const int TILE = 64;

const int HALO = (RADIUS + 3) / 4;           // texels of halo on each side
const int WIDTH = TILE + 2 * HALO;           // texels staged per row
const int SKIP = 4 * HALO - RADIUS;          // first float of the first tap window

layout(local_size_x_id = 1, local_size_y = 2, local_size_z = 2) in;

layout(set = 0, binding = 0, rgba32f) uniform readonly image3D src;
layout(set = 0, binding = 1, rgba32f) uniform writeonly image3D dst;
layout(set = 0, binding = 2) readonly buffer Weights { float w[]; };

layout(push_constant) uniform Push { GaussPush pc; };

shared vec4 rows[4 * WIDTH];

void main() {
    int texels_x = (pc.dims.x + 3) / 4;
    ivec3 g = ivec3(gl_GlobalInvocationID);
    int row = int(gl_LocalInvocationID.y + 2 * gl_LocalInvocationID.z);
    bool inside = g.y < pc.dims.y && g.z < pc.dims.z;
    int x0 = int(gl_WorkGroupID.x) * TILE - HALO;
    // Rows are padded with their edge voxel: a texel left of the row repeats voxel 0, one right
    // of it the last voxel.
    for (int j = int(gl_LocalInvocationID.x); j < WIDTH; j += TILE) {
        int t = x0 + j;
        vec4 v = vec4(0.0);
        if (inside) {
            v = imageLoad(src, ivec3(clamp(t, 0, texels_x - 1), g.y, g.z));
            v = t < 0 ? v.xxxx : (t >= texels_x ? v.wwww : v);
        }
        rows[row * WIDTH + j] = v;
    }
    barrier();
    if (!inside || g.x >= texels_x) {
        return;
    }
    float f[4 * (2 * HALO + 1)];
    for (int j = 0; j <= 2 * HALO; ++j) {
        vec4 v = rows[row * WIDTH + int(gl_LocalInvocationID.x) + j];
        f[4 * j] = v.x;
        f[4 * j + 1] = v.y;
        f[4 * j + 2] = v.z;
        f[4 * j + 3] = v.w;
    }
    vec4 acc = vec4(0.0);
    for (int k = 0; k <= 2 * RADIUS; ++k) {
        int m = SKIP + k;
        acc += w[k] * vec4(f[m], f[m + 1], f[m + 2], f[m + 3]);
    }
    imageStore(dst, g, acc);
}
