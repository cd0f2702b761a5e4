// Object-space lines (SPEC TL5): silhouettes and suggestive contours on f = τ, one cell per
// invocation, appended to a buffer through an atomic counter. The GPU twin of
// src/volume/lines.rs, which documents the method; the arithmetic follows it step by step.
// Included by extract.comp (the Hessian by differences of the volume at every cell corner) and
// extract_hessian.comp (PRECOMPUTED_HESSIAN: read from the two images hessian.comp made), and
// extract_seeded.comp (SEEDED: one round of the seeded traversal over a frontier of cells).
#include "lines.glsl"

// One straddling cell per invocation, from the list cells.comp made.
layout(local_size_x = 64) in;

// The normalised volume: the renderer's R16 texture or an R32F upload, read texel by texel.
layout(set = 0, binding = 0) uniform sampler3D volume;

struct Segment {
    vec4 a;   // index coordinates; a.w = kind (0 silhouette, 1 suggestive contour)
    vec4 b;
};

// The header is also the indirect dispatch of the rasteriser (64 segments per workgroup):
// `groups` grows by one with every 64th stored segment. `count` keeps counting past `capacity`,
// so the caller learns how many were lost.
layout(set = 0, binding = 1) buffer Lines {
    uint groups;
    uint one_y;
    uint one_z;
    uint count;
    Segment segs[];
};

layout(set = 0, binding = 2) readonly buffer Cells {
    uint cell_groups;
    uint cell_one_y;
    uint cell_one_z;
    uint cell_count;
    uint cells[];
};

#ifdef PRECOMPUTED_HESSIAN
// (hxx, hyy, hzz, hxy) and (hxz, hyz, 0, 0) per voxel, physical units (hessian.comp).
layout(set = 0, binding = 3) uniform sampler3D hessian_a;
layout(set = 0, binding = 4) uniform sampler3D hessian_b;
#endif

layout(push_constant) uniform Push { LinesPush pc; };

#ifdef SEEDED
// The next round's frontier and the visited bits; `cells` above is this round's frontier.
#define FRONTIER_BINDING 3
#define VISITED_BINDING 4
#include "frontier.glsl"
// The cell this invocation extracts, the search it came as (0 when it came following a line),
// and whether it drew a line.
ivec3 g_cell;
uint g_search;
bool g_emitted;

// The line leaves the cell where an end of its segment lies on the cell's boundary: there the
// end's coordinate equals the face's exactly (crossings interpolate between corners of that
// face). Follow it into the neighbour across that face, or across the edge or corner it is on.
void follow(vec3 p) {
    vec3 c = vec3(g_cell);
    ivec3 o = ivec3(equal(p, c + 1.0)) - ivec3(equal(p, c));
    for (int m = 1; m < 8; ++m) {
        ivec3 sel = ivec3(m & 1, (m >> 1) & 1, (m >> 2) & 1);
        if (!any(greaterThan(sel, abs(o)))) {
            push_cell(g_cell + o * sel, 0u);
        }
    }
}
#endif

// Which kinds this pipeline extracts (bit 0 silhouettes, bit 1 suggestive contours): a
// specialisation constant, so the other kind's code is not compiled in (passes/lines.rs).
layout(constant_id = 0) const int KINDS = 3;

struct Point {
    vec3 p;
    vec3 g;
    float ndotv;
    float kappa;
};

Point lerp_point(Point a, Point b, float t) {
    Point r;
    r.p = a.p + t * (b.p - a.p);
    r.g = a.g + t * (b.g - a.g);
    r.ndotv = a.ndotv + t * (b.ndotv - a.ndotv);
    r.kappa = a.kappa + t * (b.kappa - a.kappa);
    return r;
}

float at(ivec3 q) {
    return texelFetch(volume, clamp(q, ivec3(0), pc.dims - 1), 0).r;
}

vec3 view_at(vec3 x) {
    return pc.eye.w == 0.0 ? normalize(pc.eye.xyz) : normalize(pc.eye.xyz - x);
}

void emit(Point a, Point b, float kind) {
#ifdef SEEDED
    g_emitted = true;
    follow(a.p);
    follow(b.p);
#endif
    uint i = atomicAdd(count, 1u);
    if (i < pc.capacity) {
        if (i % 64u == 0u) {
            atomicAdd(groups, 1u);
        }
        segs[i].a = vec4(a.p, kind);
        segs[i].b = vec4(b.p, 0.0);
    }
}

bool before(vec3 a, vec3 b) {
    return a.x < b.x || (a.x == b.x && (a.y < b.y || (a.y == b.y && a.z < b.z)));
}

