#version 460
// One 1D Gaussian pass of the importance map (SPEC IM1): dst = src convolved along `axis` with the
// normalised kernel w[0..2R], borders clamped. The axis is a push constant, so one shader serves x,
// y and z; R and the segment lengths are specialisation constants, so every loop has a fixed count.
//
// Layout: each RGBA32F texel holds four neighbouring voxels along x (rows padded to a multiple of
// four with the edge voxel). Every access then moves four voxels.
//
// Each invocation filters one segment of a line. It loads the segment plus its halo once into a
// private array and afterwards indexes that array only with indices that are the same in every
// invocation. On SIMD CPUs (lavapipe) that indexing is a plain vector load while every image access
// is a per-lane gather, so gathers per output drop from 2R+1 to about one. On GPUs the array stays in
// registers.
#include "importance.glsl"

layout(constant_id = 0) const int RADIUS = 1;
// Outputs per invocation along y or z (texels, i.e. 4 voxels each, in vec4 arithmetic).
layout(constant_id = 1) const int SEGMENT = 32;
// Texels per invocation along x (4 voxels each).
layout(constant_id = 2) const int SEGMENT_X = 8;

const int HALO_X = (RADIUS + 3) / 4;            // texels of halo on each side for the x pass
const int FLOATS_X = 4 * (SEGMENT_X + 2 * HALO_X);
const int SKIP_X = 4 * HALO_X - RADIUS;         // first float of the first tap window

layout(local_size_x = GAUSS_LOCAL_X, local_size_y = 1, local_size_z = 1) in;

layout(set = 0, binding = 0, rgba32f) uniform readonly image3D src;
layout(set = 0, binding = 1, rgba32f) uniform writeonly image3D dst;
layout(set = 0, binding = 2) readonly buffer Weights { float w[]; };

layout(push_constant) uniform Push { GaussPush pc; };

float weights[2 * RADIUS + 1];

// Along y or z: lanes run along x texels (flattened with the other orthogonal axis, so narrow
// volumes keep every lane busy), each filtering SEGMENT texels of its column in vec4.
void filter_yz(int a) {
    int texels_x = (pc.dims.x + 3) / 4;
    int other = a == 1 ? 2 : 1;
    int lane = int(gl_GlobalInvocationID.x);
    if (lane >= texels_x * pc.dims[other]) {
        return;
    }
    ivec3 p = ivec3(lane % texels_x, 0, 0);
    p[other] = lane / texels_x;
    int n = pc.dims[a];
    int s0 = int(gl_GlobalInvocationID.y) * SEGMENT;
    vec4 vals[SEGMENT + 2 * RADIUS];
    for (int j = 0; j < SEGMENT + 2 * RADIUS; ++j) {
        ivec3 q = p;
        q[a] = clamp(s0 - RADIUS + j, 0, n - 1);
        vals[j] = imageLoad(src, q);
    }
    for (int i = 0; i < SEGMENT; ++i) {
        if (s0 + i >= n) {
            break;
        }
        vec4 acc = vec4(0.0);
        for (int k = 0; k <= 2 * RADIUS; ++k) {
            acc += weights[k] * vals[i + k];
        }
        ivec3 q = p;
        q[a] = s0 + i;
        imageStore(dst, q, acc);
    }
}

// Along x: lanes run along the segments of a row (flattened with y), so neighbouring lanes read
// neighbouring memory. Borders need no branch: rows are padded with their edge voxel, so a texel
// left of the row repeats voxel 0 (.x of texel 0) and one right of it repeats the last voxel (.w of
// the last texel).
void filter_x() {
    int nx = pc.dims.x;
    int texels_x = (nx + 3) / 4;
    int segments = (texels_x + SEGMENT_X - 1) / SEGMENT_X;
    int lane = int(gl_GlobalInvocationID.x);
    if (lane >= segments * pc.dims.y) {
        return;
    }
    int y = lane / segments;
    int z = int(gl_GlobalInvocationID.y);
    int t0 = (lane % segments) * SEGMENT_X;
    float f[FLOATS_X];
    for (int j = 0; j < SEGMENT_X + 2 * HALO_X; ++j) {
        int t = t0 - HALO_X + j;
        vec4 v = imageLoad(src, ivec3(clamp(t, 0, texels_x - 1), y, z));
        v = t < 0 ? v.xxxx : (t >= texels_x ? v.wwww : v);
        f[4 * j] = v.x;
        f[4 * j + 1] = v.y;
        f[4 * j + 2] = v.z;
        f[4 * j + 3] = v.w;
    }
    for (int j = 0; j < SEGMENT_X; ++j) {
        if (t0 + j >= texels_x) {
            break;
        }
        vec4 acc = vec4(0.0);
        for (int k = 0; k <= 2 * RADIUS; ++k) {
            int m = SKIP_X + 4 * j + k;
            acc += weights[k] * vec4(f[m], f[m + 1], f[m + 2], f[m + 3]);
        }
        imageStore(dst, ivec3(t0 + j, y, z), acc);
    }
}

void main() {
    for (int k = 0; k <= 2 * RADIUS; ++k) {
        weights[k] = w[k];
    }
    if (pc.axis == 0) {
        filter_x();
    } else {
        filter_yz(pc.axis);
    }
}
