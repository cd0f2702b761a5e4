// Classification and shading of one slice sample, shared by the one-pass, focus and context
// fragment shaders so that all levels see exactly the same samples.
#include "render.glsl"

layout(set = 0, binding = 0) uniform Uniforms { SliceUniforms u; };
layout(set = 0, binding = 1) uniform sampler3D volume;      // normalised intensity
layout(set = 0, binding = 2) uniform sampler3D gradient;    // xyz gradient (world), w length
layout(set = 0, binding = 3) uniform sampler2D transfer;    // 1D transfer function, 256 x 1

layout(location = 0) in vec3 tex;
layout(location = 1) in vec3 world;

struct Shaded {
    bool focus;
    float alpha;      // opacity after correction for the slice spacing
    vec3 phong;       // ambient + diffuse + specular
    vec3 diffuse;     // ambient + diffuse
};

bool in_focus(float s) {
    int mode = int(u.focus.z);
    return (mode == 1 && s >= u.focus.x && s <= u.focus.y) || (mode == 2 && s >= u.focus.x);
}

Shaded shade_sample() {
    Shaded r;
    float s = texture(volume, tex).r;
    vec4 c = texture(transfer, vec2(s, 0.5));
    // Opacity correction: alpha is defined per voxel of distance; material.w = spacing / voxel.
    r.alpha = 1.0 - pow(max(1.0 - c.a, 0.0), u.material.w);
    r.focus = in_focus(s);
    if (r.focus && int(u.focus.z) == 2) {
        r.alpha = 1.0;   // an isosurface focus is opaque
    }
    vec4 g = texture(gradient, tex);
    vec3 to_eye = u.view_dir.w > 0.5 ? -u.view_dir.xyz : normalize(u.eye.xyz - world);
    float ka = u.material.x, kd = u.material.y, ks = u.material.z;
    if (g.w > 1e-4) {
        // The gradient points into denser material; shading is two-sided.
        vec3 n = -g.xyz / g.w;
        vec3 l = u.light.xyz;
        float ndl = abs(dot(n, l));
        float ndh = abs(dot(n, normalize(l + to_eye)));
        r.diffuse = c.rgb * (ka + kd * ndl);
        r.phong = r.diffuse + vec3(ks * pow(ndh, u.light.w));
    } else {
        r.diffuse = c.rgb * (ka + kd);
        r.phong = r.diffuse;
    }
    return r;
}

// Samples this transparent contribute nothing and must not set the focus depth.
const float MIN_ALPHA = 1.0 / 1024.0;
