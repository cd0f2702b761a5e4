#version 460
// TL1: per-voxel gradient of the normalised volume with the 3D Sobel operator, computed once and
// stored as a 3D texture: xyz = gradient in world units (per unit of spacing), w = its length.
// The derivative along an axis is the central difference (-1, 0, 1) smoothed by (1, 2, 1) along
// the other two axes, divided by 32 so that a unit ramp has a unit gradient. Borders clamp.
// Where at least an eighth of the bricks (16^3 voxels) are of one value, it runs only on the
// others: those whose region widened by one voxel holds more than one value, listed by the host
// from the bricks' ranges it computes anyway (passes/normals.rs); every voxel of another brick has
// a zero gradient, which a clear of the image wrote. Else it runs on every voxel in order. A volume of
// sparse structure (a cell in its dish, segmented data, a phantom) is mostly such bricks, and a
// CPU device, which runs masked lanes too, only saves their work when they are never dispatched.
// A listed brick is 4 workgroups (x: 2 x 2 of 8 x 8 columns); the list runs along y, then z.
// Each invocation computes a column of NORMALS_COLUMN voxels along z and reads each slice's 3 x 3
// neighbourhood once: per slice, three sums over that plane (the x and y derivatives smoothed in
// the plane, and the plane smoothed), which three neighbouring slices combine. That is 9 fetches
// per voxel, not the stencil's 27; the sums, and so the gradients, are the same.
#include "render.glsl"

layout(local_size_x = NORMALS_LOCAL_X, local_size_y = NORMALS_LOCAL_Y, local_size_z = NORMALS_LOCAL_Z) in;

layout(set = 0, binding = 0) uniform sampler3D volume;
layout(set = 0, binding = 1, rgba16f) uniform writeonly image3D gradient;
layout(set = 0, binding = 2) readonly buffer Listed { uint listed_bricks[]; };
const int BRICK = 16;

layout(push_constant) uniform Push { NormalsPush pc; };
// Which pipeline: over the listed bricks, or over every voxel in order. A specialisation constant,
// not a test of `listed` alone: a CPU device runs both sides of a branch on a uniform.
layout(constant_id = 0) const bool LISTED = false;

// The first voxel of this invocation's column: every column of the volume in order, or of the
// listed bricks.
ivec3 column_start() {
    if (!LISTED) {
        return ivec3(gl_GlobalInvocationID.xy, gl_GlobalInvocationID.z * NORMALS_COLUMN);
    }
    uint k = gl_WorkGroupID.y + gl_WorkGroupID.z * gl_NumWorkGroups.y;
    if (k >= uint(pc.listed)) {
        return pc.dims;
    }
    ivec3 counts = (pc.dims + BRICK - 1) / BRICK;
    int b = int(listed_bricks[k]);
    ivec3 brick = ivec3(b % counts.x, (b / counts.x) % counts.y, b / (counts.x * counts.y));
    uint sub = gl_WorkGroupID.x;
    ivec2 group = ivec2(sub & 1u, sub >> 1u) * ivec2(NORMALS_LOCAL_X, NORMALS_LOCAL_Y);
    return brick * BRICK + ivec3(group + ivec2(gl_LocalInvocationID.xy), 0);
}

// Over slice z (clamped) around column xy: x, the x difference smoothed (1, 2, 1) along y; y, the
// y difference smoothed along x; z, the plane smoothed along both.
vec3 plane_sums(ivec2 xy, int z) {
    int zc = clamp(z, 0, pc.dims.z - 1);
    vec3 s = vec3(0.0);
    for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
            ivec2 q = clamp(xy + ivec2(dx, dy), ivec2(0), pc.dims.xy - 1);
            float v = texelFetch(volume, ivec3(q, zc), 0).r;
            float wx = 2.0 - abs(float(dx));
            float wy = 2.0 - abs(float(dy));
            s += v * vec3(float(dx) * wy, float(dy) * wx, wx * wy);
        }
    }
    return s;
}

void main() {
    ivec3 p = column_start();
    if (any(greaterThanEqual(p, pc.dims))) {
        return;
    }
    int n = min(NORMALS_COLUMN, pc.dims.z - p.z);
    vec3 below = plane_sums(p.xy, p.z - 1);
    vec3 here = plane_sums(p.xy, p.z);
    vec3 scale = pc.inv_spacing.xyz / 32.0;
    for (int k = 0; k < n; ++k) {
        vec3 above = plane_sums(p.xy, p.z + k + 1);
        vec3 g = vec3(below.xy + 2.0 * here.xy + above.xy, above.z - below.z) * scale;
        imageStore(gradient, ivec3(p.xy, p.z + k), vec4(g, length(g)));
        below = here;
        here = above;
    }
}
