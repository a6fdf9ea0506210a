/*
 * The layouts of bvh4_triangle4.h as a layout-neutral tree (rtk_bvh, rtk.h):
 * what rtk_scene_get_bvh returns.  The import, which shares the builder's
 * node and leaf writers, is in build_sah.c.
 */
#include <stdlib.h>
#include <string.h>

#include "backend_common.h"
#include "bvh4_triangle4.h"
#include "kernels.h"

/* A node's slot c: box and reference, whatever the node width. */
static void read_slot(const struct rtk_accel *a, uint64_t node, int c, float lo[3], float hi[3], uint32_t *ref)
{
    if (a->layout == RTK_LAYOUT_BVH8_TRIANGLE4) {
        const rtk_bvh8_node *n = (const rtk_bvh8_node *)a->nodes + node;
        lo[0] = n->lower_x[c], lo[1] = n->lower_y[c], lo[2] = n->lower_z[c];
        hi[0] = n->upper_x[c], hi[1] = n->upper_y[c], hi[2] = n->upper_z[c];
        *ref = n->child[c];
    } else {
        const rtk_bvh4_node *n = (const rtk_bvh4_node *)a->nodes + node;
        lo[0] = n->lower_x[c], lo[1] = n->lower_y[c], lo[2] = n->lower_z[c];
        hi[0] = n->upper_x[c], hi[1] = n->upper_y[c], hi[2] = n->upper_z[c];
        *ref = n->child[c];
    }
}

/* Appends the triangles of a leaf's blocks to t->prims. */
static void read_leaf(const struct rtk_accel *a, uint32_t ref, rtk_bvh *t)
{
    const uint32_t first = rtk_leaf_first(ref), blocks = rtk_leaf_blocks(ref);
    for (uint32_t k = first; k < first + blocks; k++)
        for (int lane = 0; lane < 4; lane++) {
            const uint32_t prim = a->tris ? a->tris[k].prim[lane] : a->trisi[k].prim[lane];
            if (prim == RTK_BVH4_EMPTY)
                continue;
            const uint32_t geom = a->tris ? a->tris[k].geom[lane] : a->geoms[a->trisi[k].geom[lane]].geom_id;
            t->prims[t->prim_count++] = (rtk_bvh_prim){.geom_id = geom, .prim_id = prim};
        }
}

int RTK_SYM(rtk_bvh_export)(const rtk_accel *accel, rtk_bvh *t)
{
    const struct rtk_accel *a = accel;
    const int w = a->layout == RTK_LAYOUT_BVH8_TRIANGLE4 ? 8 : 4;
    t->width = (uint32_t)w;
    t->node_count = a->node_count;
    t->leaf_count = 0;
    t->prim_count = 0;

    /* Leaves are numbered in the order of their blocks (which is the
     * builder's depth-first order): leaf_of[first block] = leaf number + 1. */
    uint32_t *leaf_of = calloc(a->leaf_count ? a->leaf_count : 1, sizeof *leaf_of);
    if (!leaf_of)
        return RTK_ERROR_OUT_OF_MEMORY;
    for (uint64_t i = 0; i < a->node_count; i++)
        for (int c = 0; c < w; c++) {
            float lo[3], hi[3];
            uint32_t ref;
            read_slot(a, i, c, lo, hi, &ref);
            if (ref != RTK_BVH4_EMPTY && (ref & RTK_BVH4_LEAF_BIT))
                leaf_of[rtk_leaf_first(ref)] = 1;
        }
    if (a->root != RTK_BVH4_EMPTY && (a->root & RTK_BVH4_LEAF_BIT))
        leaf_of[rtk_leaf_first(a->root)] = 1;
    uint32_t leaves = 0;
    for (uint64_t k = 0; k < a->leaf_count; k++)
        if (leaf_of[k])
            leaf_of[k] = ++leaves;
    t->leaf_count = leaves;

    /* Every leaf's triangles, in leaf order: walk the blocks, which are in
     * that order, starting a new leaf at each first block. */
    uint32_t *ref_of = calloc(leaves ? leaves : 1, sizeof *ref_of);
    if (!ref_of) {
        free(leaf_of);
        return RTK_ERROR_OUT_OF_MEMORY;
    }
    for (uint64_t i = 0; i < a->node_count; i++)
        for (int c = 0; c < w; c++) {
            float lo[3], hi[3];
            uint32_t ref;
            read_slot(a, i, c, lo, hi, &ref);
            if (ref != RTK_BVH4_EMPTY && (ref & RTK_BVH4_LEAF_BIT))
                ref_of[leaf_of[rtk_leaf_first(ref)] - 1] = ref;
        }
    if (a->root != RTK_BVH4_EMPTY && (a->root & RTK_BVH4_LEAF_BIT))
        ref_of[0] = a->root;
    for (uint32_t j = 0; j < leaves; j++) {
        t->leaf_first[j] = t->prim_count;
        read_leaf(a, ref_of[j], t);
    }
    t->leaf_first[leaves] = t->prim_count;
    free(ref_of);

    /* Nodes keep their indices; leaf references become leaf numbers. */
    for (uint64_t i = 0; i < a->node_count; i++)
        for (int c = 0; c < w; c++) {
            const uint64_t slot = i * (uint64_t)w + (uint64_t)c;
            uint32_t ref;
            read_slot(a, i, c, t->child_lower + 3 * slot, t->child_upper + 3 * slot, &ref);
            if (ref != RTK_BVH4_EMPTY && (ref & RTK_BVH4_LEAF_BIT))
                ref = RTK_BVH_LEAF_BIT | (leaf_of[rtk_leaf_first(ref)] - 1);
            t->children[slot] = ref;
        }
    if (a->root == RTK_BVH4_EMPTY)
        t->root = RTK_BVH_EMPTY;
    else if (a->root & RTK_BVH4_LEAF_BIT)
        t->root = RTK_BVH_LEAF_BIT | 0u;
    else
        t->root = a->root;
    free(leaf_of);
    return RTK_OK;
}
