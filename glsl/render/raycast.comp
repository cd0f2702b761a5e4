#version 460
// The ray caster (SPEC §6): one invocation per pixel writes the same layers as the slicer's passes
// (focus.phong, focus.diffuse, focus.depth, context, composite; or the one-pass composite).
//
// By default samples lie where the slicer's view-aligned planes cross the ray (depth steps of
// `spacing` along the view direction), so at the same number of planes both renderers sample the
// same points and use the same opacity correction; or they are `spacing` apart along each ray
// (equal world steps, which that correction then fits exactly). A per-pixel jitter moves them.
// Front to back: a focus sample composites into the focus layers and the first one sets the
// depth; a context sample counts only in front of the first focus sample (the slicer's depth
// test). Rays stop once their opacity reaches `ert` (early termination), and sample only the
// stretch between the first and the last brick that holds something under the current
// classification (empty-space skipping, found by a walk over the bricks before the samples)
// without moving any sample.
#define RAYCAST
#include "shade.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(set = 0, binding = 8, rgba32f) uniform writeonly image2D out_phong;
layout(set = 0, binding = 9, rgba32f) uniform writeonly image2D out_diffuse;
layout(set = 0, binding = 10, r32f) uniform writeonly image2D out_depth;
layout(set = 0, binding = 11, rgba32f) uniform writeonly image2D out_context;
layout(set = 0, binding = 12, rgba32f) uniform writeonly image2D out_composite;
// Entries 0..255: per texel i of the 1D transfer function, the larger opacity of texels i and
// i + 1 (float bits), a bound on any opacity that linear filtering can return between them.
// Then per brick: bit 0 = may hold visible context (or one-pass) samples, bit 1 = may hold focus.
layout(set = 0, binding = 13) readonly buffer RayTables { uint ray_tables[]; };
const int BRICKS_AT = 256;

// The brick cache (passes/paging.rs documents the page table's words). Frames of a volume in
// core bind one-word stand-ins and never read them.
layout(set = 0, binding = 14) readonly buffer PageTable { uint pt[]; };
layout(set = 0, binding = 15) buffer Feedback { uint wanted[]; };
// A ray's state between the passes of one frame of a bricked volume that waits for its bricks.
#include "ray_state.glsl"
layout(set = 0, binding = 16) buffer RayStates { RayState rays[]; };
// The page table's header, as uniforms (PT_HEADER words; passes/paging.rs): the lookups read the
// levels' words at every step, and lavapipe loads a storage buffer lane by lane, a loop at every
// load, where it gathers uniforms. The entries are the storage buffer `pt`.
layout(set = 0, binding = 25) uniform PageHeader { uvec4 pt_head[PT_HEADER / 4]; };
// Per ray of a bricked frame that waits and mixes channels by `add` or `max`, eight sums (one per
// channel: `add`'s premultiplied colour and opacity, `max`'s largest value in x), kept between
// its passes as the ray's state is. Other frames bind a stand-in and never read it.
layout(set = 0, binding = 23) buffer ChannelSums { vec4 channel_sums[]; };
// Segments of a label volume (classify/labels.rs): each voxel's index among the ids the volume
// holds, 16 bits, two per word; and per index its colour (RGBA8) and flags (bit 0 drawn, bit 1
// focus, bit 2 keeps the transfer function's colour: id 0, no segment), after a header of the count and whether the segments decide the level (bit 0).
// Frames without labels bind one-word stand-ins and never read them.
layout(set = 0, binding = 17) readonly buffer LabelVoxels { uint label_words[]; };
layout(set = 0, binding = 18) readonly buffer LabelTable { uint label_table[]; };
const uint MODE_WAIT = 1u;
const uint MODE_RESUME = 2u;
// A resumed pass of a bricked frame that waits runs one workgroup per tile of 8 x 8 rays that
// ray_wake.comp listed (after its indirect dispatch's arguments and the tiles' flags): the tiles
// with a ray that a brick let go on. Other frames bind a stand-in and never read it.
layout(set = 0, binding = 24) readonly buffer TileList { uint tile_args[4]; uint tile_words[]; };
// tile_args: the indirect dispatch (tiles along x of the image, rows of listed tiles, 1) and the
// count of tiles listed.
// The entry this ray last asked for, and the last resident one it read, so that it says each
// once per brick.
uint last_wanted = 0xffffffffu;
uint last_used = 0xffffffffu;
const uint USED_BIT = 0x80000000u;
// What locate() found: a place to sample, a missing brick the ray waits for, or a brick that
// holds nothing for the ray, which it walks past up to `skip_t`.
const int FOUND = 0;
const int WAITS = 1;
const int EMPTY = 2;
float skip_t;

layout(push_constant) uniform Push {
    mat4 inv_view_proj;   // clip -> box frame
    vec4 planes;          // x: depth of plane 0 along view_dir (farthest), y: spacing, z: planes, w: ert
    ivec4 bricks;         // brick counts xyz, w: brick size in voxels
    ivec4 flags;          // x: two levels (unread: VARIANT selects the mode), or with mixed
                          // channels the focus channel's component; y: skip empty
                          // bricks, z: jitter seed (0 off), w: bit 0 refine iso hits, bit 1
                          // equal steps along each ray (the last also selected by VARIANT)
} p;

const float INF = 1.0 / 0.0;

// The page table's header, read once per ray (see passes/paging.rs): levels, brick edge in
// voxels, slot edge in texels, mode, slots along x and y of the pool, the coefficients of a
// sample's footprint in voxels (cover = a · distance + b); and the pool's size in texels
// (`pool_size`, `inv_pool`, declared in shade.glsl, whose sobel_at steps by a texel).
int pt_levels;
float pt_brick;
int pt_slot_edge;
uint pt_mode;
float pt_cover_a, pt_cover_b;

// The index of the segment of voxel v (clamped into the volume).
uint label_of(ivec3 v) {
    ivec3 d = ivec3(u.volume_dims.xyz);
    v = clamp(v, ivec3(0), d - 1);
    uint i = uint(v.x) + uint(d.x) * (uint(v.y) + uint(d.y) * uint(v.z));
    uint w = label_words[i >> 1u];
    return (i & 1u) == 0u ? (w & 0xffffu) : (w >> 16u);
}

// Bricked: the index of the segment of pool texel p. The label words then hold each slot's
// indices (passes/paging.rs), slot after slot in the pool's order, the slot's texels x fastest.
uint pool_label(ivec3 p) {
    int edge = pt_slot_edge;
    ivec3 slot = p / edge;
    ivec3 l = p - slot * edge;
    ivec3 grid = ivec3(pool_size) / edge;
    uint s = uint(slot.x + grid.x * (slot.y + grid.y * slot.z));
    uint i = s * uint(edge * edge * edge) + uint(l.x + edge * (l.y + edge * l.z));
    uint w = label_words[i >> 1u];
    return (i & 1u) == 0u ? (w & 0xffffu) : (w >> 16u);
}

