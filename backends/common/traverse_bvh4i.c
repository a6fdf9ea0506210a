/* Traversal of bvh4.triangle4i (compact scenes): the single-ray template at
 * width 4 and the packet template for 4-ray packets, with leaves that read
 * their vertices from the geometries' buffers. */
#define RTK_BVHN 4
#define RTK_LEAF_INDEXED 1
#include "traverse_bvhn.h"
#define RTK_PACKET 4
#include "traverse_packet.h"
