/* Traversal of bvh4.triangle4mb.robust (motion blur in robust scenes):
 * traverse_motion.h with the watertight intersector on the vertices
 * interpolated to the ray's time (a vertex shared by two triangles is
 * interpolated to the same floats in both, so the mesh stays watertight at
 * every time). */
#define RTK_ROBUST 1
#include "traverse_motion.h"
