#version 460
// Difference of Gaussians with XDoG's soft threshold as an edge strength (imaging::edges::
// dog_strength): D = G_σ − τ·G_kσ; tanh(φ·(−ε − D)) where that is positive, else 0.
// params: τ, ε, φ.
#include "post.glsl"
layout(local_size_x = POST_LOCAL, local_size_y = POST_LOCAL) in;
layout(set = 0, binding = 0, r32f) uniform readonly image2D narrow;
layout(set = 0, binding = 1, r32f) uniform readonly image2D wide;
layout(set = 0, binding = 2, r32f) uniform writeonly image2D edges;
layout(push_constant) uniform Push { PostPush pc; };
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (outside(p, pc)) {
        return;
    }
    float d = imageLoad(narrow, p).r - pc.params.x * imageLoad(wide, p).r;
    float u = -pc.params.y - d;
    imageStore(edges, p, vec4(u > 0.0 ? tanh(pc.params.z * u) : 0.0));
}
