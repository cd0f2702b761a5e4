#version 460
// Last step of the Gaussian neighbourhood: O = (G * M) / (G * 1), sampled at the output stride.
#include "occlusion.glsl"

layout(local_size_x = OCCLUSION_LOCAL_X, local_size_y = OCCLUSION_LOCAL_Y, local_size_z = OCCLUSION_LOCAL_Z) in;

layout(set = 0, binding = 0, rgba32f) uniform readonly image3D weighted;
layout(set = 0, binding = 1, r32f) uniform writeonly image3D occlusion;

layout(push_constant) uniform Push { OcclusionPush pc; };

void main() {
    ivec3 o = ivec3(gl_GlobalInvocationID);
    if (any(greaterThanEqual(o, pc.out_dims))) {
        return;
    }
    vec2 v = imageLoad(weighted, min(o * pc.stride, pc.dims - 1)).rg;
    imageStore(occlusion, o, vec4(v.x / max(v.y, 1e-30)));
}