// The zero segment of h (0: n·v, 1: κ_r) over triangle t; false when h keeps its sign.
bool zero_segment(Point t[3], int which, out Point e0, out Point e1) {
    float v[3];
    for (int i = 0; i < 3; ++i) {
        v[i] = which == 0 ? t[i].ndotv : t[i].kappa;
    }
    int n = 0;
    for (int k = 0; k < 3; ++k) {
        int i = k, j = (k + 1) % 3;
        if ((v[i] >= 0.0) != (v[j] >= 0.0)) {
            if (!before(t[i].p, t[j].p)) {
                int s = i;
                i = j;
                j = s;
            }
            Point p = lerp_point(t[i], t[j], v[i] / (v[i] - v[j]));
            if (n == 0) {
                e0 = p;
            } else {
                e1 = p;
            }
            ++n;
        }
    }
    return n == 2;
}

void triangle(Point t[3]) {
    Point a, b;
    if ((KINDS & 1) != 0 && (pc.kinds & 1) != 0 && zero_segment(t, 0, a, b)) {
        emit(a, b, 0.0);
    }
    if ((KINDS & 2) != 0 && (pc.kinds & 2) != 0 && zero_segment(t, 1, a, b)) {
        Point m = lerp_point(a, b, 0.5);
        vec3 x = m.p * pc.spacing;
        vec3 n = normalize(-m.g);
        vec3 v = view_at(x);
        float ndotv = dot(n, v);
        vec3 p0 = t[0].p * pc.spacing, p1 = t[1].p * pc.spacing, p2 = t[2].p * pc.spacing;
        vec3 e1 = p1 - p0, e2 = p2 - p0;
        float d1 = t[1].kappa - t[0].kappa, d2 = t[2].kappa - t[0].kappa;
        float a11 = dot(e1, e1), a12 = dot(e1, e2), a22 = dot(e2, e2);
        float det = a11 * a22 - a12 * a12;
        if (ndotv > 0.0 && ndotv < pc.cos_c && det > 1e-20) {
            float ca = (d1 * a22 - d2 * a12) / det;
            float cb = (d2 * a11 - d1 * a12) / det;
            vec3 grad = ca * e1 + cb * e2;
            vec3 w = normalize(v - ndotv * n);
            if (dot(grad, w) > pc.derivative_threshold) {
                emit(a, b, 1.0);
            }
        }
    }
}

#ifdef SEEDED
// A search that found no line here steps to the neighbour across the face the surface crosses
// with the smallest mean |h| at its corners (h = n·v for a silhouette search, κ_r for a
// suggestive one): a descent towards h = 0 over the surface, as Burns et al. walk from a seed to
// a contour. Faces are tried best first until a neighbour not yet visited is found.
void walk(float f[8], Point pts[8]) {
    bool silhouettes = g_search == SEARCH_SILHOUETTE;
    float score[6];
    for (int face = 0; face < 6; ++face) {
        int axis = face >> 1, side = face & 1;
        int inside = 0;
        float sum = 0.0;
        for (int i = 0; i < 8; ++i) {
            if (((i >> axis) & 1) == side) {
                inside += f[i] >= pc.iso ? 1 : 0;
                sum += abs(silhouettes ? pts[i].ndotv : pts[i].kappa);
            }
        }
        score[face] = inside != 0 && inside != 4 ? sum : 1e30;
    }
    for (int t = 0; t < 6; ++t) {
        int best = -1;
        for (int face = 0; face < 6; ++face) {
            if (score[face] < 1e30 && (best < 0 || score[face] < score[best])) {
                best = face;
            }
        }
        if (best < 0) {
            return;
        }
        score[best] = 1e30;
        ivec3 d = ivec3(0);
        d[best >> 1] = 2 * (best & 1) - 1;
        if (push_cell(g_cell + d, g_search)) {
            return;
        }
    }
}
#endif

const ivec4 TETS[6] = ivec4[6](ivec4(0, 1, 3, 7), ivec4(0, 1, 5, 7), ivec4(0, 2, 3, 7),
                               ivec4(0, 2, 6, 7), ivec4(0, 4, 5, 7), ivec4(0, 4, 6, 7));

