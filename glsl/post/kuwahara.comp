#version 460
// Classic four-quadrant Kuwahara filter of radius r = size_mode.w on a premultiplied layer
// (imaging::stylise::kuwahara): the mean of the quadrant with the smallest luminance variance.
#include "post.glsl"
layout(local_size_x = POST_LOCAL, local_size_y = POST_LOCAL) in;
layout(set = 0, binding = 0, rgba32f) uniform readonly image2D src;
layout(set = 0, binding = 1, rgba32f) uniform writeonly image2D dst;
layout(push_constant) uniform Push { PostPush pc; };
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (outside(p, pc)) {
        return;
    }
    int r = pc.size_mode.w;
    float n = float((r + 1) * (r + 1));
    float best_var = 1.0 / 0.0;
    vec4 best = vec4(0.0);
    ivec2 corners[4] = ivec2[4](ivec2(-r, -r), ivec2(0, -r), ivec2(-r, 0), ivec2(0, 0));
    for (int q = 0; q < 4; ++q) {
        vec4 sum = vec4(0.0);
        float l1 = 0.0, l2 = 0.0;
        for (int dy = 0; dy <= r; ++dy) {
            for (int dx = 0; dx <= r; ++dx) {
                vec4 c = imageLoad(src, clamp_to(p + corners[q] + ivec2(dx, dy), pc));
                sum += c;
                float l = dot(c.rgb, LUMA);
                l1 += l;
                l2 += l * l;
            }
        }
        float mean_l = l1 / n;
        float var = l2 / n - mean_l * mean_l;
        if (var < best_var) {
            best_var = var;
            best = sum / n;
        }
    }
    imageStore(dst, p, best);
}
