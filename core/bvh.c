/*
 * The BVH as data (rtk_bvh, rtk.h): the structural check any tree must pass
 * before rtk trusts it, the check that a tree fits a scene's triangles, and
 * the memory of exported trees.  A tree that passes both checks cannot make
 * a backend read out of bounds, overflow its traversal stack or miss a hit:
 * every reference is in range, the tree is a tree of bounded depth, and
 * every box contains everything below it.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "geometry/triangle.h"
#include "internal.h"

static rtk_error bad(char *msg, size_t size, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static rtk_error bad(char *msg, size_t size, const char *fmt, ...)
{
    if (msg && size) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(msg, size, fmt, ap);
        va_end(ap);
    }
    return RTK_ERROR_INVALID_ARGUMENT;
}

static int is_leaf(uint32_t ref)
{
    return ref != RTK_BVH_EMPTY && (ref & RTK_BVH_LEAF_BIT);
}

/* Slot box ordered and finite (NaN fails every comparison). */
static int box_ok(const float *lo, const float *hi)
{
    for (int k = 0; k < 3; k++)
        if (!(lo[k] <= hi[k]) || !isfinite(lo[k]) || !isfinite(hi[k]))
            return 0;
    return 1;
}

static int box_contains(const float *lo, const float *hi, const float *in_lo, const float *in_hi)
{
    for (int k = 0; k < 3; k++)
        if (!(lo[k] <= in_lo[k] && in_hi[k] <= hi[k]))
            return 0;
    return 1;
}

rtk_error rtk_bvh_check(const rtk_bvh *t, char *msg, size_t size)
{
    if (!t)
        return bad(msg, size, "the tree is NULL");
    if (t->struct_size < sizeof(rtk_bvh))
        return bad(msg, size, "struct_size %zu: set it to sizeof(rtk_bvh) = %zu", t->struct_size, sizeof(rtk_bvh));
    if (t->width != 4 && t->width != 8)
        return bad(msg, size, "width %u: nodes are 4 or 8 wide", t->width);
    if (t->node_count >= RTK_BVH_LEAF_BIT || t->leaf_count >= RTK_BVH_LEAF_BIT - 1 || t->prim_count >= (1ull << 40))
        return bad(msg, size, "%llu nodes, %llu leaves, %llu triangles: too many for 31-bit references",
                   (unsigned long long)t->node_count, (unsigned long long)t->leaf_count,
                   (unsigned long long)t->prim_count);
    if (t->node_count && (!t->children || !t->child_lower || !t->child_upper))
        return bad(msg, size, "%llu nodes but no child arrays", (unsigned long long)t->node_count);
    if ((t->leaf_count && !t->leaf_first) || (t->prim_count && !t->prims))
        return bad(msg, size, "%llu leaves and %llu triangles but no leaf or triangle array",
                   (unsigned long long)t->leaf_count, (unsigned long long)t->prim_count);

    /* The root: node 0 (no node can point at it), the only leaf, or nothing. */
    if (t->root == RTK_BVH_EMPTY) {
        if (t->node_count || t->leaf_count || t->prim_count)
            return bad(msg, size, "an empty root over %llu nodes, %llu leaves", (unsigned long long)t->node_count,
                       (unsigned long long)t->leaf_count);
    } else if (is_leaf(t->root)) {
        if (t->node_count || t->leaf_count != 1 || t->root != RTK_BVH_LEAF_BIT)
            return bad(msg, size, "a leaf root must be leaf 0, the only leaf, with no nodes");
    } else if (t->root != 0 || !t->node_count) {
        return bad(msg, size, "root %u: an inner root must be node 0 of at least one", t->root);
    }

    if (t->leaf_count) {
        if (t->leaf_first[0] != 0 || t->leaf_first[t->leaf_count] != t->prim_count)
            return bad(msg, size, "leaf ranges run from %llu to %llu, not 0 to the %llu triangles",
                       (unsigned long long)t->leaf_first[0], (unsigned long long)t->leaf_first[t->leaf_count],
                       (unsigned long long)t->prim_count);
        for (uint64_t j = 0; j < t->leaf_count; j++)
            if (t->leaf_first[j + 1] <= t->leaf_first[j])
                return bad(msg, size, "leaf %llu is empty or its range runs backwards", (unsigned long long)j);
    } else if (t->prim_count) {
        return bad(msg, size, "%llu triangles in no leaf", (unsigned long long)t->prim_count);
    }

    /* One pass in index order: a parent precedes its children, so each
     * node's depth is known when it is reached, and a node not reached by
     * then is referenced by nothing (or only by later nodes). */
    const uint32_t w = t->width;
    uint8_t *depth = calloc(t->node_count ? t->node_count : 1, 1);
    uint8_t *seen = calloc(t->leaf_count ? t->leaf_count : 1, 1);
    rtk_error err = RTK_OK;
    if (!depth || !seen) {
        err = RTK_ERROR_OUT_OF_MEMORY;
        if (msg && size)
            snprintf(msg, size, "out of memory checking the tree");
        goto done;
    }
    if (t->node_count)
        depth[0] = 1;
    if (is_leaf(t->root))
        seen[0] = 1;
    for (uint64_t i = 0; i < t->node_count; i++) {
        if (!depth[i]) {
            err = bad(msg, size, "node %llu is not referenced by a node before it", (unsigned long long)i);
            goto done;
        }
        int used = 0;
        for (uint32_t c = 0; c < w; c++) {
            const uint64_t slot = i * w + c;
            const uint32_t ref = t->children[slot];
            if (ref == RTK_BVH_EMPTY)
                continue;
            used++;
            const float *lo = t->child_lower + 3 * slot, *hi = t->child_upper + 3 * slot;
            if (!box_ok(lo, hi)) {
                err = bad(msg, size, "node %llu, slot %u: the box is not finite or not ordered", (unsigned long long)i,
                          c);
                goto done;
            }
            if (depth[i] + 1 > RTK_BVH_MAX_DEPTH) {
                err = bad(msg, size, "node %llu, slot %u: deeper than %d levels", (unsigned long long)i, c,
                          RTK_BVH_MAX_DEPTH);
                goto done;
            }
            if (is_leaf(ref)) {
                const uint32_t j = ref & ~RTK_BVH_LEAF_BIT;
                if (j >= t->leaf_count || seen[j]) {
                    err = bad(msg, size, "node %llu, slot %u: leaf %u %s", (unsigned long long)i, c, j,
                              j >= t->leaf_count ? "does not exist" : "is referenced twice");
                    goto done;
                }
                seen[j] = 1;
                continue;
            }
            if (ref >= t->node_count || ref <= i || depth[ref]) {
                err = bad(msg, size, "node %llu, slot %u: node %u %s", (unsigned long long)i, c, ref,
                          ref >= t->node_count ? "does not exist"
                          : ref <= i           ? "does not come after its parent"
                                               : "is referenced twice");
                goto done;
            }
            depth[ref] = (uint8_t)(depth[i] + 1);
            for (uint32_t k = 0; k < w; k++) {
                const uint64_t s = (uint64_t)ref * w + k;
                if (t->children[s] == RTK_BVH_EMPTY)
                    continue;
                if (!box_ok(t->child_lower + 3 * s, t->child_upper + 3 * s)) { /* said about the child itself */
                    err = bad(msg, size, "node %u, slot %u: the box is not finite or not ordered", ref, k);
                    goto done;
                }
                if (!box_contains(lo, hi, t->child_lower + 3 * s, t->child_upper + 3 * s)) {
                    err = bad(msg, size, "node %llu, slot %u: the box does not contain slot %u of node %u",
                              (unsigned long long)i, c, k, ref);
                    goto done;
                }
            }
        }
        if (!used) {
            err = bad(msg, size, "node %llu has no children", (unsigned long long)i);
            goto done;
        }
    }
    for (uint64_t j = 0; j < t->leaf_count; j++)
        if (!seen[j]) {
            err = bad(msg, size, "leaf %llu is not referenced", (unsigned long long)j);
            goto done;
        }
done:
    free(depth);
    free(seen);
    return err;
}

