#version 460
// Line extraction with the Hessian read from the volume hessian.comp made once (6 volume fetches
// for the gradient and 2 of the Hessian a corner; 32 bytes a voxel beside the volume). The body
// is extract.glsl.
#define PRECOMPUTED_HESSIAN
#include "extract.glsl"