// The index of the segment at texture coordinate `at`: the voxel it lies in, never a blend.
// Bricked, the texel of the slot locate() placed the sample in (`ptex`), at the level it reads.
uint label_at(vec3 at) {
    if (V_BRICKED) {
        return pool_label(ivec3(floor(ptex * pool_size)));
    }
    return label_of(ivec3(floor(at * u.volume_dims.xyz)));
}

// Whether a voxel of a hidden segment is among the eight that linear filtering blends at `at`:
// its intensity would show there (a shell where the segment was), so the sample adds nothing.
// Bricked, the eight texels of the slot around `ptex` (its apron holds the brick's neighbours).
bool screened(vec3 at) {
    vec3 cell = V_BRICKED ? ptex * pool_size : at * u.volume_dims.xyz;
    ivec3 c = ivec3(floor(cell - 0.5));
    for (int k = 0; k < 8; k++) {
        ivec3 q = c + ivec3(k & 1, (k >> 1) & 1, k >> 2);
        uint i = V_BRICKED ? pool_label(q) : label_of(q);
        if ((label_table[3u + 2u * i] & 8u) != 0u) {
            return true;
        }
    }
    return false;
}

// Word i of the page table's header.
uint head(int i) {
    return pt_head[i >> 2][i & 3];
}

// Level l's words of the header (from word 8 + 8 l): its first entry, its bricks along x, y, z,
// its texture-to-voxel scale along x, y, z, and level 0's voxel over its own.
uint level_first(int l) {
    return head(8 + 8 * l);
}
ivec3 level_counts(int l) {
    return ivec3(head(9 + 8 * l), head(10 + 8 * l), head(11 + 8 * l));
}
vec3 level_scale(int l) {
    return uintBitsToFloat(uvec3(head(12 + 8 * l), head(13 + 8 * l), head(14 + 8 * l)));
}
float level_voxel_ratio(int l) {
    return uintBitsToFloat(head(15 + 8 * l));
}

void read_header() {
    pt_levels = int(head(0));
    pt_brick = float(head(1));
    pt_slot_edge = int(head(2));
    pt_mode = head(3);
    pt_cover_a = uintBitsToFloat(head(6));
    pt_cover_b = uintBitsToFloat(head(7));
    pool_size = vec3(textureSize(volume, 0));
    inv_pool = 1.0 / pool_size;
}

// The texel of the pool where the brick of page-table word `w` starts (its slot's first two
// texels along each axis are its apron's).
vec3 slot_origin(uint w) {
    uvec3 s = uvec3(w, w >> 8u, w >> 16u) & 0xffu;
    return vec3(s) * float(pt_slot_edge) + 2.0;
}

// A frame that does not wait says which resident bricks it read, so that the cache evicts the
// ones no view uses (the top bit; a missing brick's word says 1). Plain stores, no atomics: every
// ray writes the same value to a word, resident and missing bricks are different words, and a
// CPU device runs an atomic lane by lane.
void mark_used(uint e) {
    if ((pt_mode & MODE_WAIT) == 0u && e != last_used) {
        wanted[e] = USED_BIT;
        last_used = e;
    }
}

// The level the last sample wanted, with its header, and (V_BRICK_REUSE) the brick it read there
// with its place in the pool: a ray takes many samples in a brick, and reuses that lookup while
// the wanted level and the brick stay the same.
int c_level = -1;
ivec3 c_counts;
vec3 c_scale, c_inv_scale;
uint c_first;
float c_ratio;
bool c_hit = false;
ivec3 c_brick;
vec3 c_offset;

// V_BRICK_SPAN: the stretch [c_from, c_until) of the ray parameter over which the last lookup
// holds (the sample stays in its brick and its level stays the one it wanted), and its place in
// the pool as a line in t, so that a sample there costs a compare and a multiply-add. `ray_t` is
// the parameter of the sample `locate` is asked about; the ray's texture coordinates are
// ray_tex0 + t ray_dtex, and its distance from the eye is sqrt(t² + 2 ray_k t + ray_q): ray_k and
// ray_q are dir · (o − eye) and |o − eye|².
float ray_t;
vec3 ray_tex0, ray_dtex, ray_inv_dtex;
float ray_k, ray_q;
float c_from = INF, c_until = -INF;
vec3 c_base, c_step;

// The ray parameter at which the distance from the eye reaches `dist` (the later root), past the
// ray's nearest point to the eye, where that distance only grows.
float t_at_distance(float dist) {
    return -ray_k + sqrt(max(ray_k * ray_k - ray_q + dist * dist, 0.0));
}

// Per level L ≥ 1, the ray parameter from which its samples want level L or coarser: where the
// footprint a·d + b reaches 2^L (the finest level below 2, the coarsest above its floor). Made once
// per ray, so that a sample's level is a few compares and the stretch of a lookup ends exactly
// where the next level begins. (With no distance term the level is the same all along the ray.)
float level_from[16];

void level_thresholds() {
    for (int l = 1; l < pt_levels; ++l) {
        float reach = exp2(float(l));
        if (pt_cover_a > 0.0) {
            float d = (reach - pt_cover_b) / pt_cover_a;
            level_from[l] = d > 0.0 ? t_at_distance(d) : -INF;
        } else {
            level_from[l] = pt_cover_b >= reach ? -INF : INF;
        }
    }
}

// The level the sample at ray parameter t wants.
int level_at(float t) {
    int want = 0;
    for (int l = 1; l < pt_levels; ++l) {
        want += t >= level_from[l] ? 1 : 0;
    }
    return want;
}

// V_LOD_STEPS: the samples that want a level coarser than the one the planes are chosen for
// lie on every `ray_step`-th plane only (plane indices m a multiple of it, from a phase of the
// pixel's), so that each level is sampled as densely, per its voxel, as the planes sample theirs
// (GigaVoxels and the ray-guided renderers widen their steps with the level); the opacity
// correction takes the longer step (locate's `level_ratio`). `ray_step` holds for the samples
// before `step_until`, where the next level begins (a ray's levels only grow along it).
float ray_step = 1.0;
float step_until = -INF;
// Which of its step's planes a pixel's coarse samples take, a fraction in [0, 1) drawn per
// pixel: neighbouring rays sample different planes (interleaved sampling), so the coarser
// spacing shows as fine noise instead of rings across a surface.
float step_phase;
// A sample that a coarser level stands in for (its brick missing) is that level's voxel long, as
// the samples that want that level are: the walk goes on from `m_next` (see widen_step), so a
// view's first frames, drawn mostly from the coarsest level, take as many samples as that
// level's voxels are worth, not as many as the finest level's. The planes are at ray parameter
// plane_a + plane_b m. Only frames drawn around missing bricks take it (V_WIDEN): a CPU device
// runs every branch of a sample's code, masked, whether a lane takes it or not, and the one
// compare at each step cost complete frames 5 % on lavapipe.
float m_next = -INF;
float plane_a, plane_b;

