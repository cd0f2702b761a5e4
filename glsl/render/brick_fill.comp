#version 460
// The brick cache's uploads (issue 39): each brick arrives as its slot's texels and one more voxel
// on every side (36³, x fastest), normalised to 16 bits or as 8-bit voxels with the table that
// normalises them, and this pass writes the slot's intensity and its Sobel gradients into the
// pools. The gradient is sobel_normals.comp's: a texel outside the level takes the gradient of the
// edge voxel it repeats, and neighbours clamp at the level's borders, so a slot holds exactly what
// the in-core textures hold there. One workgroup row per brick (y), 64 of the slot's 34 x 34
// columns per workgroup (x): an invocation writes a column of texels along z, reading each slice's
// 3 x 3 once for three sums that neighbouring slices combine, as sobel_normals.comp does (9
// fetches a texel, not 27; the sums are the same).
#include "render.glsl"

layout(local_size_x = 64) in;

layout(set = 0, binding = 0) readonly buffer Voxels { uint words[]; };
layout(set = 0, binding = 1) readonly buffer Fills {
    uint table[128];     // 8-bit voxels: the normalised value of each, two per word
    BrickFill fills[];
};
layout(set = 0, binding = 2, r16) uniform writeonly image3D intensity;
layout(set = 0, binding = 3, rgba16f) uniform writeonly image3D gradient;

layout(push_constant) uniform Push { FillPush pc; };
// 8-bit voxels with their table, or 16-bit ones: the pyramid's pipeline says which
// (passes/paging.rs), not a test per fetch, whose both sides a CPU device runs.
layout(constant_id = 0) const bool EIGHT_BIT = false;

const int UPLOAD = 36;
const int SLOT = 34;

// The normalised value of upload voxel `l` of the brick whose voxels start at `first`.
float voxel(int first, ivec3 l) {
    uint i = uint(first + l.x + UPLOAD * (l.y + UPLOAD * l.z));
    uint v;
    if (EIGHT_BIT) {
        uint b = (words[i >> 2u] >> (8u * (i & 3u))) & 0xffu;
        v = (table[b >> 1u] >> (16u * (b & 1u))) & 0xffffu;
    } else {
        v = (words[i >> 1u] >> (16u * (i & 1u))) & 0xffffu;
    }
    return float(v) / 65535.0;
}

// Over level slice z (clamped) around the column's voxel cxy (clamped): x, the x difference
// smoothed (1, 2, 1) along y; y, the y difference smoothed along x; z, the plane smoothed along
// both.
vec3 plane_sums(int first, ivec3 lo, ivec3 dims, ivec2 cxy, int z) {
    vec3 s = vec3(0.0);
    for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
            ivec2 q = clamp(cxy + ivec2(dx, dy), ivec2(0), dims.xy - 1);
            float v = voxel(first, ivec3(q, z) - lo);
            float wx = 2.0 - abs(float(dx));
            float wy = 2.0 - abs(float(dy));
            s += v * vec3(float(dx) * wy, float(dy) * wx, wx * wy);
        }
    }
    return s;
}

void main() {
    int column = int(gl_GlobalInvocationID.x);
    int brick = int(gl_WorkGroupID.y);
    if (column >= SLOT * SLOT || brick >= pc.grid.w) {
        return;
    }
    BrickFill f = fills[brick];
    ivec2 sxy = ivec2(column % SLOT, column / SLOT);
    ivec3 lo = f.lo_slot.xyz;
    ivec3 dims = f.dims_offset.xyz;
    int first = f.dims_offset.w;
    int slot = f.lo_slot.w;
    ivec3 origin = ivec3(slot % pc.grid.x, (slot / pc.grid.x) % pc.grid.y, slot / (pc.grid.x * pc.grid.y)) * SLOT;
    // The column's voxel in the level (a texel outside it takes the edge voxel's gradient).
    ivec2 cxy = clamp(lo.xy + 1 + sxy, ivec2(0), dims.xy - 1);
    vec3 scale = f.inv_spacing.xyz / 32.0;
    // The sums of the slices below, at and above the level slice `held`, made for the first
    // texel's slice before the loop: from one texel to the next the slice advances by one or
    // (clamped past the level) not at all, so the loop makes one slice's sums at most. (A CPU
    // device runs a branch's code, masked, whether a lane takes it or not: a first-slice branch
    // in the loop cost every texel 27 fetches, not 9.)
    int held = clamp(lo.z + 1, 0, dims.z - 1);
    vec3 below = plane_sums(first, lo, dims, cxy, max(held - 1, 0));
    vec3 here = plane_sums(first, lo, dims, cxy, held);
    vec3 above = plane_sums(first, lo, dims, cxy, min(held + 1, dims.z - 1));
    for (int sz = 0; sz < SLOT; ++sz) {
        int cz = clamp(lo.z + 1 + sz, 0, dims.z - 1);
        if (cz != held) {
            below = here;
            here = above;
            above = plane_sums(first, lo, dims, cxy, min(cz + 1, dims.z - 1));
            held = cz;
        }
        vec3 g = vec3(below.xy + 2.0 * here.xy + above.xy, above.z - below.z) * scale;
        ivec3 s = ivec3(sxy, sz);
        imageStore(intensity, origin + s, vec4(voxel(first, s + 1)));
        imageStore(gradient, origin + s, vec4(g, length(g)));
    }
}
