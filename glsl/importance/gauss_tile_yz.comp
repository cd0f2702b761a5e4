#version 460
// The importance map's Gaussian along y or z (SPEC IM1) for GPUs: the same result as
// gauss1d.comp's y and z passes, with workgroup tiles staged through shared memory.
//
// A workgroup covers TX texels along x, DEPTH lines across (z for the y pass, y for the z pass)
// and LENGTH outputs along the axis. It loads the LENGTH + 2R texels of each of its TX × DEPTH
// lines once, a warp's lanes on neighbouring texels of a row (and on the next lines or rows where
// a row is narrower than a warp), then each of its LANES lanes along the axis filters
// LENGTH / LANES consecutive outputs of its line from a window of registers. Consecutive
// workgroups walk along the axis (the grid's x), so the halo the next tile re-reads is still in
// the cache.
#include "importance.glsl"

layout(constant_id = 0) const int RADIUS = 1;
layout(constant_id = 1) const int TX = 32;
layout(constant_id = 2) const int DEPTH = 1;
layout(constant_id = 3) const int LANES = 8;
layout(constant_id = 4) const int LENGTH = 64;

const int PER_LANE = LENGTH / LANES;
const int ROWS = LENGTH + 2 * RADIUS;

layout(local_size_x_id = 1, local_size_y_id = 2, local_size_z_id = 3) in;

layout(set = 0, binding = 0, rgba32f) uniform readonly image3D src;
layout(set = 0, binding = 1, rgba32f) uniform writeonly image3D dst;
layout(set = 0, binding = 2) readonly buffer Weights { float w[]; };

layout(push_constant) uniform Push { GaussPush pc; };

shared vec4 tile[ROWS * DEPTH * TX];

void main() {
    int a = pc.axis;
    int other = a == 1 ? 2 : 1;
    int texels_x = (pc.dims.x + 3) / 4;
    int n = pc.dims[a];
    ivec3 l = ivec3(gl_LocalInvocationID);
    ivec3 p = ivec3(int(gl_WorkGroupID.y) * TX + l.x, 0, 0);
    p[other] = int(gl_WorkGroupID.z) * DEPTH + l.y;
    int a0 = int(gl_WorkGroupID.x) * LENGTH;
    bool inside = p.x < texels_x && p[other] < pc.dims[other];
    int lane = l.y * TX + l.x;
    // Borders are clamped: rows before the first and after the last repeat them.
    for (int r = l.z; r < ROWS; r += LANES) {
        ivec3 q = p;
        q[a] = clamp(a0 - RADIUS + r, 0, n - 1);
        tile[r * DEPTH * TX + lane] = inside ? imageLoad(src, q) : vec4(0.0);
    }
    barrier();
    if (!inside) {
        return;
    }
    int o0 = l.z * PER_LANE;
    vec4 window[PER_LANE + 2 * RADIUS];
    for (int j = 0; j < PER_LANE + 2 * RADIUS; ++j) {
        window[j] = tile[(o0 + j) * DEPTH * TX + lane];
    }
    for (int i = 0; i < PER_LANE; ++i) {
        if (a0 + o0 + i >= n) {
            break;
        }
        vec4 acc = vec4(0.0);
        for (int k = 0; k <= 2 * RADIUS; ++k) {
            acc += w[k] * window[i + k];
        }
        ivec3 q = p;
        q[a] = a0 + o0 + i;
        imageStore(dst, q, acc);
    }
}
