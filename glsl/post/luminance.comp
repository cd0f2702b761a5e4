#version 460
// Luminance of a premultiplied layer (the focus's diffuse image), the input of every edge detector.
#include "post.glsl"
layout(local_size_x = POST_LOCAL, local_size_y = POST_LOCAL) in;
layout(set = 0, binding = 0, rgba32f) uniform readonly image2D layer;
layout(set = 0, binding = 1, r32f) uniform writeonly image2D lum;
layout(push_constant) uniform Push { PostPush pc; };
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (outside(p, pc)) {
        return;
    }
    imageStore(lum, p, vec4(dot(imageLoad(layer, p).rgb, LUMA)));
}
