/* Traversal of bvh4.triangle4: the single-ray template at width 4 and the
 * packet template for 4-ray packets. */
#define RTK_BVHN 4
#include "traverse_bvhn.h"
#define RTK_PACKET 4
#include "traverse_packet.h"
