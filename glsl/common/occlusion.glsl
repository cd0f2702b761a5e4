// Shader interfaces of the occlusion passes (twins in src/passes/occlusion.rs, layout-tested).
#ifndef VELLUM_OCCLUSION_GLSL
#define VELLUM_OCCLUSION_GLSL

struct OcclusionPush {
    ivec3 dims;        // input volume size in voxels
    int radius;        // R in voxels
    ivec3 out_dims;    // output size (dims / stride, rounded up)
    int stride;        // output voxel o covers input voxel o * stride
    int mapping;       // 0 linear ramp, 1 truncated ramp, 2 transfer-function opacity
    int axis;          // Gaussian pass: 0, 1, 2
    float t0;          // truncated ramp cut-offs (normalised intensity)
    float t1;
};

struct SpectrumPush {
    ivec3 dims;        // intensity volume size
    int stride;        // occlusion voxel = voxel / stride
    int bins_x;        // intensity bins
    int bins_y;        // occlusion bins
    int pad0;
    int pad1;
};

#define OCCLUSION_LOCAL_X 64
#define OCCLUSION_LOCAL_Y 2
#define OCCLUSION_LOCAL_Z 2

#endif
