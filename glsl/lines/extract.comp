#version 460
// Line extraction with the Hessian by differences of the volume at every cell corner (19 fetches
// a corner): no memory beside the volume. The body is extract.glsl.
#include "extract.glsl"