// A level's voxel over level 0's, as a power of two's exponent (a margin keeps an exact power of
// two from rounding down; a level coarser along some axes only counts as level 0's voxel).
float voxel_exponent(int level) {
    return floor(log2(1.0 / level_voxel_ratio(level)) + 0.05);
}

// The planes between the samples of level `level`: its voxel over the voxel of the level the
// frame's planes are chosen for (bits 8-11 of the mode word, the finest level the frame reads),
// at least one. Powers of two, so that the samples of the levels along a ray share planes.
float steps_of(int level) {
    int planes = int((pt_mode >> 8u) & 0xfu);
    return exp2(max(voxel_exponent(level) - voxel_exponent(min(planes, pt_levels - 1)), 0.0));
}

// Where the walk goes on after the sample at ray_t, on a plane, read from level `level` in place
// of the wanted one: that level's step on (a multiple of the wanted level's), or where the walk
// did not come to this sample by such a step, a part of it drawn per pixel, so that neighbouring
// rays entering a missing brick together take their coarse samples on different planes. The
// sample's opacity is corrected for the planes to there.
void widen_step(int level) {
    float m = round((ray_t - plane_a) / plane_b);
    float k = max(steps_of(level) / ray_step, 1.0);
    float gap = (m == m_next ? k : 1.0 + floor(step_phase * k)) * ray_step;
    level_ratio = c_ratio * gap;
    m_next = m + gap;
}

// Plane m, or the first plane after it that lies on a step of `step` planes from `phase`.
float on_step(float m, float step, float phase) {
    return step > 1.0 ? ceil((m - phase) / step) * step + phase : m;
}

// V_LOD_STEPS: plane m, or the next plane after it of the step of the level its sample wants
// (`ray_step`, made again where the next level begins, `step_until`: a ray's levels only grow
// along it), from the pixel's phase.
float on_level_step(float m, float a, float b) {
    float t = a + b * m;
    if (t >= step_until) {
        int want = level_at(t);
        ray_step = steps_of(want);
        step_until = want + 1 < pt_levels ? level_from[want + 1] : INF;
    }
    return on_step(m, ray_step, floor(step_phase * ray_step));
}

// The stretch [from, until) of the ray parameter over which the samples stay in sub-block q of
// brick b of level `want` (whose texture coordinates scale to its voxels by c_scale) and keep
// wanting that level; with `whole`, in the brick (q unread).
vec2 lookup_span(int want, ivec3 b, ivec3 q, bool whole) {
    float from = want > 0 ? level_from[want] : -INF;
    float until = want + 1 < pt_levels ? level_from[want + 1] : INF;
    // The brick: the slab of voxels [32 b, 32 (b + 1)) on each axis, or its sub-block's half
    // [32 b + 16 q, 32 b + 16 (q + 1)), open outwards at the volume's faces, where the lookup
    // clamps.
    vec3 v0 = ray_tex0 * c_scale, inv_dv = ray_inv_dtex * c_inv_scale;
    float h = 0.5 * pt_brick;
    ivec3 q0 = whole ? ivec3(0) : q, q1 = whole ? ivec3(1) : q;
    vec3 lo = mix(vec3(b) * pt_brick + vec3(q0) * h, vec3(-1e30), equal(2 * b + q0, ivec3(0)));
    vec3 hi = mix(vec3(b) * pt_brick + vec3(q1 + 1) * h, vec3(1e30), equal(2 * b + q1, 2 * c_counts - 1));
    vec3 ta = (lo - v0) * inv_dv, tb = (hi - v0) * inv_dv;
    // An axis the ray does not move along bounds nothing.
    bvec3 moves = notEqual(ray_dtex, vec3(0.0));
    vec3 enter = mix(vec3(-INF), min(ta, tb), moves), leave = mix(vec3(INF), max(ta, tb), moves);
    from = max(from, max(max(enter.x, enter.y), enter.z));
    until = min(until, min(min(leave.x, leave.y), leave.z));
    return vec2(from, until);
}

// Sets where the stretch of the lookup just made reads the pool: its brick placed at `offset`.
void set_base(vec3 offset) {
    c_base = (offset + ray_tex0 * c_scale) / pool_size;
    c_step = ray_dtex * c_scale / pool_size;
}

// The header of level `want` into the c_ cache, when it is not the level cached.
void load_level(int want) {
    if (want != c_level) {
        c_level = want;
        c_first = level_first(want);
        c_counts = level_counts(want);
        c_scale = level_scale(want);
        c_inv_scale = 1.0 / c_scale;
        c_ratio = level_voxel_ratio(want);
        c_hit = false;
    }
}

// The page-table entry of the brick of level `want` (its header cached) that holds the sample at
// `tex`: the brick's place b in the level's grid and the sample's place v in the level's voxels.
uint brick_at(int want, out vec3 v, out ivec3 b) {
    load_level(want);
    v = clamp(tex, 0.0, 1.0) * c_scale;
    // (The brick edge is a power of two: its reciprocal is exact.)
    b = clamp(ivec3(floor(v * (1.0 / pt_brick))), ivec3(0), c_counts - 1);
    return c_first + uint(b.x + c_counts.x * (b.y + c_counts.y * b.z));
}

// Whether brick b of level `want` (entry e, whose first word is `word`; the sample at v in that
// level's voxels) is known to hold nothing the ray needs (`skip`'s flags) where the sample is:
// the whole brick, or the sub-block q the sample is in. Then `skip_t` is the end of that
// stretch. Else `whole` says whether the brick holds what the ray needs throughout, and q is the
// sample's sub-block where it does not.
bool empty_flags(uint skip, int want, ivec3 b, vec3 v, uint e, uint word, out bool whole, out ivec3 q) {
    whole = true;
    q = ivec3(0);
    if ((word & KNOWN) == 0u) {
        return false;
    }
    bool empty = ((word >> 24u) & skip) == 0u;
    if (!empty) {
        // The sub-blocks that may hold what the ray needs (bit i for sub-block i).
        uint subs = pt[PT_ENTRY_WORDS * int(e) + 1];
        uint needed = ((skip & 1u) != 0u ? subs : 0u) | ((skip & 2u) != 0u ? subs >> 8u : 0u);
        if ((needed & 0xffu) != 0xffu) {
            whole = false;
            q = ivec3(greaterThanEqual(v, (vec3(b) + 0.5) * pt_brick));
            empty = ((needed >> uint(q.x + 2 * q.y + 4 * q.z)) & 1u) == 0u;
        }
    }
    return empty;
}

