#version 460
// One segment of a label volume as a field the line extraction reads (issue 42): at each voxel,
// the share of the 3x3x3 voxels around it that hold segment `index`, so that the field's
// iso-surface at 0.5 is the segment's boundary, smoothed over a voxel, and the lines of that
// surface are the segment's silhouettes and suggestive contours. Labels are read as the ray
// caster reads them (16-bit indices, two per word); each frame a segment's lines are made, the
// field is cleared and written over the segment's bounding box and one voxel around it.

layout(local_size_x = 4, local_size_y = 4, local_size_z = 4) in;

layout(set = 0, binding = 0) readonly buffer LabelVoxels { uint label_words[]; };
layout(set = 0, binding = 1, r32f) uniform writeonly image3D field;

layout(push_constant) uniform Push {
    ivec4 dims;   // xyz: voxels; w: the segment's index among the ids the volume holds
    ivec4 lo;     // xyz: the first voxel of the box written (the segment's box and one voxel
                  // more: the field is 0 beyond, where a clear left it)
} pc;

bool in_segment(ivec3 v) {
    uint i = uint(v.x) + uint(pc.dims.x) * (uint(v.y) + uint(pc.dims.y) * uint(v.z));
    uint w = label_words[i >> 1u];
    uint index = (i & 1u) == 0u ? (w & 0xffffu) : (w >> 16u);
    return index == uint(pc.dims.w);
}

void main() {
    ivec3 v = pc.lo.xyz + ivec3(gl_GlobalInvocationID);
    if (any(greaterThanEqual(v, pc.dims.xyz))) {
        return;
    }
    // The share of the 3x3x3 voxels around v (clamped at the volume's faces) in the segment:
    // a box filter, so that the surface at 0.5 is smooth enough for its silhouettes to lie where
    // the ray caster's surface is, not on the stairs of its voxels.
    float inside = 0.0;
    for (int dz = -1; dz <= 1; dz++) {
        for (int dy = -1; dy <= 1; dy++) {
            for (int dx = -1; dx <= 1; dx++) {
                inside += in_segment(clamp(v + ivec3(dx, dy, dz), ivec3(0), pc.dims.xyz - 1)) ? 1.0 : 0.0;
            }
        }
    }
    imageStore(field, v, vec4(inside / 27.0));
}
