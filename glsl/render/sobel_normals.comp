#version 460
// TL1: per-voxel gradient of the normalised volume with the 3D Sobel operator, computed once and
// stored as a 3D texture: xyz = gradient in world units (per unit of spacing), w = its length.
// The derivative along an axis is the central difference (-1, 0, 1) smoothed by (1, 2, 1) along
// the other two axes, divided by 32 so that a unit ramp has a unit gradient. Borders clamp.
// Where at least an eighth of the bricks (16^3 voxels) are of one value, it runs only on the
// others: those whose region widened by one voxel holds more than one value, listed by the host
// from the bricks' ranges it computes anyway (passes/normals.rs); every voxel of another brick has
// a zero gradient, which a clear of the image wrote. Else it runs on every voxel in order. A volume of
// sparse structure (a cell in its dish, segmented data, a phantom) is mostly such bricks, and a
// CPU device, which runs masked lanes too, only saves their work when they are never dispatched.
// A listed brick is one workgroup; the list runs along y, then z.
// Each invocation computes a block of NORMALS_BLOCK_X x NORMALS_BLOCK_Y columns of NORMALS_COLUMN
// voxels along z. Per slice it reads the block's (X + 2) x (Y + 2) neighbourhood once and makes
// three sums over that plane for each column (the x and y derivatives smoothed in the plane, and
// the plane smoothed), separably: along x, then along y. Three neighbouring slices combine them.
// That is (X + 2)(Y + 2) / (X Y) fetches per voxel (9 / 4 for 2 x 2), not the stencil's 27; the
// sums, and so the gradients, are the same up to the order of the additions.
#include "render.glsl"

layout(local_size_x = NORMALS_LOCAL_X, local_size_y = NORMALS_LOCAL_Y, local_size_z = NORMALS_LOCAL_Z) in;

layout(set = 0, binding = 0) uniform sampler3D volume;
layout(set = 0, binding = 1, rgba16f) uniform writeonly image3D gradient;
layout(set = 0, binding = 2) readonly buffer Listed { uint listed_bricks[]; };
const int BRICK = 16;

layout(push_constant) uniform Push { NormalsPush pc; };
// Which pipeline: over the listed bricks, or over every voxel in order. A specialisation constant,
// not a test of `listed` alone: a CPU device runs both sides of a branch on a uniform.
layout(constant_id = 0) const bool LISTED = false;

const int BX = NORMALS_BLOCK_X;
const int BY = NORMALS_BLOCK_Y;

// The first voxel of this invocation's block: every block of the volume in order, or of the
// listed bricks.
ivec3 column_start() {
    ivec2 block = ivec2(BX, BY);
    if (!LISTED) {
        return ivec3(ivec2(gl_GlobalInvocationID.xy) * block, gl_GlobalInvocationID.z * NORMALS_COLUMN);
    }
    uint k = gl_WorkGroupID.y + gl_WorkGroupID.z * gl_NumWorkGroups.y;
    if (k >= uint(pc.listed)) {
        return pc.dims;
    }
    ivec3 counts = (pc.dims + BRICK - 1) / BRICK;
    int b = int(listed_bricks[k]);
    ivec3 brick = ivec3(b % counts.x, (b / counts.x) % counts.y, b / (counts.x * counts.y));
    // A workgroup's blocks cover (local size x block) columns; a brick takes `across` of them
    // along x.
    ivec2 group_cols = ivec2(NORMALS_LOCAL_X, NORMALS_LOCAL_Y) * block;
    int across = BRICK / group_cols.x;
    int sub = int(gl_WorkGroupID.x);
    ivec2 group = ivec2(sub % across, sub / across) * group_cols;
    return brick * BRICK + ivec3(group + ivec2(gl_LocalInvocationID.xy) * block, 0);
}

// Over slice z (clamped) around the block at xy: per column, x, the x difference smoothed
// (1, 2, 1) along y; y, the y difference smoothed along x; z, the plane smoothed along both.
void plane_sums(ivec2 xy, int z, out vec3 s[BY][BX]) {
    int zc = clamp(z, 0, pc.dims.z - 1);
    // Along x first: per row of the neighbourhood, the smoothed values and the differences.
    float smooth_x[BY + 2][BX], diff_x[BY + 2][BX];
    for (int j = 0; j < BY + 2; ++j) {
        float v[BX + 2];
        for (int i = 0; i < BX + 2; ++i) {
            ivec2 q = clamp(xy + ivec2(i - 1, j - 1), ivec2(0), pc.dims.xy - 1);
            v[i] = texelFetch(volume, ivec3(q, zc), 0).r;
        }
        for (int i = 0; i < BX; ++i) {
            smooth_x[j][i] = v[i] + 2.0 * v[i + 1] + v[i + 2];
            diff_x[j][i] = v[i + 2] - v[i];
        }
    }
    // Then along y.
    for (int j = 0; j < BY; ++j) {
        for (int i = 0; i < BX; ++i) {
            s[j][i] = vec3(
                diff_x[j][i] + 2.0 * diff_x[j + 1][i] + diff_x[j + 2][i],
                smooth_x[j + 2][i] - smooth_x[j][i],
                smooth_x[j][i] + 2.0 * smooth_x[j + 1][i] + smooth_x[j + 2][i]);
        }
    }
}

void main() {
    ivec3 p = column_start();
    if (any(greaterThanEqual(p, pc.dims))) {
        return;
    }
    int n = min(NORMALS_COLUMN, pc.dims.z - p.z);
    vec3 below[BY][BX], here[BY][BX], above[BY][BX];
    plane_sums(p.xy, p.z - 1, below);
    plane_sums(p.xy, p.z, here);
    vec3 scale = pc.inv_spacing.xyz / 32.0;
    for (int k = 0; k < n; ++k) {
        plane_sums(p.xy, p.z + k + 1, above);
        for (int j = 0; j < BY; ++j) {
            for (int i = 0; i < BX; ++i) {
                ivec2 q = p.xy + ivec2(i, j);
                if (all(lessThan(q, pc.dims.xy))) {
                    vec3 g = vec3(below[j][i].xy + 2.0 * here[j][i].xy + above[j][i].xy, above[j][i].z - below[j][i].z) * scale;
                    imageStore(gradient, ivec3(q, p.z + k), vec4(g, length(g)));
                }
            }
        }
        below = here;
        here = above;
    }
}
