#version 460
// One slice sample, premultiplied, for the classic single pass (MODE 0) or the context level of a
// two-level frame (MODE 1: focus samples are left to the focus pass).
#include "shade.glsl"

layout(constant_id = 0) const int MODE = 0;

layout(location = 0) out vec4 color;

void main() {
    Shaded p = shade_sample();
    if ((MODE == 1 && p.focus) || p.alpha < MIN_ALPHA) {
        discard;
    }
    color = vec4(p.phong * p.alpha, p.alpha);
}
