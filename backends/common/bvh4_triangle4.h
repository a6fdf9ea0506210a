/*
 * Layout "bvh4.triangle4": 4-wide BVH nodes whose child boxes are stored as
 * structure-of-arrays (ready for 4-wide SIMD box tests), and leaves that each
 * hold one block of up to four triangles with precomputed edges (a vertex
 * copy: traversal never touches the application's buffers).
 *
 * This file is the layout only; the builder (build_sah.c) and the traversal
 * (traverse_bvh4.c) are separate, so either can change without the other.
 */
#ifndef RTK_BVH4_TRIANGLE4_H
#define RTK_BVH4_TRIANGLE4_H

#include <stdint.h>

#include "backend_common.h"
#include "rtk/rtk_backend.h"

/* A child reference: an inner node index, a leaf block index with the top bit
 * set, or RTK_BVH4_EMPTY.  An empty slot has an inverted box (lower = +inf,
 * upper = -inf) so no ray ever enters it. */
#define RTK_BVH4_LEAF_BIT 0x80000000u
#define RTK_BVH4_EMPTY 0xffffffffu
/* Builders never go deeper than this, so a traversal stack of
 * 3 * RTK_BVH4_MAX_DEPTH + 1 entries can never overflow. */
#define RTK_BVH4_MAX_DEPTH 64
#define RTK_BVH4_STACK_SIZE (3 * RTK_BVH4_MAX_DEPTH + 4)

typedef struct rtk_bvh4_node {
    float lower_x[4], upper_x[4];
    float lower_y[4], upper_y[4];
    float lower_z[4], upper_z[4];
    uint32_t child[4];
    uint32_t reserved[4]; /* pads the node to two cache lines */
} rtk_bvh4_node;

/* Up to four triangles: v0, e1 = v1 - v0, e2 = v2 - v0.  Unused lanes have
 * prim = RTK_BVH4_EMPTY and NaN vertices, so they never hit. */
typedef struct rtk_triangle4 {
    float v0x[4], v0y[4], v0z[4];
    float e1x[4], e1y[4], e1z[4];
    float e2x[4], e2y[4], e2z[4];
    uint32_t geom[4];
    uint32_t prim[4];
} rtk_triangle4;

struct rtk_accel {
    uint32_t layout; /* RTK_LAYOUT_BVH4_TRIANGLE4 */
    uint32_t root;   /* a child reference */
    rtk_bvh4_node *nodes;
    rtk_triangle4 *tris;
    uint64_t node_count, leaf_count;
    size_t nodes_mapped, tris_mapped; /* bytes mapped for each array (page-rounded) */
};

#endif
