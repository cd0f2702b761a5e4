#version 460
// Saturation variation (imaging::stylise::saturate): colour towards its luminance by params.x,
// luminance and alpha kept.
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
    vec4 c = imageLoad(src, p);
    float y = dot(c.rgb, LUMA);
    imageStore(dst, p, vec4(max(vec3(y) + pc.params.x * (c.rgb - vec3(y)), vec3(0.0)), c.a));
}
