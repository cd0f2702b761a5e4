#version 460
// The yardstick of the importance passes (bench table1): a plain copy of the source volume's
// texels into a work image, with subtract.comp's images, workgroups and access, and no
// arithmetic. A 1D filter pass reads one such volume and writes one; it cannot beat this.
#include "importance.glsl"

layout(local_size_x = IMPORTANCE_LOCAL_X, local_size_y = IMPORTANCE_LOCAL_Y, local_size_z = IMPORTANCE_LOCAL_Z) in;

layout(set = 0, binding = 0, rgba32f) uniform readonly image3D src;
layout(set = 0, binding = 1, rgba32f) uniform writeonly image3D dst;

layout(push_constant) uniform Push { SubtractPush pc; };

void main() {
    ivec3 p = ivec3(gl_GlobalInvocationID);
    if (any(greaterThanEqual(p, ivec3((pc.dims.x + 3) / 4, pc.dims.yz)))) {
        return;
    }
    imageStore(dst, p, imageLoad(src, p));
}
