#version 460
// One axis of a Gaussian blur (σ = params.x pixels, taps −r..r with r = ⌈3σ⌉, normalised weights,
// clamped borders), as imaging::blur.
#include "post.glsl"
layout(local_size_x = POST_LOCAL, local_size_y = POST_LOCAL) in;
layout(set = 0, binding = 0, r32f) uniform readonly image2D src;
layout(set = 0, binding = 1, r32f) uniform writeonly image2D dst;
layout(push_constant) uniform Push { PostPush pc; };
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (outside(p, pc)) {
        return;
    }
    float sigma = pc.params.x;
    int r = max(int(ceil(3.0 * sigma)), 1);
    ivec2 step = pc.size_mode.z == 0 ? ivec2(1, 0) : ivec2(0, 1);
    float sum = 0.0;
    for (int i = -r; i <= r; ++i) {
        sum += exp(-float(i * i) / (2.0 * sigma * sigma));
    }
    float acc = 0.0;
    for (int i = -r; i <= r; ++i) {
        float w = exp(-float(i * i) / (2.0 * sigma * sigma)) / sum;
        acc += w * imageLoad(src, clamp_to(p + i * step, pc)).r;
    }
    imageStore(dst, p, vec4(acc));
}