// empty_flags(), and for an empty stretch its end in `skip_t`.
bool empty_here(uint skip, int want, ivec3 b, vec3 v, uint e, uint word, out bool whole, out ivec3 q) {
    bool empty = empty_flags(skip, want, b, v, e, word, whole, q);
    if (empty) {
        // (One lookup for both: lavapipe runs the code of each, masked, at every step.)
        skip_t = lookup_span(want, b, q, whole).y;
    }
    return empty;
}

// V_TRIM: the plane m from which the walk goes on as it would have from plane m0, having stepped
// past the stretches in front of the ray that locate() finds EMPTY (known to hold nothing it
// needs, `need`'s flags): the same steps to the same planes, but in a loop that only looks them
// up. In the walk each such step carries the sampling code too, which a CPU device runs, masked,
// for every lane while any lane walks (the in-core walk trims the same way, in occupied_span).
// It stays within the level that the sample at m0 wants: with V_LOD_STEPS the walk's planes
// follow each level's step, and a step that ends in the next level's stretch is the walk's to
// take, from the plane where it began. `passed`: whether it stepped past any stretch.
float past_empty(float a, float b, float m0, float m_last, vec3 o, vec3 dir, float t_in, float t_out, uint need, out bool passed) {
    passed = false;
    int want = level_at(a + b * m0);
    float until = want + 1 < pt_levels ? level_from[want + 1] : INF;
    float step = V_LOD_STEPS ? steps_of(want) : 1.0;
    float phase = floor(step_phase * step);
    float m = m0;
    for (; m <= m_last;) {
        if (a + b * m >= until) {
            break;
        }
        // The plane the walk samples from m (on_level_step, at the same level).
        float at = on_step(m, step, phase);
        float t = a + b * at;
        if (at > m_last || t < t_in || t > t_out || t >= until) {
            break;
        }
        world = o + t * dir;
        tex = world / (2.0 * u.half_extent.xyz) + 0.5;
        ray_t = t;
        vec3 v;
        ivec3 bk, q;
        bool whole;
        uint e = brick_at(want, v, bk);
        if (!empty_here(need, want, bk, v, e, pt[PT_ENTRY_WORDS * int(e)], whole, q)) {
            break;
        }
        // As the walk steps on from an EMPTY sample at `at`.
        m = max(ceil((skip_t - 1e-4 * b - a) / b), at + 1.0);
        passed = true;
    }
    return m;
}

// Sets `ptex` for the sample at `tex` and `world`. In core, the two are the same. Bricked: the
// sample's level is chosen by its projected voxel size. When that level's brick is known to hold
// nothing the ray needs (`skip`: the flags it needs, 0 never to skip), EMPTY, with `skip_t` the end
// of its stretch. When it is resident, its place in the pool. Else the brick is asked for and,
// when the frame waits for bricks, WAITS (the ray stops here); otherwise the finest resident
// coarser level is sampled (the coarsest is always resident).
int locate(uint skip, bool on_plane) {
    if (!V_BRICKED) {
        ptex = tex;
        return FOUND;
    }
    if (V_BRICK_SPAN) {
        if (ray_t >= c_from && ray_t < c_until) {
            ptex = c_base + ray_t * c_step;
            level_ratio = c_ratio * ray_step;
            p_level_dims = c_scale;
            return FOUND;
        }
        // Until a lookup of the wanted level succeeds (set_span), there is no stretch.
        c_from = INF;
    }
    float brick = pt_brick;
    vec3 t = clamp(tex, 0.0, 1.0);
    int want = level_at(ray_t);
    vec3 v;
    ivec3 b;
    uint e = brick_at(want, v, b);
    // (With V_BRICK_SPAN every lookup goes on to set the stretch again.)
    if (V_BRICK_REUSE && !V_BRICK_SPAN && c_hit && b == c_brick) {
        ptex = (c_offset + v) * inv_pool;
        level_ratio = c_ratio * ray_step;
        p_level_dims = c_scale;
        return FOUND;
    }
    c_hit = false;
    uint word = pt[PT_ENTRY_WORDS * int(e)];
    // Whether the brick holds all the ray needs throughout, else the sub-block q the sample is in.
    bool whole = true;
    ivec3 q = ivec3(0);
    bool empty = skip != 0u && empty_flags(skip, want, b, v, e, word, whole, q);
    bool resident = (word & RESIDENT) != 0u;
    if (empty || (V_BRICK_SPAN && resident)) {
        // The stretch of the lookup: where the empty one ends, or the resident brick's (one
        // lookup_span for both: lavapipe runs the code of each, masked, at every step).
        vec2 span = lookup_span(want, b, q, whole);
        skip_t = span.y;
        c_from = empty ? INF : span.x;
        c_until = span.y;
    }
    if (empty) {
        return EMPTY;
    }
    if (resident) {
        mark_used(e);
        vec3 offset = slot_origin(word) - vec3(b) * brick;
        ptex = (offset + v) * inv_pool;
        level_ratio = c_ratio * ray_step;
        p_level_dims = c_scale;
        // A brick with a sub-block to walk past is looked up again at each sample (or, with
        // V_BRICK_SPAN, holds over its sub-block only), so that the ray meets that sub-block.
        c_hit = whole;
        c_brick = b;
        c_offset = offset;
        if (V_BRICK_SPAN) {
            set_base(offset);
        }
        return FOUND;
    }
    if (e != last_wanted) {
        wanted[e] = 1u;
        last_wanted = e;
    }
    if ((pt_mode & MODE_WAIT) != 0u) {
        return WAITS;
    }
    // The finest resident coarser level (the coarsest always is), read at the opacity of the
    // level wanted: it stands in for that level, so a ray through it stops about where it will
    // once the brick is in. (At the coarser level's own opacity the medium was 2^k times
    // thinner, rays went on deeper, and a view's first frames took 1.4-1.8 times as long.) The
    // host names that level in the missing brick's word (from bit HELD_SHIFT) where one brick
    // of it holds the whole missing brick, as each level of a pyramid that halves exactly holds
    // the finer one: the walk over the levels starts there and ends at its first step. (One straight lookup in the loop's place made every frame 5 %
    // slower on lavapipe, even frames with nothing missing.)
    uint held = word >> HELD_SHIFT;
    for (int l = held != 0u ? int(held) : want + 1; l < pt_levels; ++l) {
        ivec3 counts = level_counts(l);
        vec3 scale = level_scale(l);
        vec3 vl = t * scale;
        ivec3 bl = clamp(ivec3(floor(vl * (1.0 / brick))), ivec3(0), counts - 1);
        uint el = level_first(l) + uint(bl.x + counts.x * (bl.y + counts.y * bl.z));
        uint wl = pt[PT_ENTRY_WORDS * int(el)];
        if ((wl & RESIDENT) != 0u) {
            mark_used(el);
            ptex = (slot_origin(wl) - vec3(bl) * brick + vl) * inv_pool;
            level_ratio = c_ratio * ray_step;
            p_level_dims = scale;
            if (V_LOD_STEPS && V_WIDEN && on_plane) {
                widen_step(l);
            }
            return FOUND;
        }
    }
    return WAITS;
}