static const float *vertex_at(const rtk_build_geometry *g, uint32_t index)
{
    return (const float *)((const char *)g->vertices + (size_t)index * g->vertex_stride);
}

static const uint32_t *triangle_at(const rtk_build_geometry *g, size_t prim)
{
    return (const uint32_t *)((const char *)g->indices + prim * g->index_stride);
}

rtk_error rtk_bvh_check_fit(const rtk_bvh *t, const rtk_build_geometry *geoms, uint32_t geom_count,
                            uint64_t *non_finite, uint64_t *degenerate, char *msg, size_t size)
{
    *non_finite = *degenerate = 0;
    /* geom_id -> index in geoms, and each geometry's first triangle in one
     * array of "referenced" marks. */
    uint32_t max_id = 0;
    size_t total = 0;
    for (uint32_t g = 0; g < geom_count; g++) {
        max_id = geoms[g].geom_id > max_id ? geoms[g].geom_id : max_id;
        total += geoms[g].prim_count;
    }
    uint32_t *index_of = malloc(((size_t)max_id + 1) * sizeof *index_of);
    size_t *base = malloc((geom_count ? geom_count : 1) * sizeof *base);
    uint8_t *marked = calloc(total ? total : 1, 1);
    /* the slot above each leaf, for its box (UINT64_MAX: the root leaf) */
    uint64_t *slot_of = malloc((t->leaf_count ? t->leaf_count : 1) * sizeof *slot_of);
    rtk_error err = RTK_OK;
    if (!index_of || !base || !marked || !slot_of) {
        err = RTK_ERROR_OUT_OF_MEMORY;
        if (msg && size)
            snprintf(msg, size, "out of memory checking the tree against the scene");
        goto done;
    }
    memset(index_of, 0xff, ((size_t)max_id + 1) * sizeof *index_of);
    for (uint32_t g = 0, b = 0; g < geom_count; g++) {
        index_of[geoms[g].geom_id] = g;
        base[g] = b;
        b += geoms[g].prim_count;
    }
    for (uint64_t j = 0; j < t->leaf_count; j++)
        slot_of[j] = UINT64_MAX;
    for (uint64_t s = 0; s < t->node_count * t->width; s++)
        if (is_leaf(t->children[s]))
            slot_of[t->children[s] & ~RTK_BVH_LEAF_BIT] = s;

    for (uint64_t j = 0; j < t->leaf_count; j++) {
        for (uint64_t k = t->leaf_first[j]; k < t->leaf_first[j + 1]; k++) {
            const rtk_bvh_prim p = t->prims[k];
            const uint32_t g = p.geom_id <= max_id ? index_of[p.geom_id] : UINT32_MAX;
            if (g == UINT32_MAX) {
                err = bad(msg, size, "leaf %llu: geometry %u is not attached, enabled and committed",
                          (unsigned long long)j, p.geom_id);
                goto done;
            }
            if (p.prim_id >= geoms[g].prim_count) {
                err = bad(msg, size, "leaf %llu: geometry %u has no triangle %u (it has %zu)", (unsigned long long)j,
                          p.geom_id, p.prim_id, geoms[g].prim_count);
                goto done;
            }
            if (marked[base[g] + p.prim_id]) {
                err = bad(msg, size, "leaf %llu: triangle %u of geometry %u is in the tree twice",
                          (unsigned long long)j, p.prim_id, p.geom_id);
                goto done;
            }
            marked[base[g] + p.prim_id] = 1;
            const uint32_t *tri = triangle_at(&geoms[g], p.prim_id);
            const float *v[3] = {vertex_at(&geoms[g], tri[0]), vertex_at(&geoms[g], tri[1]),
                                 vertex_at(&geoms[g], tri[2])};
            if (!rtk_triangle_is_finite(v[0], v[1], v[2]) || rtk_triangle_is_degenerate(v[0], v[1], v[2])) {
                err = bad(msg, size,
                          "leaf %llu: triangle %u of geometry %u can never be hit (zero area or a non-finite "
                          "vertex), so it cannot be in a tree",
                          (unsigned long long)j, p.prim_id, p.geom_id);
                goto done;
            }
            if (slot_of[j] == UINT64_MAX)
                continue;
            const float *lo = t->child_lower + 3 * slot_of[j], *hi = t->child_upper + 3 * slot_of[j];
            for (int m = 0; m < 3; m++)
                if (!box_contains(lo, hi, v[m], v[m])) {
                    err = bad(msg, size, "leaf %llu: triangle %u of geometry %u is not inside the leaf's box",
                              (unsigned long long)j, p.prim_id, p.geom_id);
                    goto done;
                }
        }
    }
    /* Every triangle that can be hit must be there; the others are the
     * ones the tree leaves out, counted as a build counts them. */
    for (uint32_t g = 0; g < geom_count; g++)
        for (size_t p = 0; p < geoms[g].prim_count; p++) {
            if (marked[base[g] + p])
                continue;
            const uint32_t *tri = triangle_at(&geoms[g], p);
            const float *v0 = vertex_at(&geoms[g], tri[0]), *v1 = vertex_at(&geoms[g], tri[1]),
                        *v2 = vertex_at(&geoms[g], tri[2]);
            if (!rtk_triangle_is_finite(v0, v1, v2)) {
                (*non_finite)++;
            } else if (rtk_triangle_is_degenerate(v0, v1, v2)) {
                (*degenerate)++;
            } else {
                err = bad(msg, size, "triangle %zu of geometry %u can be hit but is not in the tree", p,
                          geoms[g].geom_id);
                goto done;
            }
        }
done:
    free(index_of);
    free(base);
    free(marked);
    free(slot_of);
    return err;
}

