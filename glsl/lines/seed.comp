#version 460
// The seeds of the seeded traversal (`LineExtractor::record` with `LineParams::seeded`): the
// cells of the previous frame's segments (mode 0, read before this frame resets the buffer),
// and every stride-th cell along each axis whose corners straddle τ (mode 1), so that lines the
// previous frame did not have are found too. Both enter the first frontier as searches, for
// the kind of the segment they come from.
#include "lines.glsl"

layout(local_size_x = 64) in;

layout(set = 0, binding = 0) uniform sampler3D volume;

struct Segment {
    vec4 a;
    vec4 b;
};

layout(set = 0, binding = 1) readonly buffer Lines {
    uint groups;
    uint one_y;
    uint one_z;
    uint count;
    Segment segs[];
};

layout(push_constant) uniform Push { LinesPush pc; };

#define FRONTIER_BINDING 2
#define VISITED_BINDING 3
#include "frontier.glsl"

void main() {
    uint step = gl_NumWorkGroups.x * 64u;
    if (pc.seed_mode == 0u) {
        uint n = min(count, pc.capacity);
        for (uint id = gl_GlobalInvocationID.x; id < n; id += step) {
            vec3 m = 0.5 * (segs[id].a.xyz + segs[id].b.xyz);
            push_cell(ivec3(floor(m)), segs[id].a.w == 0.0 ? SEARCH_SILHOUETTE : SEARCH_SUGGESTIVE);
        }
        return;
    }
    ivec3 grid = (pc.dims - 2) / pc.stride + 1;
    uint n = uint(grid.x) * uint(grid.y) * uint(grid.z);
    for (uint id = gl_GlobalInvocationID.x; id < n; id += step) {
        ivec3 g = ivec3(int(id % uint(grid.x)), int((id / uint(grid.x)) % uint(grid.y)),
                        int(id / (uint(grid.x) * uint(grid.y))));
        ivec3 c = g * pc.stride;
        int inside = 0;
        for (int i = 0; i < 8; ++i) {
            ivec3 q = min(c + ivec3(i & 1, (i >> 1) & 1, (i >> 2) & 1), pc.dims - 1);
            inside += texelFetch(volume, q, 0).r >= pc.iso ? 1 : 0;
        }
        if (inside != 0 && inside != 8) {
            // With both kinds, seeds search for each in a checkerboard.
            bool silhouette = (pc.kinds & 1) != 0 && ((pc.kinds & 2) == 0 || ((g.x + g.y + g.z) & 1) == 0);
            push_cell(c, silhouette ? SEARCH_SILHOUETTE : SEARCH_SUGGESTIVE);
        }
    }
}
