/*
 * Layouts "bvh4.triangle4" and "bvh8.triangle4": 4- or 8-wide BVH nodes whose
 * child boxes are stored as structure-of-arrays (ready for 4- or 8-wide SIMD
 * box tests), and leaves that each hold one block of up to four triangles
 * with precomputed edges (a vertex copy: traversal never touches the
 * application's buffers).  The 8-wide nodes are used by the AVX backends,
 * where one 8-wide box test costs what a 4-wide one does.
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
/* A node pushes at most N - 1 children and continues into one. */
#define RTK_BVHN_STACK_SIZE(N) (((N) - 1) * RTK_BVH4_MAX_DEPTH + (N))

typedef struct rtk_bvh4_node {
    float lower_x[4], upper_x[4];
    float lower_y[4], upper_y[4];
    float lower_z[4], upper_z[4];
    uint32_t child[4];
    uint32_t reserved[4]; /* pads the node to two cache lines */
} rtk_bvh4_node;

typedef struct rtk_bvh8_node {
    float lower_x[8], upper_x[8];
    float lower_y[8], upper_y[8];
    float lower_z[8], upper_z[8];
    uint32_t child[8];
    uint32_t reserved[8]; /* pads the node to four cache lines */
} rtk_bvh8_node;

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
    uint32_t layout; /* RTK_LAYOUT_BVH4_TRIANGLE4 or RTK_LAYOUT_BVH8_TRIANGLE4 */
    uint32_t root;   /* a child reference */
    void *nodes;     /* rtk_bvh4_node or rtk_bvh8_node, by layout */
    rtk_triangle4 *tris;
    uint64_t node_count, leaf_count;
    size_t nodes_mapped, tris_mapped; /* bytes mapped for each array (page-rounded) */
};

#endif
