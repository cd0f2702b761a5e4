#version 460
// Canny: non-maximum suppression along the gradient (quantised to 0°, 45°, 90°, 135°) and the
// double threshold: 2 strong, 1 weak, 0 none (imaging::edges::canny_classes). params: high, low.
#include "post.glsl"
layout(local_size_x = POST_LOCAL, local_size_y = POST_LOCAL) in;
layout(set = 0, binding = 0, rgba32f) uniform readonly image2D grad;
layout(set = 0, binding = 1, r32f) uniform writeonly image2D classes;
layout(push_constant) uniform Push { PostPush pc; };
float mag(ivec2 p) {
    return imageLoad(grad, clamp_to(p, pc)).z;
}
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (outside(p, pc)) {
        return;
    }
    vec4 g = imageLoad(grad, p);
    float ax = abs(g.x), ay = abs(g.y);
    ivec2 a, b;
    if (ay <= 0.41421357 * ax) {
        a = ivec2(1, 0); b = ivec2(-1, 0);
    } else if (ay >= 2.4142136 * ax) {
        a = ivec2(0, 1); b = ivec2(0, -1);
    } else if (g.x * g.y > 0.0) {
        a = ivec2(1, 1); b = ivec2(-1, -1);
    } else {
        a = ivec2(1, -1); b = ivec2(-1, 1);
    }
    float m = g.z;
    bool keep = m > mag(p + a) && m >= mag(p + b);
    float c = keep && m >= pc.params.x ? 2.0 : (keep && m >= pc.params.y ? 1.0 : 0.0);
    imageStore(classes, p, vec4(c));
}
