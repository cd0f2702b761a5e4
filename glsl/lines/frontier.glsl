// The seeded traversal's frontier (Burns et al.'s seed-and-traverse, on the GPU): a list of cells
// for the next round, in the layout of the straddling-cell list (its header is that round's
// indirect dispatch), and one bit per cell, set when a cell first enters a frontier in this
// frame, so that no cell is visited twice. Define FRONTIER_BINDING and VISITED_BINDING and
// declare `pc` (LinesPush) before including; `pc.cell_capacity` is the frontier's capacity.

layout(set = 0, binding = FRONTIER_BINDING) buffer Frontier {
    uint front_groups;
    uint front_one_y;
    uint front_one_z;
    uint front_count;
    uint front_cells[];
};

layout(set = 0, binding = VISITED_BINDING) buffer Visited {
    uint visited[];
};

// Set on a frontier entry whose cell may not hold the line (a seed, or a step of a walk towards
// it), with the kind it searches for: if the cell holds no line, the walk goes on to a
// neighbour. Cells entered by following a line through a face hold it, and end there if they do
// not. The cell's index is in the low 30 bits.
#define SEARCH_SILHOUETTE 0x80000000u
#define SEARCH_SUGGESTIVE 0x40000000u
#define CELL_BITS 0x3fffffffu

// Appends cell `c` with `flag` unless it is outside the volume or already visited; whether it
// was appended (an entry past the capacity is counted and lost).
bool push_cell(ivec3 c, uint flag) {
    if (any(lessThan(c, ivec3(0))) || any(greaterThanEqual(c, pc.dims - 1))) {
        return false;
    }
    uint k = uint(c.x) + uint(pc.dims.x) * (uint(c.y) + uint(pc.dims.y) * uint(c.z));
    uint bit = 1u << (k & 31u);
    if ((atomicOr(visited[k >> 5u], bit) & bit) != 0u) {
        return false;
    }
    uint i = atomicAdd(front_count, 1u);
    if (i < pc.cell_capacity) {
        if (i % 64u == 0u && i / 64u < LINES_MAX_GROUPS) {
            atomicAdd(front_groups, 1u);
        }
        front_cells[i] = k | flag;
    }
    return true;
}
