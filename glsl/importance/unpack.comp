#version 460
// ΔD from the packed RGBA32F layout into an R32F volume the renderer samples with linear filtering,
// and max |ΔD| over the volume by reduction (a workgroup maximum in shared memory, then one atomic
// per workgroup), for n = |ΔD| / max |ΔD| (SPEC IM4). Non-negative floats order like their bits.
#include "importance.glsl"

layout(local_size_x = IMPORTANCE_LOCAL_X, local_size_y = IMPORTANCE_LOCAL_Y, local_size_z = IMPORTANCE_LOCAL_Z) in;

layout(set = 0, binding = 0, rgba32f) uniform readonly image3D packed;
layout(set = 0, binding = 1, r32f) uniform writeonly image3D delta_d;
layout(set = 0, binding = 2) buffer MaxAbs { uint max_abs_bits; };

layout(push_constant) uniform Push { SubtractPush pc; };

shared uint group_max;

void main() {
    if (gl_LocalInvocationIndex == 0) {
        group_max = 0u;
    }
    barrier();
    ivec3 p = ivec3(gl_GlobalInvocationID);
    if (all(lessThan(p, pc.dims))) {
        float v = imageLoad(packed, ivec3(p.x / 4, p.yz))[p.x % 4];
        imageStore(delta_d, p, vec4(v));
        atomicMax(group_max, floatBitsToUint(abs(v)));
    }
    barrier();
    if (gl_LocalInvocationIndex == 0) {
        atomicMax(max_abs_bits, group_max);
    }
}
