/*
 * Oriented boxes of the leaf blocks, for closest points (point_query.c).
 *
 * A point far from the surface has a large ball of candidates, and a
 * tilted patch's axis-aligned boxes reach well inside it: on the bunny,
 * points spread through its box entered 27 leaf blocks each, and 21 of
 * those got as far as the triangles' float bounds, where only 7 came
 * within the box of the block's triangles oriented along their normal
 * (rtktool's scratch counters, docs/benchmarks/points-and-python.md).
 * So each block of the triangle4 and triangle4v layouts gets a box along
 * its own axes: the third its triangles' summed normal, the first its
 * longest edge made perpendicular to that, the second their cross
 * product.  Since 5ed48c6 every child of a node gets one (node_obb
 * below), a leaf's from its blocks' triangles, an inner node's from its
 * children's boxes, tested beside the axis-aligned boxes in one SIMD
 * step: the curved or tilted surface under an inner node also fills only
 * part of its axis-aligned box (python3 -m rtk.bench's box points: the
 * bunny +30%, torus:0.3M +68%, sphere:1.3M about 2x over the blocks' boxes
 * alone), and the blocks' own boxes are then left out.
 *
 * The boxes are made at a tree's first closest-point query, not at its
 * build: a scene that is only traced pays nothing for them (48 bytes per
 * child slot of a node, 21-25 bytes a triangle on the 8-wide trees of
 * the shared meshes; 64 per block for a tree of one leaf; through the
 * tree's memory monitor).  Queries
 * that find none made make them; concurrent first queries each make a
 * copy and one is kept (a compare-and-swap), so a committed scene stays
 * free to query from any number of threads.  A refit drops them.
 */
#ifndef RTK_BLOCK_BOUNDS_H
#define RTK_BLOCK_BOUNDS_H

#include "bvh4_triangle4.h"

/* A leaf block's box: every vertex v of its triangles has
 * |axis[k] . (v - c)| <= h[k], evaluated exactly (in double, from the
 * floats stored here and the vertices' floats).  The float axes are
 * within a few ulps of orthonormal. */
typedef struct rtk_block_obb {
    float c[3];
    float h[3];
    float axis[3][3];
    float pad;
} rtk_block_obb;

#define RTK_NODE_OBB_ROWS 12

/* A box's second axis: the cross product of its third and first, in float,
 * as the operations of the walk's SIMD test make it lane by lane. */
static inline void rtk_obb_axis1(const float *a2, const float *a0, float *a1)
{
    a1[0] = a2[1] * a0[2] - a2[2] * a0[1];
    a1[1] = a2[2] * a0[0] - a2[0] * a0[2];
    a1[2] = a2[0] * a0[1] - a2[1] * a0[0];
}

/* What a tree's first closest-point query makes (one allocation): for a
 * tree of nodes node_obb (obb and worth NULL), for a tree of one leaf its
 * blocks' boxes (node_obb NULL). */
typedef struct rtk_block_bounds {
    const rtk_block_obb *obb; /* one per block of a->tris */
    /* bit i of worth[i / 64]: block i's box is worth a test, being less than
     * half as thick as its axis-aligned box's thinnest side (a tilted or
     * curved patch; an axis-aligned one, as most of San Miguel's walls,
     * has nothing to gain and would only pay for reading it) */
    const uint64_t *worth;
    /* the squared best distance beyond which the walk tests them: a query
     * nearer than a few blocks' sizes finds most of its blocks' boxes in
     * reach, and would mostly pay for reading them */
    float from;
    /* The boxes of every node's children, along their own axes: for the
     * node's width w, node i's RTK_NODE_OBB_ROWS rows of w floats from
     * node_obb + i * RTK_NODE_OBB_ROWS * w, lane c of each child c's: the
     * centre's x, y and z, the half extents h[0..2], axis[0] and axis[2]
     * (axis[1] is their rtk_obb_axis1), as an rtk_block_obb's.  A leaf's
     * is made from all of its blocks' triangles as a block's is, an inner
     * child's along its triangles' summed normal from its children's
     * boxes (their extents along the new axes), and an empty slot's leaves
     * nothing out.  Tested beside the axis-aligned boxes of a node's
     * children (rtk_block_obb_lower2 lane by lane), they leave out inner
     * nodes too, where curved or tilted surface lies in one corner of an
     * axis-aligned box. */
    const float *node_obb;
} rtk_block_bounds;

/* The accel's boxes, made now if they were not yet; NULL for layouts
 * without triangle4/triangle4v blocks, or when the memory monitor or the
 * heap refuses them (the walk then goes without). */
const rtk_block_bounds *rtk_block_bounds_of(const rtk_accel *a);

/* Frees them (a refit's boxes change, and a released tree's go with it). */
void rtk_block_bounds_drop(rtk_accel *a);

static inline int rtk_block_worth(const rtk_block_bounds *b, uint32_t block)
{
    return (int)(b->worth[block >> 6] >> (block & 63) & 1u);
}

static inline float rtk_pos_part(float g) { return g > 0.0f ? g : 0.0f; }

/* A lower bound of the squared distance from the float point pf, within
 * dp of the query's on every axis, to anything inside the box.
 *
 * Exactly, |axis[k] . (p - x)| >= |axis[k] . (p - c)| - h[k] for every x
 * of the box, and the sum of those squares is at most |p - x|^2 times the
 * axes' largest singular value squared (under 1 + 2^-20).  In float, the
 * projections are off by a few ulps of |pf - c|_1 (2^-20 of it is taken
 * off each gap), and pf by at most 2 dp along a unit axis; the sum is
 * lowered by 2^-18 for its own rounding and the axes, and below 2^-100
 * (squares of gaps under 2^-50, near float's subnormals) taken as 0. */
static inline float rtk_block_obb_lower2(const rtk_block_obb *o, const float *pf, float dp)
{
    const float dx = pf[0] - o->c[0], dy = pf[1] - o->c[1], dz = pf[2] - o->c[2];
    const float slack = (__builtin_fabsf(dx) + __builtin_fabsf(dy) + __builtin_fabsf(dz)) * 0x1p-20f + 2.0f * dp;
    float s = 0.0f;
    for (int k = 0; k < 3; k++) {
        const float q = o->axis[k][0] * dx + o->axis[k][1] * dy + o->axis[k][2] * dz;
        const float g = rtk_pos_part(__builtin_fabsf(q) - o->h[k] - slack);
        s += g * g;
    }
    /* (squares down where floats lose their bits: no bound) */
    return s < 0x1p-100f ? 0.0f : s * (1.0f - 0x1p-18f);
}

#endif
