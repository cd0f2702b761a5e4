// Push constants of the image-space style passes (glsl/post/). Twin of render::post::PostPush; a
// unit test checks the layout.
#ifndef VELLUM_POST_GLSL
#define VELLUM_POST_GLSL

struct PostPush {
    ivec4 size_mode;  // width, height, pass-specific mode (blur axis), pass-specific radius
    vec4 params;      // pass-specific: blur σ; DoG τ, ε, φ; Canny high, low; saturation factor
    vec4 edge;        // composite: edge colour (rgb) and opacity
    ivec4 flags;      // composite: dilation radius, edges present, edge offset; hysteresis: pass index
};

#define POST_LOCAL 16

// Rec. 709 luma of premultiplied colour (imaging::LUMA).
const vec3 LUMA = vec3(0.2126, 0.7152, 0.0722);

// The image bounds a post pass covers.
bool outside(ivec2 p, PostPush pc) {
    return any(greaterThanEqual(p, pc.size_mode.xy));
}

ivec2 clamp_to(ivec2 p, PostPush pc) {
    return clamp(p, ivec2(0), pc.size_mode.xy - 1);
}

#endif
