#version 460
// One round of the seeded traversal: extract the frontier's cells, follow each line found into
// the cells across the faces its ends lie on, and walk searches that found none towards the
// line. The body is extract.glsl.
#define SEEDED
#include "extract.glsl"
