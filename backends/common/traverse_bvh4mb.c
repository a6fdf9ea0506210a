/* Traversal of bvh4.triangle4mb (motion blur): traverse_motion.h with the
 * fast intersector. */
#include "traverse_motion.h"
