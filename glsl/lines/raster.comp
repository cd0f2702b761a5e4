#version 460
// Draws the extracted segments into the style's edge image, one segment per invocation,
// depth-tested against the focus level's linear depth (the two-level paper's trick: pass 1's
// depth replaces a visibility computation). A pixel of the segment is drawn where its depth is at
// most the focus depth plus a bias; where there is no focus (+inf) it is always drawn.
#include "lines.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

struct Segment {
    vec4 a;
    vec4 b;
};

layout(set = 0, binding = 0) readonly buffer Lines {
    uint groups;
    uint one_y;
    uint one_z;
    uint count;
    Segment segs[];
};
layout(set = 0, binding = 1, r32f) uniform readonly image2D focus_depth;
layout(set = 0, binding = 2, r32f) uniform image2D edges;

layout(push_constant) uniform Push { RasterPush pc; };

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= min(count, pc.capacity_size.x)) {
        return;
    }
    ivec2 size = ivec2(pc.capacity_size.yz);
    vec3 ends[2];
    float depth[2];
    vec4 pts[2] = vec4[2](segs[i].a, segs[i].b);
    for (int k = 0; k < 2; ++k) {
        vec4 clip = pc.index_to_clip * vec4(pts[k].xyz, 1.0);
        if (clip.w <= 0.0) {
            return;
        }
        vec2 ndc = clip.xy / clip.w;
        // y down, as the render targets.
        ends[k] = vec3((ndc * 0.5 + 0.5) * vec2(size), 0.0);
        depth[k] = dot(pts[k].xyz, pc.depth.xyz) + pc.depth.w;
    }
    vec2 d = ends[1].xy - ends[0].xy;
    int steps = int(ceil(max(abs(d.x), abs(d.y))));
    steps = clamp(steps, 1, 4096);
    for (int s = 0; s <= steps; ++s) {
        float t = float(s) / float(steps);
        ivec2 p = ivec2(floor(ends[0].xy + t * d));
        if (any(lessThan(p, ivec2(0))) || any(greaterThanEqual(p, size))) {
            continue;
        }
        float z = mix(depth[0], depth[1], t);
        if (z <= imageLoad(focus_depth, p).r + pc.params.x) {
            imageStore(edges, p, vec4(pc.params.y));
        }
    }
}
