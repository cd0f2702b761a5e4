#version 460
// One slice sample, premultiplied, for the classic single pass (MODE 0) or the context level of a
// two-level frame (MODE 1: focus samples are left to the focus pass).
#include "shade.glsl"

layout(constant_id = 0) const int MODE = 0;

layout(location = 0) out vec4 color;

void main() {
    float s = sample_intensity();
    bool focus = sample_in_focus(s);
    if (MODE == 1 && focus) {
        discard;
    }
    vec4 c = classify(s, focus);
    if (c.a < MIN_ALPHA) {
        discard;
    }
    vec3 phong, diffuse;
    shade(c.rgb, focus, phong, diffuse);
    color = vec4(phong * c.a, c.a);
}
