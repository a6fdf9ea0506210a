/* Traversal of bvh4.triangle4i (compact scenes): the single-ray template at
 * width 4 and the packet template for 4-ray packets (and 8-ray ones where
 * the SIMD layer has 8-wide vectors: sse41, avx, avx2), with leaves that read
 * their vertices from the geometries' buffers. */
#define RTK_BVHN 4
#define RTK_LEAF_INDEXED 1
#include "traverse_bvhn.h"
#include "traverse_stream.h"
#include "traverse_objects.h"
#include "traverse_objects_stream.h"
#define RTK_PACKET 4
#include "traverse_packet.h"
#ifdef RTK_SIMD_HAS_8
#define RTK_PACKET 8
#include "traverse_packet.h"
#endif
