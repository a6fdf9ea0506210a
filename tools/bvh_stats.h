/* What a BVH engineer wants to see of a tree (rtk_bvh), and a picture of
 * its boxes level by level: for rtktool build, on a fresh build or a dump. */
#ifndef RTK_TOOLS_BVH_STATS_H
#define RTK_TOOLS_BVH_STATS_H

#include <stddef.h>
#include <stdint.h>

#include "rtk/rtk.h"

#define BVH_STATS_LEAF_BINS 17 /* triangles per leaf: 1 .. 16, and more */

typedef struct bvh_stats {
    uint32_t width; /* child slots per node */
    uint64_t nodes, leaves;
    uint64_t prims; /* distinct triangles */
    uint64_t refs;  /* triangle references in the leaves (more than prims after spatial splits) */
    uint64_t slots_used;             /* child slots holding a node or leaf */
    uint32_t depth_max;              /* levels, the leaves' included (as rtk_scene_info.depth) */
    double depth_mean;               /* of the leaves */
    uint64_t leaf_prims[BVH_STATS_LEAF_BINS]; /* [n - 1]: leaves of n triangles; [16]: more than 16 */
    uint64_t leaf_blocks;            /* blocks of four triangles the leaves take */
    double sah;                      /* the builders' cost model (rtk_scene_info.sah_cost) */
    float lower[3], upper[3];        /* the root's box (all 0 without inner nodes) */
} bvh_stats;

/* The tree must have passed rtk_bvh_check.  0, or non-zero when out of memory. */
int bvh_stats_compute(const rtk_bvh *t, bvh_stats *s);

/* Draws the boxes of levels 1 .. `levels` (a panel each, 4 to a row),
 * projected along the root box's shortest axis: inner nodes' boxes in
 * blue, leaves' in orange, brighter where they pile up.  0, or non-zero
 * with err. */
int bvh_picture(const rtk_bvh *t, const bvh_stats *s, int levels, int panel, const char *path, char *err,
                size_t err_size);
#endif
