// Shader interfaces of the renderer. Twins of the #[repr(C)] structs in src/render/ and
// src/passes/normals.rs; unit tests check that the layouts agree. Only vec4/mat4/ivec4 and
// scalar-padded members are used, so std140 and std430 layouts coincide.
#ifndef VELLUM_RENDER_GLSL
#define VELLUM_RENDER_GLSL

struct NormalsPush {
    ivec3 dims;          // volume size in voxels
    int listed;          // bricks in the list sobel_normals.comp runs on, or -1: every voxel
    vec4 inv_spacing;    // 1 / voxel spacing (xyz), w unused
};

// Per-frame uniforms of the slice renderer.
struct SliceUniforms {
    mat4 view_proj;      // world -> clip
    vec4 half_extent;    // xyz: half size of the volume box in world units (box centred at 0); w: one world unit in the volume's units (its longest edge)
    vec4 eye;            // xyz: camera position (world)
    vec4 view_dir;       // xyz: unit direction from the eye into the scene; w: 1 for ortho
    vec4 light;          // xyz: unit direction towards the light (world); w: specular exponent
    vec4 material;       // ambient, diffuse, specular, opacity ratio (slice spacing / voxel)
    vec4 focus;          // lo, hi (normalised intensity), mode (0 none, 1 range, 2 iso), 1 = OTF
    ivec4 mod_flags;     // colour mode (0 off, 1 raw, 2 abs), opacity on, stipple on, levels (1 focus, 2 context, 3 both)
    vec4 mod_color;      // gamma, base colour (0 ambient, 1 phong)
    vec4 mod_opacity;    // t_l, t_h, k_l, k_h (eq. 5)
    vec4 mod_stipple;    // t, f (eq. 6)
    uvec4 mod_seed;      // stipple seed
    vec4 stipple_white;
    vec4 stipple_black;
    vec4 volume_dims;    // voxels along x, y, z
    vec4 region_lo;      // the ray caster's region (one rank's box of a job), texture coords:
    vec4 region_hi;      // samples in [lo, hi) only; region_hi.w = 1 when a region is set
};

// One brick of the brick cache's upload (render/brick_fill.comp, passes/paging.rs).
struct BrickFill {
    ivec4 slot_offset;   // x: the pool slot; y: the upload's first voxel in the batch; zw unused
};

struct FillPush {
    ivec4 grid;          // x, y: slots along x and y of the pool; z: channel_fill's channels
                         // (brick_fill's width is its pipeline's EIGHT_BIT); w: bricks
};

#define NORMALS_LOCAL_X 8
#define NORMALS_LOCAL_Y 8
#define NORMALS_LOCAL_Z 1
// Voxels along z that one invocation of render/sobel_normals.comp computes, in a block of
// NORMALS_BLOCK_X x NORMALS_BLOCK_Y columns.
#define NORMALS_COLUMN 16
#define NORMALS_BLOCK_X 2
#define NORMALS_BLOCK_Y 2

#endif
