#version 460
// Proxy-slice vertices are world positions on the volume box [-half, half]; the texture coordinate
// maps the box onto [0, 1]^3.
#include "render.glsl"

layout(location = 0) in vec3 position;

layout(set = 0, binding = 0) uniform Uniforms { SliceUniforms u; };

layout(location = 0) out vec3 tex;
layout(location = 1) out vec3 world;

void main() {
    tex = position / (2.0 * u.half_extent.xyz) + 0.5;
    world = position;
    gl_Position = u.view_proj * vec4(position, 1.0);
}