// The brick of box-frame texture coordinate t (clamped into the volume).
ivec3 brick_of(vec3 t) {
    ivec3 v = clamp(ivec3(floor(t * u.volume_dims.xyz)), ivec3(0), ivec3(u.volume_dims.xyz) - 1);
    return v / p.bricks.w;
}

// Ray parameters where the ray enters and leaves brick b (slab entry and exit).
vec2 brick_slabs(ivec3 b, vec3 o, vec3 dir) {
    vec3 lo = vec3(b * p.bricks.w) / u.volume_dims.xyz;
    vec3 hi = min(vec3((b + 1) * p.bricks.w) / u.volume_dims.xyz, vec3(1.0));
    vec3 wlo = (lo - 0.5) * 2.0 * u.half_extent.xyz;
    vec3 whi = (hi - 0.5) * 2.0 * u.half_extent.xyz;
    vec3 inv = 1.0 / dir;
    vec3 t1 = (wlo - o) * inv;
    vec3 t2 = (whi - o) * inv;
    vec3 tmin = min(t1, t2), tmax = max(t1, t2);
    return vec2(max(max(tmin.x, tmin.y), tmin.z), min(min(tmax.x, tmax.y), tmax.z));
}

bool brick_needed(ivec3 bk, uint need) {
    return (ray_tables[BRICKS_AT + bk.x + p.bricks.x * (bk.y + p.bricks.y * bk.z)] & need) != 0u;
}

// The stretch [first, last] of the ray, within [t0, t1], over bricks that hold something it
// needs (flags & need): the walk before the samples, one lookup per brick crossed, so that the
// sample loop carries no test of its own (a test there cost more than skipping saved wherever
// little is empty: issue 43). (INF, -INF) when no brick does. Empty bricks between occupied
// ones are sampled: their samples add nothing, as without skipping. Two walks: from the front
// to the first brick it needs, and from the back to the last, so a ray through a volume that is
// full inside pays for the empty bricks at its two ends only (walking the whole ray cost more
// than the trim saved on the engine and the phantom, on an H200).
vec2 occupied_span(vec3 o, vec3 dir, float t0, float t1, uint need, float hair) {
    int steps = p.bricks.x + p.bricks.y + p.bricks.z + 3;
    // From the front: the first brick the ray needs, [first, first_exit].
    float first = INF, first_exit = INF;
    float t = t0;
    for (int i = 0; i < steps && t < t1; i++) {
        ivec3 bk = brick_of((o + t * dir) / (2.0 * u.half_extent.xyz) + 0.5);
        float te = brick_slabs(bk, o, dir).y;
        // A ray along a face, or rounding, can put the exit at t: step on by a hair.
        te = te > t ? te : t + hair;
        if (brick_needed(bk, need)) {
            first = t;
            first_exit = te;
            break;
        }
        t = te + hair;
    }
    if (first == INF) {
        // A walk cut short by its step count leaves the rest of the ray to the samples.
        return t < t1 ? vec2(t, t1) : vec2(INF, -INF);
    }
    // From the back: the last brick the ray needs, up to the first one.
    float s = t1;
    for (int i = 0; i < steps && s > first_exit; i++) {
        ivec3 bk = brick_of((o + s * dir) / (2.0 * u.half_extent.xyz) + 0.5);
        vec2 slab = brick_slabs(bk, o, dir);
        if (brick_needed(bk, need)) {
            // To the brick's exit, as the walk from the front would have gone.
            return vec2(first, max(slab.y, s));
        }
        s = (slab.x < s ? slab.x : s - hair) - hair;
    }
    // Back at the first brick: it is the only one; cut short: the rest of the ray stays.
    return vec2(first, s > first_exit ? t1 : first_exit);
}

// `add` and `max` mixing, one level and unlit. `add`: each channel composited front to back on
// its own (emission and absorption, the fluorescence look: no channel hides another), and the
// channels' results added. `max`: each channel's largest value over the ray's samples,
// classified by its transfer function, and the channels' colours added. Bricked, each sample is
// looked up in the page table; a pass that waits stops the ray at a missing brick (`stopped`,
// with m that sample's) and keeps its sums in `channel_sums`, from which a later pass of the
// frame (`resumed`) goes on.
vec4 channel_projection(vec3 o, vec3 dir, float a, float b, inout float m, float m_last, float t_in, float t_out, uint ray, bool resumed, out bool stopped) {
    stopped = false;
    int n = CHANNEL_COUNT;
    float most[MAX_CHANNELS];
    vec4 acc[MAX_CHANNELS];
    uint kept = ray * uint(MAX_CHANNELS);
    for (int k = 0; k < MAX_CHANNELS; k++) {
        vec4 v = V_BRICKED && resumed && k < n ? channel_sums[kept + uint(k)] : vec4(0.0);
        most[k] = v.x;
        acc[k] = v;
    }
    float ert = p.planes.w;
    for (; m <= m_last; m += 1.0) {
        float t = a + b * m;
        if (t < t_in || t > t_out) {
            continue;
        }
        world = o + t * dir;
        tex = world / (2.0 * u.half_extent.xyz) + 0.5;
        ray_t = t;
        if (locate(0u, false) != FOUND) {
            stopped = true;
            break;
        }
        fetch_channels(ptex);
        if (V_MIX_MAX) {
            for (int k = 0; k < n; k++) {
                most[k] = max(most[k], channel_value(k));
            }
            continue;
        }
        bool all_opaque = true;
        for (int k = 0; k < n; k++) {
            vec4 c = channel_class(k, channel_value(k));
            float alpha = correct_opacity(c.a, u.material.w * level_ratio);
            acc[k] += (1.0 - acc[k].a) * vec4(c.rgb * alpha, alpha);
            all_opaque = all_opaque && acc[k].a >= ert;
        }
        if (all_opaque) {
            break;
        }
    }
    if (V_BRICKED && stopped) {
        for (int k = 0; k < n; k++) {
            channel_sums[kept + uint(k)] = V_MIX_MAX ? vec4(most[k]) : acc[k];
        }
    }
    vec4 sum = vec4(0.0);
    for (int k = 0; k < n; k++) {
        if (V_MIX_MAX) {
            vec4 c = channel_class(k, most[k]);
            sum += vec4(c.rgb * c.a, c.a);
        } else {
            sum += acc[k];
        }
    }
    float alpha = min(sum.a, 1.0);
    return vec4(min(sum.rgb, vec3(alpha)), alpha);
}

