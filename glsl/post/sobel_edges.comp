#version 460
// Sobel edges: 1 where the normalised magnitude reaches the threshold (params.x), else 0.
#include "post.glsl"
layout(local_size_x = POST_LOCAL, local_size_y = POST_LOCAL) in;
layout(set = 0, binding = 0, rgba32f) uniform readonly image2D grad;
layout(set = 0, binding = 1, r32f) uniform writeonly image2D edges;
layout(push_constant) uniform Push { PostPush pc; };
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (outside(p, pc)) {
        return;
    }
    imageStore(edges, p, vec4(imageLoad(grad, p).z >= pc.params.x ? 1.0 : 0.0));
}
