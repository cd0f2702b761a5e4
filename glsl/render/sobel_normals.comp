#version 460
// TL1: per-voxel gradient of the normalised volume with the 3D Sobel operator, computed once and
// stored as a 3D texture: xyz = gradient in world units (per unit of spacing), w = its length.
// The derivative along an axis is the central difference (-1, 0, 1) smoothed by (1, 2, 1) along
// the other two axes, divided by 32 so that a unit ramp has a unit gradient. Borders clamp.
#include "render.glsl"

layout(local_size_x = NORMALS_LOCAL_X, local_size_y = NORMALS_LOCAL_Y, local_size_z = NORMALS_LOCAL_Z) in;

layout(set = 0, binding = 0) uniform sampler3D volume;
layout(set = 0, binding = 1, rgba16f) uniform writeonly image3D gradient;

layout(push_constant) uniform Push { NormalsPush pc; };

void main() {
    ivec3 p = ivec3(gl_GlobalInvocationID);
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
