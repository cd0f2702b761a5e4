// Classification and shading of one slice sample, shared by the one-pass, focus and context
// fragment shaders so that all levels see exactly the same samples.
#include "render.glsl"

layout(set = 0, binding = 0) uniform Uniforms { SliceUniforms u; };
layout(set = 0, binding = 1) uniform sampler3D volume;      // normalised intensity
layout(set = 0, binding = 2) uniform sampler3D gradient;    // xyz gradient (world), w length
layout(set = 0, binding = 3) uniform sampler2D transfer;    // 1D transfer function, 256 x 1
layout(set = 0, binding = 4) uniform sampler3D occlusion;   // ambient occlusion O (OTF only)
layout(set = 0, binding = 5) uniform sampler2D occlusion_tf; // 2D table over (s, O) (OTF only)

layout(location = 0) in vec3 tex;
layout(location = 1) in vec3 world;

bool in_focus(float s) {
    int mode = int(u.focus.z);
    return (mode == 1 && s >= u.focus.x && s <= u.focus.y) || (mode == 2 && s >= u.focus.x);
}

// Samples this transparent contribute nothing and must not set the focus depth.
const float MIN_ALPHA = 1.0 / 1024.0;

// The normalised intensity of this fragment's sample. Shaders classify it first and discard
// before paying for the transfer function, the gradient and the lighting.
float sample_intensity() {
    return texture(volume, tex).r;
}

// Colour (straight) and opacity of intensity s, the opacity corrected for the slice spacing
// (material.w = spacing / voxel). An isosurface focus is opaque.
vec4 classify(float s, bool focus) {
    // focus.w = 1: the occlusion transfer function (SPEC OS4) replaces the 1D one.
    vec4 c = u.focus.w > 0.5 ? texture(occlusion_tf, vec2(s, texture(occlusion, tex).r)) : texture(transfer, vec2(s, 0.5));
    c.a = 1.0 - pow(max(1.0 - c.a, 0.0), u.material.w);
    if (focus && int(u.focus.z) == 2) {
        c.a = 1.0;
    }
    return c;
}

// Phong (with specular) and diffuse-only colours of a sample of straight colour `rgb`.
void shade(vec3 rgb, out vec3 phong, out vec3 diffuse) {
    vec4 g = texture(gradient, tex);
    float ka = u.material.x, kd = u.material.y, ks = u.material.z;
    if (g.w > 1e-4) {
        // The gradient points into denser material; shading is two-sided.
        vec3 n = -g.xyz / g.w;
        vec3 l = u.light.xyz;
        vec3 to_eye = u.view_dir.w > 0.5 ? -u.view_dir.xyz : normalize(u.eye.xyz - world);
        diffuse = rgb * (ka + kd * abs(dot(n, l)));
        phong = diffuse + vec3(ks * pow(abs(dot(n, normalize(l + to_eye))), u.light.w));
    } else {
        diffuse = rgb * (ka + kd);
        phong = diffuse;
    }
}
