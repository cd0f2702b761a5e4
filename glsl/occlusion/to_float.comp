#version 460
// The renderer's normalised intensity (R16_UNORM, sampled) as the R32F storage image the occlusion
// passes read, so that a scene's occlusion volume is computed from the texture already on the GPU.
#include "occlusion.glsl"

layout(local_size_x = OCCLUSION_LOCAL_X, local_size_y = OCCLUSION_LOCAL_Y, local_size_z = OCCLUSION_LOCAL_Z) in;

layout(set = 0, binding = 0) uniform sampler3D normalised;
layout(set = 0, binding = 1, r32f) uniform writeonly image3D intensity;

layout(push_constant) uniform Push { OcclusionPush pc; };

void main() {
    ivec3 p = ivec3(gl_GlobalInvocationID);
    if (any(greaterThanEqual(p, pc.dims))) {
        return;
    }
    imageStore(intensity, p, vec4(texelFetch(normalised, p, 0).r));
}
