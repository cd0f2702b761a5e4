#version 460
// Runs the modulation functions of classify.glsl on a list of inputs, for tests/modulation.rs to
// compare with the CPU reference (src/classify/modulation.rs). Not used by any renderer.
#include "classify.glsl"

layout(local_size_x = 64) in;

struct ProbeIn {
    vec4 rgb_delta;   // colour, ΔD
    vec4 a_n_r;       // opacity A, n, r (for the stipple rule), unused
    vec4 voxel;       // continuous voxel coordinates (for stipple_random), unused
};

struct ProbeOut {
    vec4 raw;         // eq. 3 colour, unused
    vec4 absolute;    // eq. 4 colour, unused
    vec4 rest;        // eq. 5 opacity, eq. 6 white (1) or black (0), stipple_random, unused
};

layout(set = 0, binding = 0) readonly buffer Inputs { ProbeIn inputs[]; };
layout(set = 0, binding = 1) writeonly buffer Outputs { ProbeOut outputs[]; };

layout(push_constant) uniform Push {
    vec4 opacity;     // t_l, t_h, k_l, k_h
    vec4 params;      // gamma, stipple t, stipple f, count
    uvec4 seed;
} pc;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= uint(pc.params.w)) {
        return;
    }
    ProbeIn p = inputs[i];
    ProbeOut o;
    o.raw = vec4(modulate_color(p.rgb_delta.rgb, p.rgb_delta.w, 1, pc.params.x), 0.0);
    o.absolute = vec4(modulate_color(p.rgb_delta.rgb, p.rgb_delta.w, 2, pc.params.x), 0.0);
    o.rest = vec4(
        modulate_opacity(p.a_n_r.x, p.a_n_r.y, pc.opacity),
        stipple_is_white(p.a_n_r.y, p.a_n_r.z, pc.params.y, pc.params.z) ? 1.0 : 0.0,
        stipple_random(p.voxel.xyz, pc.seed.x),
        0.0);
    outputs[i] = o;
}
