#version 460
// The viewer's volume view: the composite layer (premultiplied RGBA) over the background, scaled
// to the window (the composite is smaller while the viewer renders at reduced resolution). At
// full resolution each fragment samples one texel at its centre, so the window shows the values
// `vellum render` writes to its PNG.
layout(set = 0, binding = 0) uniform sampler2D composite_layer;

layout(push_constant) uniform Push {
    vec4 background; // rgb, unused
    vec4 rect;       // x, y, width, height of the view in window pixels
} pc;

layout(location = 0) out vec4 color;

void main() {
    vec2 uv = (gl_FragCoord.xy - pc.rect.xy) / pc.rect.zw;
    vec4 c = texture(composite_layer, uv);
    color = vec4(clamp(c.rgb + (1.0 - clamp(c.a, 0.0, 1.0)) * pc.background.rgb, 0.0, 1.0), 1.0);
}
