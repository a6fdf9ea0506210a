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

/* A node's slot c: box and reference, whatever the node width; 0 when its
 * prefetch offset (rtk_bvh4_node) is not the one its reference calls for. */
static int read_slot(const struct rtk_accel *a, uint64_t node, int c, float lo[3], float hi[3], uint32_t *ref)
{
    if (a->layout == RTK_LAYOUT_BVH8_TRIANGLE4 || a->layout == RTK_LAYOUT_BVH8_TRIANGLE4V) {
        const rtk_bvh8_node *n = (const rtk_bvh8_node *)a->nodes + node;
        lo[0] = n->lower_x[c], lo[1] = n->lower_y[c], lo[2] = n->lower_z[c];
        hi[0] = n->upper_x[c], hi[1] = n->upper_y[c], hi[2] = n->upper_z[c];
        *ref = n->child[c];
        return n->prefetch[c] == rtk_prefetch_units(a, n, *ref, sizeof *n);
    }
    const rtk_bvh4_node *n = (const rtk_bvh4_node *)a->nodes + node;
    lo[0] = n->lower_x[c], lo[1] = n->lower_y[c], lo[2] = n->lower_z[c];
    hi[0] = n->upper_x[c], hi[1] = n->upper_y[c], hi[2] = n->upper_z[c];
    *ref = n->child[c];
    return n->prefetch[c] == rtk_prefetch_units(a, n, *ref, sizeof *n);
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
    const int w = a->layout == RTK_LAYOUT_BVH8_TRIANGLE4 || a->layout == RTK_LAYOUT_BVH8_TRIANGLE4V ? 8 : 4;
    t->width = (uint32_t)w;
    t->node_count = a->node_count;
    t->leaf_count = 0;
    t->prim_count = 0;

    /* at[first block of a leaf] = that leaf's reference (never 0: the leaf
     * bit is set); then, once the leaf is read, its number. */
    uint32_t *at = calloc(a->leaf_count ? a->leaf_count : 1, sizeof *at);
    if (!at)
        return RTK_ERROR_OUT_OF_MEMORY;
    if (a->root != RTK_BVH4_EMPTY && (a->root & RTK_BVH4_LEAF_BIT))
        at[rtk_leaf_first(a->root)] = a->root;
    /* (the prefetch offsets are checked on the way: they only ever cost
     * speed when wrong, and this is where the tests can see them) */
    int prefetch_ok = 1;
    for (uint64_t i = 0; i < a->node_count; i++)
        for (int c = 0; c < w; c++) {
            const uint64_t slot = i * (uint64_t)w + (uint64_t)c;
            prefetch_ok &= read_slot(a, i, c, t->child_lower + 3 * slot, t->child_upper + 3 * slot,
                                     &t->children[slot]);
            const uint32_t ref = t->children[slot];
            if (ref != RTK_BVH4_EMPTY && (ref & RTK_BVH4_LEAF_BIT))
                at[rtk_leaf_first(ref)] = ref;
        }
    /* Leaves numbered in the order of their blocks (the builder's
     * depth-first order), so an import lays the blocks out the same way. */
    for (uint64_t k = 0; k < a->leaf_count; k++)
        if (at[k]) {
            t->leaf_first[t->leaf_count] = t->prim_count;
            read_leaf(a, at[k], t);
            at[k] = (uint32_t)t->leaf_count++;
        }
    t->leaf_first[t->leaf_count] = t->prim_count;
    /* Nodes keep their indices; leaf references become leaf numbers. */
    for (uint64_t slot = 0; slot < a->node_count * (uint64_t)w; slot++) {
        const uint32_t ref = t->children[slot];
        if (ref != RTK_BVH4_EMPTY && (ref & RTK_BVH4_LEAF_BIT))
            t->children[slot] = RTK_BVH_LEAF_BIT | at[rtk_leaf_first(ref)];
    }
    t->root = a->root == RTK_BVH4_EMPTY || !(a->root & RTK_BVH4_LEAF_BIT) ? a->root : RTK_BVH_LEAF_BIT;
    free(at);
    return prefetch_ok ? RTK_OK : RTK_ERROR_UNKNOWN;
}
