#version 460
// Draws the extracted segments into the style's edge image, one segment per invocation,
// antialiased and depth-tested against the focus level's linear depth (the two-level paper's
// trick: pass 1's depth replaces a visibility computation).
//
// A segment is a line one pixel wide with a tent profile: a pixel whose centre lies at distance
// d < 1 from the segment (round caps) is covered 1 − d, so a line crossing between two pixel
// rows lights both by halves and the coverage across it always sums to one pixel. A covered
// pixel is drawn where the depth of its nearest point on the segment is at most the focus depth
// plus a bias; where there is no focus (+inf) it is always drawn. Segments meet and overlap at
// shared ends, so a pixel keeps the largest value written to it, by atomic max on the unsigned
// view of the R32F image (non-negative floats order as their bits do): the result does not
// depend on the order the segments are drawn in.
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
// The R32_UINT view of the R32F edge image.
layout(set = 0, binding = 2, r32ui) uniform uimage2D edges;

layout(push_constant) uniform Push { RasterPush pc; };

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= min(count, pc.capacity_size.x)) {
        return;
    }
    ivec2 size = ivec2(pc.capacity_size.yz);
    vec2 ends[2];
    float depth[2];
    vec4 pts[2] = vec4[2](segs[i].a, segs[i].b);
    for (int k = 0; k < 2; ++k) {
        vec4 clip = pc.index_to_clip * vec4(pts[k].xyz, 1.0);
        if (clip.w <= 0.0) {
            return;
        }
        vec2 ndc = clip.xy / clip.w;
        // y down, as the render targets; pixel (x, y) covers [x, x + 1) × [y, y + 1).
        ends[k] = (ndc * 0.5 + 0.5) * vec2(size);
        depth[k] = dot(pts[k].xyz, pc.depth.xyz) + pc.depth.w;
    }
    vec2 a = ends[0], d = ends[1] - ends[0];
    float len2 = dot(d, d);
    // Walk the major axis over the pixel centres within one pixel of the segment; in each
    // column (or row), the pixels whose centres lie within 1.5 of the segment across it, which
    // holds every centre within distance 1 of it (at 45°, 1 across is √2 along the minor axis).
    bool x_major = abs(d.x) >= abs(d.y);
    vec2 am = x_major ? a : a.yx;
    vec2 dm = x_major ? d : d.yx;
    float lo = min(am.x, am.x + dm.x), hi = max(am.x, am.x + dm.x);
    int i0 = int(ceil(lo - 1.5)), i1 = int(floor(hi + 0.5));
    i1 = min(i1, i0 + 4096);
    float full = pc.params.y, floor_value = pc.params.z;
    for (int c = i0; c <= i1; ++c) {
        float t = dm.x != 0.0 ? clamp((float(c) + 0.5 - am.x) / dm.x, 0.0, 1.0) : 0.0;
        float across = am.y + t * dm.y;
        for (int r = int(ceil(across - 2.0)); r <= int(floor(across + 1.0)); ++r) {
            ivec2 p = x_major ? ivec2(c, r) : ivec2(r, c);
            if (any(lessThan(p, ivec2(0))) || any(greaterThanEqual(p, size))) {
                continue;
            }
            vec2 q = vec2(p) + 0.5;
            float s = len2 > 0.0 ? clamp(dot(q - a, d) / len2, 0.0, 1.0) : 0.0;
            float coverage = 1.0 - length(a + s * d - q);
            if (coverage <= 0.0) {
                continue;
            }
            float z = mix(depth[0], depth[1], s);
            if (z <= imageLoad(focus_depth, p).r + pc.params.x) {
                float v = floor_value + coverage * (full - floor_value);
                imageAtomicMax(edges, p, floatBitsToUint(v));
            }
        }
    }
}
