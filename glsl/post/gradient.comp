#version 460
// Sobel gradient of a plane: (gx, gy, magnitude / 4√2, 0), x right and y down, as imaging::edges.
#include "post.glsl"
layout(local_size_x = POST_LOCAL, local_size_y = POST_LOCAL) in;
layout(set = 0, binding = 0, r32f) uniform readonly image2D src;
layout(set = 0, binding = 1, rgba32f) uniform writeonly image2D grad;
layout(push_constant) uniform Push { PostPush pc; };
float v(ivec2 p, int dx, int dy) {
    return imageLoad(src, clamp_to(p + ivec2(dx, dy), pc)).r;
}
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (outside(p, pc)) {
        return;
    }
    float gx = (v(p, 1, -1) + 2.0 * v(p, 1, 0) + v(p, 1, 1)) - (v(p, -1, -1) + 2.0 * v(p, -1, 0) + v(p, -1, 1));
    float gy = (v(p, -1, 1) + 2.0 * v(p, 0, 1) + v(p, 1, 1)) - (v(p, -1, -1) + 2.0 * v(p, 0, -1) + v(p, 1, -1));
    imageStore(grad, p, vec4(gx, gy, sqrt(gx * gx + gy * gy) / 5.6568542, 0.0));
}