rtk_error rtk_bvh_alloc(rtk_bvh *t, uint32_t width, uint64_t nodes, uint64_t leaves, uint64_t prims)
{
    *t = (rtk_bvh){.struct_size = sizeof *t, .width = width};
    const size_t slots = (size_t)nodes * width;
    t->child_lower = malloc((slots ? slots : 1) * 3 * sizeof(float));
    t->child_upper = malloc((slots ? slots : 1) * 3 * sizeof(float));
    t->children = malloc((slots ? slots : 1) * sizeof(uint32_t));
    t->leaf_first = malloc((leaves + 1) * sizeof(uint64_t));
    t->prims = malloc((prims ? prims : 1) * sizeof(rtk_bvh_prim));
    if (!t->child_lower || !t->child_upper || !t->children || !t->leaf_first || !t->prims) {
        rtk_bvh_free(t);
        return RTK_ERROR_OUT_OF_MEMORY;
    }
    return RTK_OK;
}

void rtk_bvh_free(rtk_bvh *t)
{
    if (!t)
        return;
    free(t->child_lower);
    free(t->child_upper);
    free(t->children);
    free(t->leaf_first);
    free(t->prims);
    t->child_lower = t->child_upper = NULL;
    t->children = NULL;
    t->leaf_first = NULL;
    t->prims = NULL;
    t->node_count = t->leaf_count = t->prim_count = 0;
    t->root = RTK_BVH_EMPTY;
}
