#version 460
// TL3 composite: the context level over the focus level, both premultiplied. The context holds
// only samples in front of the focus (the rest failed the depth test), so "over" is exact.
layout(set = 0, binding = 0) uniform sampler2D focus_layer;
layout(set = 0, binding = 1) uniform sampler2D context_layer;

layout(location = 0) out vec4 color;

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 f = texelFetch(focus_layer, p, 0);
    vec4 c = texelFetch(context_layer, p, 0);
    color = c + (1.0 - c.a) * f;
}
