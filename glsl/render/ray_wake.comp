#version 460
// Before a resumed pass of a bricked frame that waits (passes/paging.rs): which tiles of 8 x 8
// rays have a ray with something to do, listed for the ray caster's indirect dispatch. A ray
// that finished, or that would stop again where it stopped (waits_still), is left: the latter
// only asks for its brick again, as its walk would. Every other ray that stopped lists its tile,
// once. On a CPU device a dispatch of the ray caster costs about the same per ray whatever the
// ray then does, so a pass that a few bricks let go on costs those rays' tiles, not the image.
// One workgroup per tile of the image.
#include "ray_state.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 0) readonly buffer PageTable { uint pt[]; };
layout(set = 0, binding = 1) buffer Feedback { uint wanted[]; };
layout(set = 0, binding = 2) readonly buffer RayStates { RayState rays[]; };
// The indirect dispatch (x: the image's tiles along x, the host's; y: rows of listed tiles; z: 1)
// and the count of tiles listed; then per tile whether it is listed; then the list.
layout(set = 0, binding = 3) buffer Tiles { uint args[4]; uint tile_words[]; };

// x, y: the image's size; z: tiles along x; w: tiles.
layout(push_constant) uniform Push { uvec4 size; } p;

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    if (px.x >= p.size.x || px.y >= p.size.y) {
        return;
    }
    uvec4 f = rays[px.y * p.size.x + px.x].flags;
    if ((f.x & 2u) != 0u || (f.x & 1u) == 0u) {
        return;
    }
    if (f.y != 0u) {
        uint entry = awaited_entry(f.y);
        if (waits_still(f.y, pt[PT_ENTRY_WORDS * int(entry)])) {
            wanted[entry] = 1u;
            return;
        }
    }
    uint tile = gl_WorkGroupID.y * p.size.z + gl_WorkGroupID.x;
    if (atomicExchange(tile_words[tile], 1u) == 0u) {
        uint listed = atomicAdd(args[3], 1u);
        tile_words[p.size.w + listed] = tile;
        atomicMax(args[1], listed / p.size.z + 1u);
    }
}
