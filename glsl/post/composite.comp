#version 460
// The style composite (imaging::stylise::composite): edges, dilated to the line width and drawn in
// their colour and opacity, over the focus; the (abstracted) context over that. flags: dilation
// radius, edges present, edge offset (1 for Canny's classes: 2 → 1, 1 → 0).
#include "post.glsl"
layout(local_size_x = POST_LOCAL, local_size_y = POST_LOCAL) in;
layout(set = 0, binding = 0, rgba32f) uniform readonly image2D focus;
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D context;
layout(set = 0, binding = 2, r32f) uniform readonly image2D edges;
layout(set = 0, binding = 3, rgba32f) uniform writeonly image2D composite;
layout(push_constant) uniform Push { PostPush pc; };
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (outside(p, pc)) {
        return;
    }
    vec4 f = imageLoad(focus, p);
    if (pc.flags.y != 0) {
        int rho = pc.flags.x;
        float s = 0.0;
        for (int dy = -rho; dy <= rho; ++dy) {
            for (int dx = -rho; dx <= rho; ++dx) {
                s = max(s, clamp(imageLoad(edges, clamp_to(p + ivec2(dx, dy), pc)).r - float(pc.flags.z), 0.0, 1.0));
            }
        }
        float a = clamp(s * pc.edge.a, 0.0, 1.0);
        f = vec4(pc.edge.rgb * a, a) + (1.0 - a) * f;
    }
    vec4 c = imageLoad(context, p);
    imageStore(composite, p, c + (1.0 - c.a) * f);
}
