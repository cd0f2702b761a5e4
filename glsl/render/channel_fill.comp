#version 460
// The brick cache's mixed channels (issue 42): each brick's channels arrive as its slot's texels
// (36³, x fastest), one channel after another, normalised to 16 bits over each channel's
// range, and this pass writes the slot's texels of channels 0-3 and 4-7 into the two channel
// pools (component k % 4), which the ray caster samples where it samples the intensity pool.
// One workgroup row per brick (y), 64 texels per workgroup (x), as brick_fill.comp.
#include "render.glsl"

layout(local_size_x = 64) in;

layout(set = 0, binding = 0) readonly buffer Voxels { uint words[]; };
layout(set = 0, binding = 1) readonly buffer Fills {
    uint table[128];     // unused here: brick_fill.comp's table of 8-bit values
    BrickFill fills[];
};
layout(set = 0, binding = 2, rgba16) uniform writeonly image3D channels_lo;
layout(set = 0, binding = 3, rgba16) uniform writeonly image3D channels_hi;

// grid.x, grid.y: pool slots along x and y; grid.z: channels; grid.w: bricks in this dispatch.
layout(push_constant) uniform Push { FillPush pc; };

const int SLOT = 36;
const uint BOX = uint(SLOT * SLOT * SLOT);

float value(uint i) {
    return float((words[i >> 1u] >> (16u * (i & 1u))) & 0xffffu) / 65535.0;
}

void main() {
    int t = int(gl_GlobalInvocationID.x);
    int brick = int(gl_WorkGroupID.y);
    if (t >= SLOT * SLOT * SLOT || brick >= pc.grid.w) {
        return;
    }
    int n = pc.grid.z;
    ivec3 s = ivec3(t % SLOT, (t / SLOT) % SLOT, t / (SLOT * SLOT));
    uint at = uint(brick) * uint(n) * BOX + uint(t);
    vec4 lo = vec4(0.0), hi = vec4(0.0);
    for (int k = 0; k < n; k++) {
        float v = value(at + uint(k) * BOX);
        if (k < 4) {
            lo[k] = v;
        } else {
            hi[k - 4] = v;
        }
    }
    int slot = fills[brick].slot_offset.x;
    ivec3 place = ivec3(slot % pc.grid.x, (slot / pc.grid.x) % pc.grid.y, slot / (pc.grid.x * pc.grid.y)) * SLOT + s;
    imageStore(channels_lo, place, lo);
    if (n > 4) {
        imageStore(channels_hi, place, hi);
    }
}
