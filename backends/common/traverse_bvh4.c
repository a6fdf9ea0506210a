/* Single-ray traversal of bvh4.triangle4: the template at width 4. */
#define RTK_BVHN 4
#include "traverse_bvhn.h"
