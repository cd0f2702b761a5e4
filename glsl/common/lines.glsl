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
    uint cell_capacity;          // cells the straddling-cell list (or a frontier) holds
    uint seed_mode;              // seed.comp: 0 the previous segments, 1 the strided scan
    uint pad1;
    uint pad2;
};

// The Hessian of the volume at voxel q by central differences, in physical units (`s` is the
// voxel spacing): (hxx, hyy, hzz, hxy) and (hxz, hyz), the second derivatives the CPU twin
// (volume::lines) takes. Clamped at the border. extract.comp calls it at every cell corner;
// hessian.comp once per voxel, for extract_hessian.comp to read.
#define LINES_AT(D) texelFetch(vol, clamp(q + (D), ivec3(0), dims - 1), 0).r
void hessian_at(sampler3D vol, ivec3 dims, vec3 s, ivec3 q, out vec4 h0, out vec2 h1) {
    float f0 = LINES_AT(ivec3(0));
    float hxx = (LINES_AT(ivec3(1, 0, 0)) - 2.0 * f0 + LINES_AT(ivec3(-1, 0, 0))) / (s.x * s.x);
    float hyy = (LINES_AT(ivec3(0, 1, 0)) - 2.0 * f0 + LINES_AT(ivec3(0, -1, 0))) / (s.y * s.y);
    float hzz = (LINES_AT(ivec3(0, 0, 1)) - 2.0 * f0 + LINES_AT(ivec3(0, 0, -1))) / (s.z * s.z);
    float hxy = (LINES_AT(ivec3(1, 1, 0)) - LINES_AT(ivec3(1, -1, 0)) - LINES_AT(ivec3(-1, 1, 0))
                 + LINES_AT(ivec3(-1, -1, 0))) / (4.0 * s.x * s.y);
    float hxz = (LINES_AT(ivec3(1, 0, 1)) - LINES_AT(ivec3(1, 0, -1)) - LINES_AT(ivec3(-1, 0, 1))
                 + LINES_AT(ivec3(-1, 0, -1))) / (4.0 * s.x * s.z);
    float hyz = (LINES_AT(ivec3(0, 1, 1)) - LINES_AT(ivec3(0, 1, -1)) - LINES_AT(ivec3(0, -1, 1))
                 + LINES_AT(ivec3(0, -1, -1))) / (4.0 * s.y * s.z);
    h0 = vec4(hxx, hyy, hzz, hxy);
    h1 = vec2(hxz, hyz);
}
#undef LINES_AT

// Most workgroups an indirect dispatch of the line passes asks for (the smallest
// maxComputeWorkGroupCount[0] Vulkan allows); the shaders stride over the rest.
#define LINES_MAX_GROUPS 65535u

// Push constants of the line rasteriser (twin: `RasterPush` in src/passes/lines.rs).
struct RasterPush {
    mat4 index_to_clip;   // voxel index -> clip, the renderer's box -> clip after index -> box
    vec4 depth;           // linear depth of index p: dot(p, depth.xyz) + depth.w (box units)
    vec4 params;          // x: depth bias (box units), y: the value a fully covered pixel gets,
                          // z: the value of zero coverage
    uvec4 capacity_size;  // x: capacity; y, z: image size
};

#endif