// The bounds table's opacity bound for a sample of value s (the larger of the two transfer-function
// knots linear filtering blends there).
float opacity_bound(float s) {
    return uintBitsToFloat(ray_tables[tf_pair(s)]);
}

// Whether a sample of value s, with opacity bound `bound`, may add to a layer: it counts (one
// pass, focus, or context in front of the first focus sample) and its bound reaches a_min, or it
// is focus on an isosurface.
bool table_may_add(float s, float bound, bool context_counts, bool iso, float a_min) {
    bool focus = sample_in_focus(s);
    bool counts = !V_TWO_LEVEL || focus || context_counts;
    return counts && (bound >= a_min || (focus && iso));
}

// The walk to the next sample that may add to a layer, four samples at a time, for a ray in core
// whose samples the bounds table decides. A sample waits for its fetch and then for its table
// read before the next one is fetched; on a GPU a lone ray is that chain of latencies, and a
// small frame (too few rays to hide them) lasts as long as its longest ray's chain, whatever its
// pixel count (issue 43). Here, after two samples one at a time, four fetches are in flight
// together, then their four table reads. It advances m past those samples and whole batches in
// which no sample may add, updating the previous sample as the walk one at a time would, and
// stops at the first sample that may: there m is that sample's, `s` its value, and true is
// returned. The samples and the image are unchanged.
bool walk_batch(vec3 o, vec3 dir, float a, float b, float t_in, float t_out, inout float m,
                float m_last, bool context_counts, bool iso, float a_min, inout float prev_t,
                inout float prev_s, out float s) {
    s = 0.0;
    // Two samples one at a time first: in a stretch where every sample adds (after a hit, in a
    // translucent volume), a batch's other three fetches would be wasted, and at 1024² those
    // cost more than the latency they hide (measured on an H200: the engine's one pass 0.77 ms
    // batched from the first sample, 0.56 one at a time).
    for (int k = 0; k < 2 && m <= m_last; k++, m += 1.0) {
        float t = a + b * m;
        vec3 at = (o + t * dir) / (2.0 * u.half_extent.xyz) + 0.5;
        s = textureLod(volume, at, 0.0).r;
        if (t < t_in || t > t_out) {
            continue;
        }
        if (table_may_add(s, opacity_bound(s), context_counts, iso, a_min)) {
            return true;
        }
        prev_t = t;
        prev_s = s;
    }
    for (; m + 3.0 <= m_last; m += 4.0) {
        vec4 t4 = a + b * (m + vec4(0.0, 1.0, 2.0, 3.0));
        vec4 s4;
        for (int j = 0; j < 4; j++) {
            vec3 at = (o + t4[j] * dir) / (2.0 * u.half_extent.xyz) + 0.5;
            s4[j] = textureLod(volume, at, 0.0).r;
        }
        vec4 bound;
        for (int j = 0; j < 4; j++) {
            bound[j] = opacity_bound(s4[j]);
        }
        for (int j = 0; j < 4; j++) {
            bool inside = t4[j] >= t_in && t4[j] <= t_out;
            if (inside && table_may_add(s4[j], bound[j], context_counts, iso, a_min)) {
                m += float(j);
                s = s4[j];
                return true;
            }
            if (inside) {
                prev_t = t4[j];
                prev_s = s4[j];
            }
        }
    }
    return false;
}

// Whether a pass that waits resumes the rays of the tiles ray_wake.comp listed.
bool resumes_listed() {
    return V_BRICKED && (head(3) & (MODE_WAIT | MODE_RESUME)) == (MODE_WAIT | MODE_RESUME);
}

