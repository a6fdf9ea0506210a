/* Traversal of bvh8.triangle4v (robust scenes on avx and avx2): the
 * single-ray template at width 8 with the watertight intersector.  No packet
 * kernels yet: the core traces packets through it ray by ray. */
#include "simd/simd.h"
#ifdef RTK_SIMD_HAS_8
#define RTK_BVHN 8
#define RTK_ROBUST 1
#include "traverse_bvhn.h"
#endif
