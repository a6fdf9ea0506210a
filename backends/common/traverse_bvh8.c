/* Single-ray traversal of bvh8.triangle4: the template at width 8, in the
 * backends whose SIMD layer has 8-wide vectors (avx, avx2). */
#include "simd/simd.h"
#ifdef RTK_SIMD_HAS_8
#define RTK_BVHN 8
#include "traverse_bvhn.h"
#endif
