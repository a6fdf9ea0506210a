/* Traversal of bvh8.triangle4mb (motion blur, 8-wide nodes), in the
 * backends whose SIMD layer has 8-wide vectors: traverse_motion.h at width
 * 8 with the fast intersector. */
#include "simd/simd.h"
#ifdef RTK_SIMD_HAS_8
#define RTK_BVHN 8
#include "traverse_motion.h"
#endif
