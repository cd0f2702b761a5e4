#version 460
// The brick cache's uploads (issue 39): each brick arrives as its slot's texels and one more voxel
// on every side (36³, x fastest), normalised to 16 bits or as 8-bit voxels with the table that
// normalises them, and this pass writes the slot's intensity and its Sobel gradients into the
// pools. The gradient is sobel_normals.comp's: a texel outside the level takes the gradient of the
// edge voxel it repeats, and neighbours clamp at the level's borders, so a slot holds exactly what
// the in-core textures hold there. One workgroup row per brick (y), 64 texels per workgroup (x).
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

const int UPLOAD = 36;
const int SLOT = 34;

// The normalised value of upload voxel `l` of the brick whose voxels start at `first`.
float voxel(int first, ivec3 l) {
    uint i = uint(first + l.x + UPLOAD * (l.y + UPLOAD * l.z));
    uint v;
    if (pc.grid.z != 0) {
        uint b = (words[i >> 2u] >> (8u * (i & 3u))) & 0xffu;
        v = (table[b >> 1u] >> (16u * (b & 1u))) & 0xffffu;
    } else {
        v = (words[i >> 1u] >> (16u * (i & 1u))) & 0xffffu;
    }
    return float(v) / 65535.0;
}

void main() {
    int t = int(gl_GlobalInvocationID.x);
    int brick = int(gl_WorkGroupID.y);
    if (t >= SLOT * SLOT * SLOT || brick >= pc.grid.w) {
        return;
    }
    BrickFill f = fills[brick];
    ivec3 s = ivec3(t % SLOT, (t / SLOT) % SLOT, t / (SLOT * SLOT));
    ivec3 lo = f.lo_slot.xyz;
    ivec3 dims = f.dims_offset.xyz;
    int first = f.dims_offset.w;
    // The texel's voxel in the level, and the voxel whose gradient it takes.
    ivec3 c = clamp(lo + 1 + s, ivec3(0), dims - 1);
    vec3 g = vec3(0.0);
    for (int dz = -1; dz <= 1; ++dz) {
        for (int dy = -1; dy <= 1; ++dy) {
            for (int dx = -1; dx <= 1; ++dx) {
                ivec3 d = ivec3(dx, dy, dz);
                float v = voxel(first, clamp(c + d, ivec3(0), dims - 1) - lo);
                vec3 w = vec3(2.0) - abs(vec3(d));
                g += v * vec3(d) * vec3(w.y * w.z, w.x * w.z, w.x * w.y);
            }
        }
    }
    g *= f.inv_spacing.xyz / 32.0;
    int slot = f.lo_slot.w;
    ivec3 at = ivec3(slot % pc.grid.x, (slot / pc.grid.x) % pc.grid.y, slot / (pc.grid.x * pc.grid.y)) * SLOT + s;
    imageStore(intensity, at, vec4(voxel(first, s + 1)));
    imageStore(gradient, at, vec4(g, length(g)));
}
