/* Traversal of bvh8.triangle4mb.robust (motion blur in robust scenes,
 * 8-wide nodes): traverse_motion.h at width 8 with the watertight
 * intersector (see traverse_bvh4mbr.c). */
#include "simd/simd.h"
#ifdef RTK_SIMD_HAS_8
#define RTK_BVHN 8
#define RTK_ROBUST 1
#include "traverse_motion.h"
#endif
