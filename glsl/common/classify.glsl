// Classification as pure functions: no bindings, no shader inputs, so fragment shaders (the slicer)
// and compute shaders (a ray caster, post passes) include the same code. The caller samples its
// textures and passes values in. Twin of src/classify/ (transfer.rs: correct_opacity).
#ifndef VELLUM_CLASSIFY_GLSL
#define VELLUM_CLASSIFY_GLSL

// Samples this transparent contribute nothing and must not set the focus depth.
const float MIN_ALPHA = 1.0 / 1024.0;

// Focus modes of the `focus` vector (lo, hi, mode, _) on the normalised intensity range.
const int FOCUS_NONE = 0;
const int FOCUS_RANGE = 1;
const int FOCUS_ISO = 2;

// Whether normalised intensity s is in the focus (two-level paper §3.1).
bool in_focus(float s, vec4 focus) {
    int mode = int(focus.z);
    return (mode == FOCUS_RANGE && s >= focus.x && s <= focus.y) || (mode == FOCUS_ISO && s >= focus.x);
}

// Opacity of one sample at `ratio` times the reference distance of one voxel.
float correct_opacity(float alpha, float ratio) {
    return 1.0 - pow(max(1.0 - alpha, 0.0), ratio);
}

// Transfer-function tables hold their function at the knots i / 255 (src/classify/transfer.rs,
// `table`), so a value of 0 reads exactly the function at 0 and 1 reads it at 1. This maps a value
// in [0, 1] onto the texture coordinate that interpolates between those knots.
const float TF_TEXELS = 256.0;
float tf_coord(float s) {
    return (clamp(s, 0.0, 1.0) * (TF_TEXELS - 1.0) + 0.5) / TF_TEXELS;
}

// Texel pair (i, i + 1) whose knots enclose value s: the entry of a bounds table for s.
int tf_pair(float s) {
    return clamp(int(floor(s * (TF_TEXELS - 1.0))), 0, int(TF_TEXELS) - 1);
}

// Texture coordinate of the occlusion transfer function for intensity s and occlusion o (OS4).
vec2 occlusion_tf_coord(float s, float occlusion) {
    return vec2(tf_coord(s), tf_coord(occlusion));
}

// Colour (straight) and opacity of a sample whose transfer function (1D, or the occlusion one)
// gave `rgba`, at `ratio` voxel lengths per sample. An isosurface focus is opaque.
vec4 classify_sample(vec4 rgba, float ratio, bool focus, vec4 focus_spec) {
    vec4 c = rgba;
    c.a = correct_opacity(c.a, ratio);
    if (focus && int(focus_spec.z) == FOCUS_ISO) {
        c.a = 1.0;
    }
    return c;
}

// Importance modulation (importance paper §4; twins in src/classify/modulation.rs).
// ΔD is in normalised intensity units and n = |ΔD| / max |ΔD| in [0, 1].

// Eq. 3 (mode 1, raw ΔD) or eq. 4 (mode 2, |ΔD|): rgb + ΔD·γ, floored at 0.
vec3 modulate_color(vec3 rgb, float delta_d, int mode, float gamma) {
    float d = mode == 2 ? abs(delta_d) : delta_d;
    return max(rgb + vec3(d * gamma), vec3(0.0));
}

// Eq. 5 with p = (t_l, t_h, k_l, k_h), clamped to [0, 1].
float modulate_opacity(float a, float n, vec4 p) {
    if (n < p.x) {
        return clamp(a * p.z * n, 0.0, 1.0);
    }
    if (n > p.y) {
        return clamp(a * p.w * n, 0.0, 1.0);
    }
    return a;
}

// Eq. 6: white when n >= t or f·n >= r.
bool stipple_is_white(float n, float r, float t, float f) {
    return n >= t || f * n >= r;
}

// PCG3D (Jarzynski and Olano 2020), as classify::modulation::pcg3d.
uvec3 pcg3d(uvec3 v) {
    v = v * 1664525u + 1013904223u;
    v.x += v.y * v.z;
    v.y += v.z * v.x;
    v.z += v.x * v.y;
    v ^= v >> 16u;
    v.x += v.y * v.z;
    v.y += v.z * v.x;
    v.z += v.x * v.y;
    return v;
}

// Sub-voxel steps of the stipple grid (classify::modulation::STIPPLE_GRID).
const float STIPPLE_GRID = 16.0;

// r(s) in [0, 1) for a sample at continuous voxel coordinates `voxel`: stateless and seeded.
float stipple_random(vec3 voxel, uint seed) {
    uvec3 q = uvec3(ivec3(floor(voxel * STIPPLE_GRID)));
    uvec3 v = q + seed * uvec3(0x9E3779B9u, 0x85EBCA6Bu, 0xC2B2AE35u);
    return float(pcg3d(v).x >> 8u) / 16777216.0;
}

#endif
