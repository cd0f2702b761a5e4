// The visibility mapping M(s) of SPEC OS2 on normalised intensity s in [0, 1].
layout(set = 0, binding = 3) readonly buffer TransferOpacity { float tf_alpha[256]; };

float visibility(float s, OcclusionPush pc) {
    if (pc.mapping == 1) {
        return clamp((s - pc.t0) / max(pc.t1 - pc.t0, 1e-6), 0.0, 1.0);
    }
    if (pc.mapping == 2) {
        return tf_alpha[clamp(int(floor(s * 255.0 + 0.5)), 0, 255)]; // the nearest knot i / 255
    }
    return clamp(s, 0.0, 1.0);
}
