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
// A listed brick is 16 workgroups (x: 2 x 2 x 4 of 8 x 8 x 4); the list runs along y, then z.
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

// The voxel of this invocation: every voxel of the volume in order, or of the listed bricks.
ivec3 voxel() {
    if (!LISTED) {
        return ivec3(gl_GlobalInvocationID);
    }
    uint k = gl_WorkGroupID.y + gl_WorkGroupID.z * gl_NumWorkGroups.y;
    if (k >= uint(pc.listed)) {
        return pc.dims;
    }
    ivec3 counts = (pc.dims + BRICK - 1) / BRICK;
    int b = int(listed_bricks[k]);
    ivec3 brick = ivec3(b % counts.x, (b / counts.x) % counts.y, b / (counts.x * counts.y));
    uint sub = gl_WorkGroupID.x;
    ivec3 local = ivec3(NORMALS_LOCAL_X, NORMALS_LOCAL_Y, NORMALS_LOCAL_Z);
    ivec3 group = ivec3(sub & 1u, (sub >> 1u) & 1u, sub >> 2u) * local;
    return brick * BRICK + group + ivec3(gl_LocalInvocationID);
}

void main() {
    ivec3 p = voxel();
    if (any(greaterThanEqual(p, pc.dims))) {
        return;
    }
    vec3 g = vec3(0.0);
    for (int dz = -1; dz <= 1; ++dz) {
        for (int dy = -1; dy <= 1; ++dy) {
            for (int dx = -1; dx <= 1; ++dx) {
                ivec3 d = ivec3(dx, dy, dz);
                float v = texelFetch(volume, clamp(p + d, ivec3(0), pc.dims - 1), 0).r;
                vec3 w = vec3(2.0) - abs(vec3(d));   // smoothing weight 1 or 2 per axis
                g += v * vec3(d) * vec3(w.y * w.z, w.x * w.z, w.x * w.y);
            }
        }
    }
    g *= pc.inv_spacing.xyz / 32.0;
    imageStore(gradient, p, vec4(g, length(g)));
}
