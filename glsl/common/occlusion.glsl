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

// Push constants of the FFT passes (issue 16; twin: `FftPush` in passes/occlusion_fft/gpu.rs).
struct FftPush {
    ivec3 dims;        // volume size N
    int mode;          // fft_x: 0 data, 1 ball kernel, 2 Gaussian kernel; fft_z: 0 kernel, 1 convolve
    ivec3 pad;         // transform size P
    int radius;        // R in voxels
    ivec3 live;        // rows (y) and planes (z) that hold data; the others are zero
    int stride;        // output voxel o samples voxel o * stride
    ivec3 reach;       // min(R, N - 1) per axis
    int n;             // length of this pass's transforms
    ivec3 out_dims;    // output size
    int stages;        // radix stages of length n
    int radices0;      // 4 bits per stage, stages 0..7
    int radices1;      // stages 8..15
    int twiddle_base;  // first twiddle of length n
    int mapping;       // visibility mapping, as OcclusionPush
    float t0;
    float t1;
    float norm;        // 1 / (Px Py Pz)
    float dir;         // -1 forward, +1 inverse
    ivec3 classes;     // denominator classes per axis
    int pad0;
};

// Invocations per line of the FFT passes (glsl/common/fft.glsl).
#define FFT_LOCAL 64

#define OCCLUSION_LOCAL_X 64
#define OCCLUSION_LOCAL_Y 2
#define OCCLUSION_LOCAL_Z 2

#endif
