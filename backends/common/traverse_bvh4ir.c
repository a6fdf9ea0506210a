/* Traversal of bvh4.triangle4i.robust (scenes both compact and robust):
 * the single-ray template at width 4 with index leaves and the watertight
 * intersector.  No packet kernels yet: the core traces packets through it
 * ray by ray. */
#define RTK_BVHN 4
#define RTK_LEAF_INDEXED 1
#define RTK_ROBUST 1
#include "traverse_bvhn.h"
