#version 460
// The ray caster (SPEC §6): one invocation per pixel writes the same layers as the slicer's passes
// (focus.phong, focus.diffuse, focus.depth, context, composite; or the one-pass composite).
//
// By default samples lie where the slicer's view-aligned planes cross the ray (depth steps of
// `spacing` along the view direction), so at the same number of planes both renderers sample the
// same points and use the same opacity correction; or they are `spacing` apart along each ray
// (equal world steps, which that correction then fits exactly). A per-pixel jitter moves them.
// Front to back: a focus sample composites into the focus layers and the first one sets the
// depth; a context sample counts only in front of the first focus sample (the slicer's depth
// test). Rays stop once their opacity reaches `ert` (early termination), and skip bricks that
// hold nothing under the current classification (empty-space skipping) without moving any sample.
#define RAYCAST
#include "shade.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 8, rgba32f) uniform writeonly image2D out_phong;
layout(set = 0, binding = 9, rgba32f) uniform writeonly image2D out_diffuse;
layout(set = 0, binding = 10, r32f) uniform writeonly image2D out_depth;
layout(set = 0, binding = 11, rgba32f) uniform writeonly image2D out_context;
layout(set = 0, binding = 12, rgba32f) uniform writeonly image2D out_composite;
// Entries 0..255: per texel i of the 1D transfer function, the larger opacity of texels i and
// i + 1 (float bits), a bound on any opacity that linear filtering can return between them.
// Then per brick: bit 0 = may hold visible context (or one-pass) samples, bit 1 = may hold focus.
layout(set = 0, binding = 13) readonly buffer RayTables { uint ray_tables[]; };
const int BRICKS_AT = 256;

layout(push_constant) uniform Push {
    mat4 inv_view_proj;   // clip -> box frame
    vec4 planes;          // x: depth of plane 0 along view_dir (farthest), y: spacing, z: planes, w: ert
    ivec4 bricks;         // brick counts xyz, w: brick size in voxels
    ivec4 flags;          // x: two levels (unread: VARIANT selects the mode), y: skip empty
                          // bricks, z: jitter seed (0 off), w: bit 0 refine iso hits, bit 1
                          // equal steps along each ray (the last also selected by VARIANT)
} p;

const float INF = 1.0 / 0.0;

// The brick of box-frame texture coordinate t (clamped into the volume).
ivec3 brick_of(vec3 t) {
    ivec3 v = clamp(ivec3(floor(t * u.volume_dims.xyz)), ivec3(0), ivec3(u.volume_dims.xyz) - 1);
    return v / p.bricks.w;
}