void extract_cell(ivec3 c) {
    float f[8];
    int inside = 0;
    for (int i = 0; i < 8; ++i) {
        f[i] = at(c + ivec3(i & 1, (i >> 1) & 1, (i >> 2) & 1));
        inside += f[i] >= pc.iso ? 1 : 0;
    }
    if (inside == 0 || inside == 8) {
        return;
    }
    Point pts[8];
    vec3 s = pc.spacing;
    for (int i = 0; i < 8; ++i) {
        ivec3 q = c + ivec3(i & 1, (i >> 1) & 1, (i >> 2) & 1);
        vec3 g = vec3(at(q + ivec3(1, 0, 0)) - at(q - ivec3(1, 0, 0)),
                      at(q + ivec3(0, 1, 0)) - at(q - ivec3(0, 1, 0)),
                      at(q + ivec3(0, 0, 1)) - at(q - ivec3(0, 0, 1))) / (2.0 * s);
#ifdef PRECOMPUTED_HESSIAN
        vec4 h0 = texelFetch(hessian_a, q, 0);
        vec2 h1 = texelFetch(hessian_b, q, 0).xy;
#else
        vec4 h0;
        vec2 h1;
        hessian_at(volume, pc.dims, s, q, h0, h1);
#endif
        float hxx = h0.x, hyy = h0.y, hzz = h0.z, hxy = h0.w, hxz = h1.x, hyz = h1.y;
        vec3 p = vec3(q);
        vec3 v = view_at(p * s);
        float gl = max(length(g), 1e-30);
        vec3 n = -g / gl;
        float ndotv = dot(n, v);
        vec3 w = v - ndotv * n;
        float ww = dot(w, w);
        vec3 hw = vec3(hxx * w.x + hxy * w.y + hxz * w.z,
                       hxy * w.x + hyy * w.y + hyz * w.z,
                       hxz * w.x + hyz * w.y + hzz * w.z);
        pts[i].p = p;
        pts[i].g = g;
        pts[i].ndotv = ndotv;
        pts[i].kappa = ww > 1e-12 ? -dot(w, hw) / (gl * ww) : 0.0;
    }
    for (int k = 0; k < 6; ++k) {
        ivec4 tet = TETS[k];
        float sv[4] = float[4](f[tet.x] - pc.iso, f[tet.y] - pc.iso, f[tet.z] - pc.iso,
                               f[tet.w] - pc.iso);
        int ins[4];
        int outs[4];
        int ni = 0, no = 0;
        for (int j = 0; j < 4; ++j) {
            if (sv[j] >= 0.0) {
                ins[ni++] = j;
            } else {
                outs[no++] = j;
            }
        }
        if (ni == 0 || ni == 4) {
            continue;
        }
        // Crossing on edge (a, b) of the tetrahedron, from the lower corner index to the higher.
        #define CROSS(A, B, OUT) { \
            int ca_ = (A), cb_ = (B); \
            if (tet[ca_] > tet[cb_]) { int t_ = ca_; ca_ = cb_; cb_ = t_; } \
            OUT = lerp_point(pts[tet[ca_]], pts[tet[cb_]], sv[ca_] / (sv[ca_] - sv[cb_])); }
        // One triangle (a lone corner) or two (two in, two out), from four crossings chosen by
        // index first: a CPU rasteriser runs both sides of a branch in every lane, so the
        // crossings and triangles are not split between the two cases.
        int pa[4], pb[4];
        if (ni == 1 || ni == 3) {
            int lone = ni == 1 ? ins[0] : outs[0];
            int o[3];
            int m = 0;
            for (int j = 0; j < 4; ++j) {
                if (j != lone) {
                    o[m++] = j;
                }
            }
            pa = int[4](lone, lone, lone, lone);
            pb = int[4](o[0], o[1], o[2], o[2]);
        } else {
            // ac, ad, bd, bc: the triangles are (ac, ad, bd) and (ac, bd, bc).
            pa = int[4](ins[0], ins[0], ins[1], ins[1]);
            pb = int[4](outs[0], outs[1], outs[1], outs[0]);
        }
        Point q[4];
        for (int j = 0; j < 4; ++j) {
            CROSS(pa[j], pb[j], q[j]);
        }
        Point t0[3] = Point[3](q[0], q[1], q[2]);
        triangle(t0);
        if (ni == 2) {
            Point t1[3] = Point[3](q[0], q[2], q[3]);
            triangle(t1);
        }
    }
#ifdef SEEDED
    if (g_search != 0u && !g_emitted) {
        walk(f, pts);
    }
#endif
}

void main() {
    uint n = min(cell_count, pc.cell_capacity);
    for (uint id = gl_GlobalInvocationID.x; id < n; id += LINES_MAX_GROUPS * 64u) {
        uint k = cells[id];
#ifdef SEEDED
        g_search = k & ~CELL_BITS;
        g_emitted = false;
        k &= CELL_BITS;
#endif
        uint dx = uint(pc.dims.x), dy = uint(pc.dims.y);
        ivec3 c = ivec3(int(k % dx), int((k / dx) % dy), int(k / (dx * dy)));
#ifdef SEEDED
        g_cell = c;
#endif
        extract_cell(c);
    }
}
