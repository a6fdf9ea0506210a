/* Traversal of bvh4.triangle4mb (motion blur): traverse_bvh4mb.h with the
 * fast intersector. */
#include "traverse_bvh4mb.h"
