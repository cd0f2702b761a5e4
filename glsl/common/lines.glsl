// Shader interface of the line extraction (twin: `LinesPush` in src/passes/lines.rs).
#ifndef VELLUM_LINES_GLSL
#define VELLUM_LINES_GLSL

struct LinesPush {
    ivec3 dims;                  // volume size
    int stride;                  // visit every stride-th cell (1 all, 2 interactive)
    vec3 spacing;                // physical size of a voxel
    float iso;                   // τ on the normalised scale
    vec4 eye;                    // w = 0: unit direction towards the eye; w = 1: eye position (physical)
    int kinds;                   // bit 0 silhouettes, bit 1 suggestive contours
    float cos_c;                 // cos θ_c
    float derivative_threshold;  // t_d
    uint capacity;               // segments the buffer holds
    uint cell_capacity;          // cells the straddling-cell list holds
    uint pad0;
    uint pad1;
    uint pad2;
};

// Most workgroups an indirect dispatch of the line passes asks for (the smallest
// maxComputeWorkGroupCount[0] Vulkan allows); the shaders stride over the rest.
#define LINES_MAX_GROUPS 65535u

// Push constants of the line rasteriser (twin: `RasterPush` in src/passes/lines.rs).
struct RasterPush {
    mat4 index_to_clip;   // voxel index -> clip, the renderer's box -> clip after index -> box
    vec4 depth;           // linear depth of index p: dot(p, depth.xyz) + depth.w (box units)
    vec4 params;          // x: depth bias (box units), y: the value written to edges
    uvec4 capacity_size;  // x: capacity; y, z: image size
};

#endif
