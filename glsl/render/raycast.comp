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
// Per brick: bit 0 = may hold visible context (or one-pass) samples, bit 1 = may hold focus.
layout(set = 0, binding = 13) readonly buffer Bricks { uint brick_flags[]; };

layout(push_constant) uniform Push {
    mat4 inv_view_proj;   // clip -> box frame
    vec4 planes;          // x: depth of plane 0 along view_dir (farthest), y: spacing, z: planes, w: ert
    ivec4 bricks;         // brick counts xyz, w: brick size in voxels
    ivec4 flags;          // x: two levels, y: skip empty bricks, z: jitter seed (0 off),
                          // w: bit 0 refine iso hits, bit 1 equal steps along each ray
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
    bool two = p.flags.x != 0;
    float cos_t = dot(dir, d);
    if (t_out > t_in && cos_t > 0.0) {
        // Samples are t(m) = a + b m for m = m_first, m_first + 1, ... (front to back).
        // Planes: plane k has depth far - (k + 0.5) spacing along d, and depth along the ray is
        // dot(o, d) + t cos_t; with m = -k, a and b follow, and m stays within the planes.
        // Equal steps: spacing along the ray from the box entry.
        float od = dot(o, d);
        float far = p.planes.x, spacing = p.planes.y;
        float jitter = 0.0;
        if (p.flags.z != 0) {
            jitter = float(pcg3d(uvec3(px, uint(p.flags.z))).x >> 8u) / 16777216.0 - 0.5;
        }
        float a, b, m_first, m_last;
        if ((p.flags.w & 2) == 0) {
            a = (far - (0.5 + jitter) * spacing - od) / cos_t;
            b = spacing / cos_t;
            m_first = max(ceil((t_in - a) / b), 1.0 - p.planes.z);
            m_last = min(floor((t_out - a) / b), 0.0);
        } else {
            a = t_in + (0.5 + jitter) * spacing;
            b = spacing;
            m_first = 0.0;
            m_last = floor((t_out - a) / b);
        }
        bool first = true;
        float ert = p.planes.w;
        // The previous plane's sample, for refining an isosurface hit (t < 0: none).
        float prev_t = -1.0, prev_s = 0.0;
        // The brick of the last sample and its flags, looked up once per brick.
        ivec3 cur_brick = ivec3(-1);
        uint cur_flags = 0u;
        for (float m = m_first; m <= m_last; m += 1.0) {
            float t = a + b * m;
            if (t < t_in || t > t_out) {
                continue;
            }
            world = o + t * dir;
            tex = world / (2.0 * u.half_extent.xyz) + 0.5;
            if (p.flags.y != 0) {
                ivec3 bk = brick_of(tex);
                if (bk != cur_brick) {
                    cur_brick = bk;
                    cur_flags = brick_flags[bk.x + p.bricks.x * (bk.y + p.bricks.y * bk.z)];
                }
                uint f = cur_flags;
                // One pass needs visible bricks; two levels need visible context in front of
                // the first focus sample, or focus.
                uint need = two ? (first ? 3u : 2u) : 1u;
                if ((f & need) == 0u) {
                    // Resume at the first sample at or behind the brick's exit (less a hair, so
                    // that rounding can only revisit this brick, never skip a sample of the
                    // next), and always at least one sample further.
                    float te = brick_exit(bk, o, dir) - 1e-4 * b;
                    m = max(ceil((te - a) / b), m + 1.0) - 1.0;
                    prev_t = -1.0;
                    continue;
                }
            }
            float s = sample_intensity();
            bool focus = sample_in_focus(s);
            bool refine = two && focus && first && (p.flags.w & 1) != 0 && int(u.focus.z) == FOCUS_ISO;
            if (refine && prev_t >= 0.0 && s > prev_s) {
                // Regula falsi between the previous plane (below the isovalue) and this one.
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
            prev_t = t;
            prev_s = s;
            if (!two) {
                vec4 c = classify(s, focus);
                if (c.a < MIN_ALPHA) {
                    continue;
                }
                vec3 ph, di;
                shade(c.rgb, focus, ph, di);
                fp += (1.0 - fp.a) * vec4(ph * c.a, c.a);
                if (fp.a >= ert) {
                    break;
                }
            } else if (focus) {
                vec4 c = classify(s, true);
                if (c.a < MIN_ALPHA) {
                    continue;
                }
                vec3 ph, di;
                shade(c.rgb, true, ph, di);
                fp += (1.0 - fp.a) * vec4(ph * c.a, c.a);
                fd += (1.0 - fd.a) * vec4(di * c.a, c.a);
                if (first) {
                    depth = dot(world - u.eye.xyz, d);
                    first = false;
                }
                if (fp.a >= ert) {
                    break;
                }
            } else if (first) {
                vec4 c = classify(s, false);
                if (c.a < MIN_ALPHA) {
                    continue;
                }
                vec3 ph, di;
                shade(c.rgb, false, ph, di);
                ctx += (1.0 - ctx.a) * vec4(ph * c.a, c.a);
            }
        }
    }
    if (two) {
        imageStore(out_phong, px, fp);
        imageStore(out_diffuse, px, fd);
        imageStore(out_depth, px, vec4(depth));
        imageStore(out_context, px, ctx);
        imageStore(out_composite, px, ctx + (1.0 - ctx.a) * fp);
    } else {
        imageStore(out_composite, px, fp);
    }
}
