// Push constants of the importance-map passes. Twin of passes::importance::GaussPush and
// SubtractPush; a unit test checks the layouts match.
#ifndef VELLUM_IMPORTANCE_GLSL
#define VELLUM_IMPORTANCE_GLSL

struct GaussPush {
    ivec3 dims;   // volume size in voxels
    int axis;     // 0 = x, 1 = y, 2 = z
    int radius;   // R: taps -R..R
    int pad[3];   // std430 rounds the struct to 16 bytes
};

struct SubtractPush {
    ivec3 dims;
    int pad;
};

// The subtract walks the volume in rows of 64 voxels along x; the Gaussian pass runs GAUSS_LOCAL_X
// lines side by side (see gauss1d.comp).
#define IMPORTANCE_LOCAL_X 64
#define IMPORTANCE_LOCAL_Y 2
#define IMPORTANCE_LOCAL_Z 2
#define GAUSS_LOCAL_X 64

#endif
