#version 460
// Pass 2 of ball occlusion (SPEC OS1): O(x) = mean of M over the voxels x' of the volume with
// |x' - x| <= R. The ball is a stack of x-runs, one per (dy, dz) in the disk of radius R; each run
// is a difference of the prefix sums P. That makes the cost per voxel O(R^2) rather than the
// O(R^3) of brute force. Voxels outside the volume are left out of both the sum and the count.
#include "occlusion.glsl"

// One row of outputs per workgroup: y and z, and so every branch of the run loop, are uniform.
layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

layout(set = 0, binding = 0, r32f) uniform readonly image3D prefix;
layout(set = 0, binding = 1, r32f) uniform writeonly image3D occlusion;

layout(push_constant) uniform Push { OcclusionPush pc; };

// floor(sqrt(n)) for n >= 0, exact for integers.
int isqrt(int n) {
    int r = int(sqrt(float(n)));
    while (r * r > n) --r;
    while ((r + 1) * (r + 1) <= n) ++r;
    return r;
}

void main() {
    ivec3 o = ivec3(gl_GlobalInvocationID);
    if (any(greaterThanEqual(o, pc.out_dims))) {
        return;
    }
    ivec3 p = min(o * pc.stride, pc.dims - 1);
    int R = pc.radius;
    float sum = 0.0;
    int count = 0;
    for (int dz = -R; dz <= R; ++dz) {
        int z = p.z + dz;
        if (z < 0 || z >= pc.dims.z) continue;
        for (int dy = -R; dy <= R; ++dy) {
            int y = p.y + dy;
            int r2 = R * R - dy * dy - dz * dz;
            if (y < 0 || y >= pc.dims.y || r2 < 0) continue;
            int w = isqrt(r2);
            int lo = max(p.x - w, 0);
            int hi = min(p.x + w, pc.dims.x - 1);
            float run = imageLoad(prefix, ivec3(hi, y, z)).r;
            if (lo > 0) {
                run -= imageLoad(prefix, ivec3(lo - 1, y, z)).r;
            }
            sum += run;
            count += hi - lo + 1;
        }
    }
    imageStore(occlusion, o, vec4(sum / float(max(count, 1))));
}
