// What a bricked still frame keeps per ray between its passes (passes/paging.rs, render/bricked.rs),
// shared by raycast.comp, which writes it, and ray_wake.comp, which reads it.
struct RayState {
    vec4 fp;
    vec4 fd;
    vec4 ctx;
    vec4 walk;   // depth, m (the next sample), prev_t, prev_s
    // x: bit 0 started, bit 1 done, bit 2 no focus sample yet; y: the page-table entry a stopped
    // ray waits for + 1 (0: none), bit 31 whether that brick's range was known then.
    uvec4 flags;
};

// Words of the page table's header (bound as uniforms), and per entry (a storage buffer of the
// entries alone).
const int PT_HEADER = 8 + 8 * 16;
const int PT_ENTRY_WORDS = 2;
// An entry's first word: RESIDENT, with the brick's slot along x, y and z of the pool in bits
// 0-7, 8-15 and 16-23; KNOWN: the brick's range is known, and bits 24 and 25 say whether it may
// hold visible context (or one-pass) samples and focus; not RESIDENT, bits 28-31 may name the
// level of a resident coarser brick that holds the whole brick. Its second word, read when
// KNOWN: the same per sub-block of the brick's 2 x 2 x 2, bit i visible and bit 8 + i focus for
// sub-block qx + 2 qy + 4 qz.
const uint KNOWN = 0x4000000u;
const uint RESIDENT = 0x8000000u;
// A missing brick's word from this bit on: the level of its holder (passes/paging.rs HELD_SHIFT).
const uint HELD_SHIFT = 28u;

// What a ray that stops at entry `entry` (page-table word `word`) keeps in flags.y.
uint awaits_of(uint entry, uint word) {
    return (entry + 1u) | (word & KNOWN) << 5u;
}

// The entry a stopped ray waits for (flags.y = `awaits`, not 0).
uint awaited_entry(uint awaits) {
    return (awaits & 0x7fffffffu) - 1u;
}

// Whether a ray that stopped with flags.y = `awaits` would stop there again, its brick's word
// now `word`: still missing, and its range as known or unknown as then (within a frame a known
// range's flags do not change), so its walk would end at the same place with the same state.
bool waits_still(uint awaits, uint word) {
    return (word & RESIDENT) == 0u && (word & KNOWN) << 5u == (awaits & 0x80000000u);
}
