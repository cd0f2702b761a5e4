#version 460
// The brick cache's 8-bit uploads (issue 39): each brick arrives as its slot's texels (36³, x
// fastest: the brick and a two-voxel apron) as 8-bit voxels, with the table that normalises them,
// and this pass writes their normalised values into the intensity pool. (16-bit bricks travel as
// the slots hold them and are copied, passes/paging.rs.) The pool holds no gradients: the ray
// caster makes each shaded sample's from the slot (shade.glsl's sobel_at). One workgroup row per
// brick (y), 64 of the slot's texels per workgroup (x).
#include "render.glsl"

layout(local_size_x = 64) in;

layout(set = 0, binding = 0) readonly buffer Voxels { uint words[]; };
layout(set = 0, binding = 1) readonly buffer Fills {
    uint table[128];     // the normalised value of each 8-bit voxel, two per word
    BrickFill fills[];
};
layout(set = 0, binding = 2, r16) uniform writeonly image3D intensity;

layout(push_constant) uniform Push { FillPush pc; };

const int SLOT = 36;

void main() {
    int t = int(gl_GlobalInvocationID.x);
    int brick = int(gl_WorkGroupID.y);
    if (t >= SLOT * SLOT * SLOT || brick >= pc.grid.w) {
        return;
    }
    BrickFill f = fills[brick];
    int slot = f.slot_offset.x;
    uint i = uint(f.slot_offset.y + t);
    uint b = (words[i >> 2u] >> (8u * (i & 3u))) & 0xffu;
    uint v = (table[b >> 1u] >> (16u * (b & 1u))) & 0xffffu;
    ivec3 s = ivec3(t % SLOT, (t / SLOT) % SLOT, t / (SLOT * SLOT));
    ivec3 origin = ivec3(slot % pc.grid.x, (slot / pc.grid.x) % pc.grid.y, slot / (pc.grid.x * pc.grid.y)) * SLOT;
    imageStore(intensity, origin + s, vec4(float(v) / 65535.0));
}
