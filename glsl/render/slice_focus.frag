#version 460
// The focus level (TL3 pass 1): only focus samples, written to three targets at once.
#include "shade.glsl"

layout(location = 0) out vec4 phong;         // with specular, premultiplied
layout(location = 1) out vec4 diffuse;       // without specular, premultiplied
layout(location = 2) out vec4 linear_depth;  // distance along the view direction (r)

void main() {
    float s = sample_intensity();
    if (!sample_in_focus(s)) {
        discard;
    }
    vec4 c = classify(s, true);
    if (c.a < MIN_ALPHA) {
        discard;
    }
    vec3 p, d;
    shade(c.rgb, true, p, d);
    phong = vec4(p * c.a, c.a);
    diffuse = vec4(d * c.a, c.a);
    linear_depth = vec4(dot(world - u.eye.xyz, u.view_dir.xyz), 0.0, 0.0, 1.0);
}
