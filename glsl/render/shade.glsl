// The slicer's glue between its bindings and the shared classification and shading functions
// (glsl/common/classify.glsl, shading.glsl): one-pass, focus and context fragment shaders include
// it, so all levels see exactly the same samples.
#include "render.glsl"
#include "classify.glsl"
#include "shading.glsl"

layout(set = 0, binding = 0) uniform Uniforms { SliceUniforms u; };
layout(set = 0, binding = 1) uniform sampler3D volume;      // normalised intensity
layout(set = 0, binding = 2) uniform sampler3D gradient;    // xyz gradient (world), w length
layout(set = 0, binding = 3) uniform sampler2D transfer;    // 1D transfer function, 256 x 1
layout(set = 0, binding = 4) uniform sampler3D occlusion;   // ambient occlusion O (OTF only)
layout(set = 0, binding = 5) uniform sampler2D occlusion_tf; // 2D table over (s, O) (OTF only)

layout(location = 0) in vec3 tex;
layout(location = 1) in vec3 world;

bool sample_in_focus(float s) {
    return in_focus(s, u.focus);
}

// The normalised intensity of this fragment's sample. Shaders classify it first and discard
// before paying for the transfer function, the gradient and the lighting.
float sample_intensity() {
    return texture(volume, tex).r;
}

// Colour (straight) and opacity of intensity s, the opacity corrected for the slice spacing
// (material.w = spacing / voxel). focus.w = 1: the occlusion transfer function replaces the 1D one.
vec4 classify(float s, bool focus) {
    vec4 rgba = u.focus.w > 0.5
        ? texture(occlusion_tf, occlusion_tf_coord(s, texture(occlusion, tex).r))
        : texture(transfer, vec2(s, 0.5));
    return classify_sample(rgba, u.material.w, focus, u.focus);
}

// Phong (with specular) and diffuse-only colours of a sample of straight colour `rgb`, lit by the
// headlight.
void shade(vec3 rgb, out vec3 phong, out vec3 diffuse) {
    vec3 to_eye = u.view_dir.w > 0.5 ? -u.view_dir.xyz : normalize(u.eye.xyz - world);
    shade_phong(rgb, texture(gradient, tex), u.light.xyz, to_eye, u.material, u.light.w, phong, diffuse);
}
