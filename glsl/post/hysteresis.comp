#version 460
// Canny hysteresis, one of a bounded series of passes (render::post::HYSTERESIS_PASSES). Each pass
// loads its 16×16 tile with a one-pixel halo into shared memory and spreads "strong" (2) to 8-
// connected "weak" (1) pixels until the tile stops changing; chains cross tile borders in the
// next pass. Pass i runs only if pass i − 1 changed something (changed[i] > 0) and counts its own
// changes in changed[i + 1], so the series stops doing work once it has converged, and a non-zero
// last counter says it did not.
#include "post.glsl"
layout(local_size_x = POST_LOCAL, local_size_y = POST_LOCAL) in;
layout(set = 0, binding = 0, r32f) uniform image2D classes;
layout(set = 0, binding = 1) buffer Changed { uint changed[]; };
layout(push_constant) uniform Push { PostPush pc; };

const int T = POST_LOCAL + 2;
shared float tile[T * T];
shared uint tile_changed;

void main() {
    int pass_index = pc.flags.w;
    if (changed[pass_index] == 0u) {
        return;
    }
    ivec2 origin = ivec2(gl_WorkGroupID.xy) * POST_LOCAL - 1;
    for (int i = int(gl_LocalInvocationIndex); i < T * T; i += POST_LOCAL * POST_LOCAL) {
        ivec2 q = origin + ivec2(i % T, i / T);
        bool in_image = all(greaterThanEqual(q, ivec2(0))) && !outside(q, pc);
        tile[i] = in_image ? imageLoad(classes, q).r : 0.0;
    }
    ivec2 l = ivec2(gl_LocalInvocationID.xy) + 1;
    int me = l.y * T + l.x;
    bool any_change = false;
    for (int iter = 0; iter < POST_LOCAL * POST_LOCAL; ++iter) {
        if (gl_LocalInvocationIndex == 0) {
            tile_changed = 0u;
        }
        barrier();
        if (tile[me] == 1.0) {
            bool strong = false;
            for (int dy = -1; dy <= 1; ++dy) {
                for (int dx = -1; dx <= 1; ++dx) {
                    strong = strong || tile[me + dy * T + dx] == 2.0;
                }
            }
            if (strong) {
                tile[me] = 2.0;
                tile_changed = 1u;
                any_change = true;
            }
        }
        barrier();
        bool done = tile_changed == 0u;
        barrier();
        if (done) {
            break;
        }
    }
    ivec2 p = origin + l;
    if (!outside(p, pc) && any_change) {
        imageStore(classes, p, vec4(tile[me]));
        atomicAdd(changed[pass_index + 1], 1u);
    }
}
