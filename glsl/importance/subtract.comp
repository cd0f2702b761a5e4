#version 460
// The last step of the importance map (SPEC IM1, eq. 1): delta_d = blurred - original, written over
// the blurred image. Texels hold four voxels along x, as in gauss1d.comp.
#include "importance.glsl"

layout(local_size_x = IMPORTANCE_LOCAL_X, local_size_y = IMPORTANCE_LOCAL_Y, local_size_z = IMPORTANCE_LOCAL_Z) in;

layout(set = 0, binding = 0, rgba32f) uniform readonly image3D original;
layout(set = 0, binding = 1, rgba32f) uniform image3D blurred;

layout(push_constant) uniform Push { SubtractPush pc; };

void main() {
    ivec3 p = ivec3(gl_GlobalInvocationID);
    if (any(greaterThanEqual(p, ivec3((pc.dims.x + 3) / 4, pc.dims.yz)))) {
        return;
    }
    imageStore(blurred, p, imageLoad(blurred, p) - imageLoad(original, p));
}