// In a resumed pass that waits, whether ray `ray` of a listed tile has nothing to do: it
// finished in an earlier pass, or it would stop again where it stopped (waits_still;
// ray_wake.comp asked for that brick again).
bool resumed_waiting(uint ray) {
    if (!resumes_listed()) {
        return false;
    }
    uvec4 f = rays[ray].flags;
    if ((f.x & 2u) != 0u) {
        return true;
    }
    return f.y != 0u && waits_still(f.y, pt[PT_ENTRY_WORDS * int(awaited_entry(f.y))]);
}

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = imageSize(out_composite);
    if (resumes_listed()) {
        // One workgroup per listed tile (an indirect dispatch, rows of the image's tiles along x).
        ivec2 tiles = (size + 7) / 8;
        uint listed = gl_WorkGroupID.y * uint(tiles.x) + gl_WorkGroupID.x;
        if (listed >= tile_args[3]) {
            return;
        }
        int tile = int(tile_words[tiles.x * tiles.y + int(listed)]);
        px = ivec2(tile % tiles.x, tile / tiles.x) * 8 + ivec2(gl_LocalInvocationID.xy);
    }
    if (px.x >= size.x || px.y >= size.y) {
        return;
    }
    vec2 ndc = (vec2(px) + 0.5) / vec2(size) * 2.0 - 1.0;
    vec4 a = p.inv_view_proj * vec4(ndc, 0.0, 1.0);
    vec4 b = p.inv_view_proj * vec4(ndc, 1.0, 1.0);
    vec3 o = a.xyz / a.w;
    vec3 dir = normalize(b.xyz / b.w - o);
    vec3 d = u.view_dir.xyz;

    // Box entry and exit.
    vec3 inv = 1.0 / dir;
    vec3 t1 = (-u.half_extent.xyz - o) * inv;
    vec3 t2 = (u.half_extent.xyz - o) * inv;
    vec3 tmin3 = min(t1, t2), tmax3 = max(t1, t2);
    float t_in = max(max(max(tmin3.x, tmin3.y), tmin3.z), 0.0);
    float t_out = min(min(tmax3.x, tmax3.y), tmax3.z);
    // One rank's region of a job: the walk is clipped to its box, a hair wider, and each sample
    // tested against [lo, hi), so that a sample on a shared face counts in exactly one region.
    bool region = u.region_hi.w > 0.5;
    if (region) {
        vec3 r1 = ((u.region_lo.xyz - 0.5) * 2.0 * u.half_extent.xyz - o) * inv;
        vec3 r2 = ((u.region_hi.xyz - 0.5) * 2.0 * u.half_extent.xyz - o) * inv;
        vec3 rmin = min(r1, r2), rmax = max(r1, r2);
        float hair = 1e-3 * p.planes.y;
        t_in = max(t_in, max(max(rmin.x, rmin.y), rmin.z) - hair);
        t_out = min(t_out, min(min(rmax.x, rmax.y), rmax.z) + hair);
    }

    vec4 fp = vec4(0.0), fd = vec4(0.0), ctx = vec4(0.0);
    float depth = INF;
    float cos_t = dot(dir, d);
    // A bricked frame that waits for its bricks runs in passes: each ray goes on from where the
    // last pass stopped it until a brick is missing, and saves its state there. A last pass that
    // no longer waits goes on from the saved states with what is resident.
    uint ray = uint(px.y * size.x + px.x);
    if (V_BRICKED) {
        read_header();
        if (resumed_waiting(ray)) {
            return;
        }
        ray_tex0 = o / (2.0 * u.half_extent.xyz) + 0.5;
        ray_dtex = dir / (2.0 * u.half_extent.xyz);
        ray_inv_dtex = 1.0 / ray_dtex;
        vec3 eo = o - u.eye.xyz;
        ray_k = dot(dir, eo);
        ray_q = dot(eo, eo);
        level_thresholds();
        step_phase = float(pcg3d(uvec3(px, 0x51u)).x >> 8u) / 16777216.0;
    }
    bool wait = V_BRICKED && (pt_mode & MODE_WAIT) != 0u;
    bool stopped = false;
    if (t_out > t_in && cos_t > 0.0) {
        // Samples are t(m) = a + b m for m = m_first, m_first + 1, ... (front to back).
        // Planes: plane k has depth far - (k + 0.5) spacing along d, and depth along the ray is
        // dot(o, d) + t cos_t; with m = -k, a and b follow, and m stays within the planes.
        // Equal steps: spacing along the ray from the box entry.
        float od = dot(o, d);
        float far = p.planes.x, spacing = p.planes.y;
        float jitter = 0.0;
        if (V_JITTER && p.flags.z != 0) {
            jitter = float(pcg3d(uvec3(px, uint(p.flags.z))).x >> 8u) / 16777216.0 - 0.5;
        }
        float a, b, m, m_last;
        if (!V_WORLD_STEPS) {
            a = (far - (0.5 + jitter) * spacing - od) / cos_t;
            b = spacing / cos_t;
            m = max(ceil((t_in - a) / b), 1.0 - p.planes.z);
            m_last = min(floor((t_out - a) / b), 0.0);
        } else {
            a = t_in + (0.5 + jitter) * spacing;
            b = spacing;
            m = 0.0;
            m_last = floor((t_out - a) / b);
        }
        plane_a = a;
        plane_b = b;
        bool first = true;
        float ert = p.planes.w;
        bool skip = V_SKIP_EMPTY && p.flags.y != 0;
        if (skip && !V_BRICKED) {
            // Only the stretch over bricks one pass (or two levels, context or focus) needs is
            // sampled; the samples keep their places, so the image is the one without skipping.
            float hair = 1e-4 * b;
            vec2 span = occupied_span(o, dir, t_in, t_out, V_TWO_LEVEL ? 3u : 1u, hair);
            m = max(m, ceil((span.x - hair - a) / b));
            m_last = min(m_last, floor((span.y + hair - a) / b));
        }
        bool refine_on = V_TWO_LEVEL && V_REFINE_ISO && (p.flags.w & 1) != 0 && int(u.focus.z) == FOCUS_ISO;
        // Without an occlusion TF or opacity modulation, the walk tests a sample's bound from the
        // table instead of classifying it: a raw opacity below a_min stays below MIN_ALPHA after
        // the correction for the spacing (with a margin for rounding). The exact test follows.
        bool iso = int(u.focus.z) == FOCUS_ISO;
        float a_min = 0.99 * (1.0 - pow(1.0 - MIN_ALPHA, 1.0 / u.material.w));
        // The previous sample on the ray, for refining an isosurface hit (t < 0: none).
        float prev_t = -1.0, prev_s = 0.0;
        bool done = false;
        if (V_BRICKED && (pt_mode & MODE_RESUME) != 0u) {
            RayState r = rays[ray];
            fp = r.fp;
            fd = r.fd;
            ctx = r.ctx;
            depth = r.walk.x;
            m = r.walk.y;
            prev_t = r.walk.z;
            prev_s = r.walk.w;
            done = (r.flags.x & 2u) != 0u;
            first = (r.flags.x & 4u) != 0u;
            if (wait && done) {
                // Finished in an earlier pass; its state stands.
                return;
            }
        }
        if ((V_MIX_MAX || V_MIX_ADD) && !done) {
            // A ray that a pass stopped (its state saved, bit 0) goes on from its sums.
            bool resumed = V_BRICKED && (pt_mode & MODE_RESUME) != 0u && (rays[ray].flags.x & 1u) != 0u;
            fp = channel_projection(o, dir, a, b, m, m_last, t_in, t_out, ray, resumed, stopped);
            done = true;
        }
        // Two loops: the inner one walks to the next sample that adds to a layer, paying only for
        // its intensity and class; the outer one shades and composites it. A CPU rasteriser runs
        // a loop body for all its lanes while any is active, so shading in the walk would be paid
        // at every sample of every lane; here it is paid once per contributing sample.
        if (V_TRIM && skip && !done && !region) {
            // Past the empty bricks in front of the ray (a resumed ray: in front of where it
            // stopped), as the walk would step past them.
            bool passed;
            m = past_empty(a, b, m, m_last, o, dir, t_in, t_out, V_TWO_LEVEL ? (first && ctx.a < ert ? 3u : 2u) : 1u, passed);
            prev_t = passed ? -1.0 : prev_t;
        }
        // The walk four samples at a time (in core, the bounds table deciding): see walk_batch.
        bool batch = V_WALK_BATCH && !V_BRICKED && !V_LABELS && !V_CHANNELS && !V_OTF && !V_MOD_OPACITY && !region;
        for (; !done;) {
            float t = 0.0, s = 0.0;
            bool focus = false, hit = false;
            uint label = 0u;
            vec4 c = vec4(0.0);
            // The batch's value of the sample it stopped at, which the walk below then takes
            // instead of fetching it again.
            bool have_s = false;
            if (batch) {
                have_s = walk_batch(o, dir, a, b, t_in, t_out, m, m_last, first && ctx.a < ert, iso, a_min, prev_t, prev_s, s);
            }
            // (After a sample a coarser level stood in for, on from where widen_step says.)
            for (; m <= m_last; m = V_LOD_STEPS && V_WIDEN ? max(m + 1.0, m_next) : m + 1.0) {
                if (V_LOD_STEPS) {
                    // On to the next plane of the step of the level this sample wants.
                    m = on_level_step(m, a, b);
                    if (m > m_last) {
                        break;
                    }
                }
                t = a + b * m;
                if (t < t_in || t > t_out) {
                    have_s = false;
                    continue;
                }
                world = o + t * dir;
                tex = world / (2.0 * u.half_extent.xyz) + 0.5;
                ray_t = t;
                if (region && (any(lessThan(tex, u.region_lo.xyz)) || any(greaterThanEqual(tex, u.region_hi.xyz)))) {
                    prev_t = -1.0;
                    continue;
                }
                // One pass needs visible bricks; two levels need visible context in front of
                // the first focus sample, or focus.
                uint need = V_TWO_LEVEL ? (first && ctx.a < ert ? 3u : 2u) : 1u;
                int found = locate(skip ? need : 0u, true);
                if (found == EMPTY) {
                    // As above, from the end of the brick's stretch.
                    m = max(ceil((skip_t - 1e-4 * b - a) / b), m + 1.0) - 1.0;
                    prev_t = -1.0;
                    continue;
                }
                if (found == WAITS) {
                    stopped = true;
                    break;
                }
                if (V_CHANNELS) {
                    // One fetch for every four channels: the focus channel's component holds
                    // the intensity texture's value.
                    fetch_channels(ptex);
                    s = channel_value(p.flags.x);
                } else if (!have_s) {
                    s = sample_intensity();
                }
                have_s = false;
                focus = sample_in_focus(s);
                if (V_LABELS) {
                    // A hidden segment's samples add nothing; with focus ids, the segment
                    // decides the level.
                    label = label_at(tex);
                    uint flags = label_table[3u + 2u * label];
                    if ((flags & 1u) == 0u || (V_LABELS_SCREEN && screened(tex))) {
                        prev_t = -1.0;
                        continue;
                    }
                    if ((label_table[1] & 1u) != 0u) {
                        focus = (flags & 2u) != 0u;
                    }
                }
                // Behind the first focus sample, only focus samples count (the depth test); nor do
                // context samples behind a context that reached `ert` (early termination).
                bool counts = !V_TWO_LEVEL || focus || (first && ctx.a < ert);
                bool maybe;
                if (V_OTF || V_MOD_OPACITY) {
                    c = classify(s, focus);
                    maybe = c.a >= MIN_ALPHA;
                } else if (V_CHANNELS) {
                    maybe = channels_may_show(a_min) || (focus && iso);
                } else {
                    maybe = opacity_bound(s) >= a_min || (focus && iso);
                }
                if (counts && maybe) {
                    hit = true;
                    break;
                }
                prev_t = t;
                prev_s = s;
            }
            if (stopped || !hit) {
                break;
            }
            // Where to go on from if the refinement below meets a missing brick.
            float m_hit = m, keep_t = prev_t, keep_s = prev_s;
            m = V_LOD_STEPS && V_WIDEN ? max(m + 1.0, m_next) : m + 1.0;
            if (refine_on && focus && first && prev_t >= 0.0 && s > prev_s) {
                // Regula falsi between the previous sample (below the isovalue) and this one.
                float ta = prev_t, sa = prev_s, tb = t, sb = s;
                for (int i = 0; i < 4; i++) {
                    float tm = ta + (u.focus.x - sa) / (sb - sa) * (tb - ta);
                    world = o + tm * dir;
                    tex = world / (2.0 * u.half_extent.xyz) + 0.5;
                    ray_t = tm;
                    if (locate(0u, false) != FOUND) {
                        stopped = true;
                        break;
                    }
                    float sm = sample_intensity();
                    if (sm >= u.focus.x) {
                        tb = tm;
                        sb = sm;
                    } else {
                        ta = tm;
                        sa = sm;
                    }
                }
                t = ta + (u.focus.x - sa) / (sb - sa) * (tb - ta);
                world = o + t * dir;
                tex = world / (2.0 * u.half_extent.xyz) + 0.5;
                ray_t = t;
                stopped = stopped || locate(0u, false) != FOUND;
                if (V_CHANNELS && !stopped) {
                    fetch_channels(ptex);
                }
                if (stopped) {
                    m = m_hit;
                    prev_t = keep_t;
                    prev_s = keep_s;
                    break;
                }
            }
            if (!(V_OTF || V_MOD_OPACITY) || refine_on) {
                // The exact class (at the surface when refined: an occlusion or importance
                // lookup may move it).
                c = classify(s, focus);
            }
            prev_t = t;
            prev_s = s;
            if (c.a < MIN_ALPHA) {
                continue;
            }
            if (V_LABELS && (label_table[3u + 2u * label] & 4u) == 0u) {
                c.rgb = unpackUnorm4x8(label_table[2u + 2u * label]).rgb;
            }
            vec3 ph, di;
            shade(c.rgb, focus, ph, di);
            if (!V_TWO_LEVEL) {
                fp += (1.0 - fp.a) * vec4(ph * c.a, c.a);
                if (fp.a >= ert) {
                    break;
                }
            } else if (focus) {
                fp += (1.0 - fp.a) * vec4(ph * c.a, c.a);
                fd += (1.0 - fd.a) * vec4(di * c.a, c.a);
                if (first) {
                    depth = dot(world - u.eye.xyz, d);
                    first = false;
                }
                if (fp.a >= ert) {
                    break;
                }
            } else {
                ctx += (1.0 - ctx.a) * vec4(ph * c.a, c.a);
                // (Where segments decide the level, the focus behind an opaque context still
                // counts for its own layers.)
                bool segments = V_LABELS && (label_table[1] & 1u) != 0u;
                if (ctx.a >= ert && int(u.focus.z) == FOCUS_NONE && !segments) {
                    break;
                }
            }
        }
        if (wait) {
            uint flags = 1u | (stopped ? 0u : 2u) | (first ? 4u : 0u);
            // A stopped ray keeps the entry it waits for (+ 1; 0: none) and whether that
            // brick's range was known (bit 31), for resumed_waiting.
            uint awaits = stopped ? awaits_of(last_wanted, pt[PT_ENTRY_WORDS * int(last_wanted)]) : 0u;
            rays[ray] = RayState(fp, fd, ctx, vec4(depth, m, prev_t, prev_s), uvec4(flags, awaits, 0u, 0u));
        }
    } else if (wait) {
        // A ray that misses the box is done from the first pass (resumed_waiting reads that).
        rays[ray].flags = uvec4(3u, 0u, 0u, 0u);
    }
    // A pass that waits for bricks keeps its results in the rays' states; only the frame that
    // ends the passes (or draws without waiting) writes the layers.
    if (wait) {
        return;
    }
    if (V_TWO_LEVEL) {
        imageStore(out_phong, px, fp);
        imageStore(out_diffuse, px, fd);
        imageStore(out_depth, px, vec4(depth));
        imageStore(out_context, px, ctx);
        imageStore(out_composite, px, ctx + (1.0 - ctx.a) * fp);
    } else {
        imageStore(out_composite, px, fp);
    }
}
