/* Traversal of bvh8.triangle4v (robust scenes on avx and avx2): the
 * single-ray template at width 8 with the watertight intersector, and the
 * packet template for 4- and 8-ray packets. */
#include "simd/simd.h"
#ifdef RTK_SIMD_HAS_8
#define RTK_BVHN 8
#define RTK_ROBUST 1
#include "traverse_bvhn.h"
#include "traverse_stream.h"
#include "traverse_objects.h"
#include "traverse_objects_stream.h"
#define RTK_PACKET 4
#include "traverse_packet.h"
#define RTK_PACKET 8
#include "traverse_packet.h"
#endif
