#version 460
// Before a resumed pass of a bricked frame that waits (passes/paging.rs): which tiles of 8 x 8
// rays have a ray with something to do, listed for the ray caster's indirect dispatch. A ray
// that finished, or that stopped at a brick still missing (its range as known or unknown as
// then), would stop again with the same state: it only asks for that brick again, as its walk
// would. Every other ray that stopped wakes its tile, which is listed once. On a CPU device a
// dispatch of the ray caster costs about the same per ray whatever the ray then does, so a pass
// that a few bricks let go on costs those rays' tiles, not the whole image.
layout(local_size_x = 64) in;

// raycast.comp's RayState: flags.x bit 0 started, bit 1 done; flags.y the page-table entry the
// ray waits for + 1 (0: none), bit 31 whether that brick's range was known.
struct RayState {
    vec4 fp;
    vec4 fd;
    vec4 ctx;
    vec4 walk;
    uvec4 flags;
};
layout(set = 0, binding = 0) readonly buffer PageTable { uint pt[]; };
layout(set = 0, binding = 1) buffer Feedback { uint wanted[]; };
layout(set = 0, binding = 2) readonly buffer RayStates { RayState rays[]; };
// The indirect dispatch (x: tiles listed, y = z = 1), then per tile whether it is listed, then
// the list.
layout(set = 0, binding = 3) buffer Tiles { uint args[4]; uint tile_words[]; };

// x, y: the image's size; z: tiles along x; w: tiles.
layout(push_constant) uniform Push { uvec4 size; } p;

const int PT_HEADER = 8 + 8 * 16;
const uint KNOWN = 0x4000000u;
const uint RESIDENT = 0x8000000u;

void main() {
    uint ray = gl_GlobalInvocationID.x;
    if (ray >= p.size.x * p.size.y) {
        return;
    }
    uvec4 f = rays[ray].flags;
    if ((f.x & 2u) != 0u || (f.x & 1u) == 0u) {
        return;
    }
    if (f.y != 0u) {
        uint entry = (f.y & 0x7fffffffu) - 1u;
        uint word = pt[PT_HEADER + int(entry)];
        if ((word & RESIDENT) == 0u && (word & KNOWN) << 5u == (f.y & 0x80000000u)) {
            wanted[entry] = 1u;
            return;
        }
    }
    uvec2 px = uvec2(ray % p.size.x, ray / p.size.x);
    uint tile = (px.y / 8u) * p.size.z + px.x / 8u;
    if (atomicExchange(tile_words[tile], 1u) == 0u) {
        tile_words[p.size.w + atomicAdd(args[0], 1u)] = tile;
    }
}
