/* Traversal of bvh4.triangle4v (robust scenes): the single-ray template at
 * width 4 with the watertight intersector.  No packet kernels yet: the core
 * traces packets through it ray by ray. */
#define RTK_BVHN 4
#define RTK_ROBUST 1
#include "traverse_bvhn.h"
