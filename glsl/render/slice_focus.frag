#version 460
// The focus level (TL3 pass 1): only focus samples, written to three targets at once.
#include "shade.glsl"

layout(location = 0) out vec4 phong;         // with specular, premultiplied
layout(location = 1) out vec4 diffuse;       // without specular, premultiplied
layout(location = 2) out vec4 linear_depth;  // distance along the view direction (r)

void main() {
    Shaded p = shade_sample();
    if (!p.focus || p.alpha < MIN_ALPHA) {
        discard;
    }
    phong = vec4(p.phong * p.alpha, p.alpha);
    diffuse = vec4(p.diffuse * p.alpha, p.alpha);
    linear_depth = vec4(dot(world - u.eye.xyz, u.view_dir.xyz), 0.0, 0.0, 1.0);
}