// Ray parameter where the ray leaves brick b (slab exit).
float brick_exit(ivec3 b, vec3 o, vec3 dir) {
    vec3 lo = vec3(b * p.bricks.w) / u.volume_dims.xyz;
    vec3 hi = min(vec3((b + 1) * p.bricks.w) / u.volume_dims.xyz, vec3(1.0));
    vec3 wlo = (lo - 0.5) * 2.0 * u.half_extent.xyz;
    vec3 whi = (hi - 0.5) * 2.0 * u.half_extent.xyz;
    vec3 inv = 1.0 / dir;
    vec3 t1 = (wlo - o) * inv;
    vec3 t2 = (whi - o) * inv;
    vec3 tmax = max(t1, t2);
    return min(min(tmax.x, tmax.y), tmax.z);
}

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(out_composite);
    if (px.x >= size.x || px.y >= size.y) {
        return;
    }
    vec2 ndc = (vec2(px) + 0.5) / vec2(size) * 2.0 - 1.0;
    vec4 a = p.inv_view_proj * vec4(ndc, 0.0, 1.0);
    vec4 b = p.inv_view_proj * vec4(ndc, 1.0, 1.0);
    vec3 o = a.xyz / a.w;
    vec3 dir = normalize(b.xyz / b.w - o);
    vec3 d = u.view_dir.xyz;

    // Box entry and exit.
    vec3 inv = 1.0 / dir;
    vec3 t1 = (-u.half_extent.xyz - o) * inv;
    vec3 t2 = (u.half_extent.xyz - o) * inv;
    vec3 tmin3 = min(t1, t2), tmax3 = max(t1, t2);
    float t_in = max(max(max(tmin3.x, tmin3.y), tmin3.z), 0.0);
    float t_out = min(min(tmax3.x, tmax3.y), tmax3.z);

    vec4 fp = vec4(0.0), fd = vec4(0.0), ctx = vec4(0.0);
    float depth = INF;
    float cos_t = dot(dir, d);
    if (t_out > t_in && cos_t > 0.0) {
        // Samples are t(m) = a + b m for m = m_first, m_first + 1, ... (front to back).
        // Planes: plane k has depth far - (k + 0.5) spacing along d, and depth along the ray is
        // dot(o, d) + t cos_t; with m = -k, a and b follow, and m stays within the planes.
        // Equal steps: spacing along the ray from the box entry.
        float od = dot(o, d);
        float far = p.planes.x, spacing = p.planes.y;
        float jitter = 0.0;
        if (V_JITTER && p.flags.z != 0) {
            jitter = float(pcg3d(uvec3(px, uint(p.flags.z))).x >> 8u) / 16777216.0 - 0.5;
        }
        float a, b, m, m_last;
        if (!V_WORLD_STEPS) {
            a = (far - (0.5 + jitter) * spacing - od) / cos_t;
            b = spacing / cos_t;
            m = max(ceil((t_in - a) / b), 1.0 - p.planes.z);
            m_last = min(floor((t_out - a) / b), 0.0);
        } else {
            a = t_in + (0.5 + jitter) * spacing;
            b = spacing;
            m = 0.0;
            m_last = floor((t_out - a) / b);
        }
        bool first = true;
        float ert = p.planes.w;
        bool skip = V_SKIP_EMPTY && p.flags.y != 0;
        bool refine_on = V_TWO_LEVEL && V_REFINE_ISO && (p.flags.w & 1) != 0 && int(u.focus.z) == FOCUS_ISO;
        // Without an occlusion TF or opacity modulation, the walk tests a sample's bound from the
        // table instead of classifying it: a raw opacity below a_min stays below MIN_ALPHA after
        // the correction for the spacing (with a margin for rounding). The exact test follows.
        bool iso = int(u.focus.z) == FOCUS_ISO;
        float a_min = 0.99 * (1.0 - pow(1.0 - MIN_ALPHA, 1.0 / u.material.w));
        // The previous sample on the ray, for refining an isosurface hit (t < 0: none).
        float prev_t = -1.0, prev_s = 0.0;
        // The brick of the last sample and its flags, looked up once per brick.
        ivec3 cur_brick = ivec3(-1);
        uint cur_flags = 0u;
        // Two loops: the inner one walks to the next sample that adds to a layer, paying only for
        // its intensity and class; the outer one shades and composites it. A CPU rasteriser runs
        // a loop body for all its lanes while any is active, so shading in the walk would be paid
        // at every sample of every lane; here it is paid once per contributing sample.
        for (;;) {
            float t = 0.0, s = 0.0;
            bool focus = false, hit = false;
            vec4 c = vec4(0.0);
            for (; m <= m_last; m += 1.0) {
                t = a + b * m;
                if (t < t_in || t > t_out) {
                    continue;
                }
                world = o + t * dir;
                tex = world / (2.0 * u.half_extent.xyz) + 0.5;
                if (skip) {
                    ivec3 bk = brick_of(tex);
                    if (bk != cur_brick) {
                        cur_brick = bk;
                        cur_flags = ray_tables[BRICKS_AT + bk.x + p.bricks.x * (bk.y + p.bricks.y * bk.z)];
                    }
                    // One pass needs visible bricks; two levels need visible context in front of
                    // the first focus sample, or focus.
                    uint need = V_TWO_LEVEL ? (first && ctx.a < ert ? 3u : 2u) : 1u;
                    if ((cur_flags & need) == 0u) {
                        // Resume at the first sample at or behind the brick's exit (less a hair,
                        // so that rounding can only revisit this brick, never skip a sample of
                        // the next), and always at least one sample further.
                        float te = brick_exit(bk, o, dir) - 1e-4 * b;
                        m = max(ceil((te - a) / b), m + 1.0) - 1.0;
                        prev_t = -1.0;
                        continue;
                    }
                }
                s = sample_intensity();
                focus = sample_in_focus(s);
                // Behind the first focus sample, only focus samples count (the depth test); nor do
                // context samples behind a context that reached `ert` (early termination).
                bool counts = !V_TWO_LEVEL || focus || (first && ctx.a < ert);
                bool maybe;
                if (V_OTF || V_MOD_OPACITY) {
                    c = classify(s, focus);
                    maybe = c.a >= MIN_ALPHA;
                } else {
                    int i = clamp(int(floor(s * 256.0 - 0.5)), 0, 255);
                    maybe = uintBitsToFloat(ray_tables[i]) >= a_min || (focus && iso);
                }
                if (counts && maybe) {
                    hit = true;
                    break;
                }
                prev_t = t;
                prev_s = s;
            }
            if (!hit) {
                break;
            }
            m += 1.0;
            if (refine_on && focus && first && prev_t >= 0.0 && s > prev_s) {
                // Regula falsi between the previous sample (below the isovalue) and this one.
                float ta = prev_t, sa = prev_s, tb = t, sb = s;
                for (int i = 0; i < 4; i++) {
                    float tm = ta + (u.focus.x - sa) / (sb - sa) * (tb - ta);
                    world = o + tm * dir;
                    tex = world / (2.0 * u.half_extent.xyz) + 0.5;
                    float sm = sample_intensity();
                    if (sm >= u.focus.x) {
                        tb = tm;
                        sb = sm;
                    } else {
                        ta = tm;
                        sa = sm;
                    }
                }
                t = ta + (u.focus.x - sa) / (sb - sa) * (tb - ta);
                world = o + t * dir;
                tex = world / (2.0 * u.half_extent.xyz) + 0.5;
            }
            if (!(V_OTF || V_MOD_OPACITY) || refine_on) {
                // The exact class (at the surface when refined: an occlusion or importance
                // lookup may move it).
                c = classify(s, focus);
            }
            prev_t = t;
            prev_s = s;
            if (c.a < MIN_ALPHA) {
                continue;
            }
            vec3 ph, di;
            shade(c.rgb, focus, ph, di);
            if (!V_TWO_LEVEL) {
                fp += (1.0 - fp.a) * vec4(ph * c.a, c.a);
                if (fp.a >= ert) {
                    break;
                }
            } else if (focus) {
                fp += (1.0 - fp.a) * vec4(ph * c.a, c.a);
                fd += (1.0 - fd.a) * vec4(di * c.a, c.a);
                if (first) {
                    depth = dot(world - u.eye.xyz, d);
                    first = false;
                }
                if (fp.a >= ert) {
                    break;
                }
            } else {
                ctx += (1.0 - ctx.a) * vec4(ph * c.a, c.a);
                if (ctx.a >= ert && int(u.focus.z) == FOCUS_NONE) {
                    break;
                }
            }
        }
    }
    if (V_TWO_LEVEL) {
        imageStore(out_phong, px, fp);
        imageStore(out_diffuse, px, fd);
        imageStore(out_depth, px, vec4(depth));
        imageStore(out_context, px, ctx);
        imageStore(out_composite, px, ctx + (1.0 - ctx.a) * fp);
    } else {
        imageStore(out_composite, px, fp);
    }
}
