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

// Texture coordinate of the occlusion transfer function for intensity s and occlusion o (OS4).
vec2 occlusion_tf_coord(float s, float occlusion) {
    return vec2(s, occlusion);
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

#endif
