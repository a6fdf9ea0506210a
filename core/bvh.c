/*
 * The BVH as data (rtk_bvh, rtk.h): the structural check any tree must pass
 * before rtk trusts it, the check that a tree fits a scene's triangles, and
 * the memory of exported trees.  A tree that passes both checks cannot make
 * a backend read out of bounds, overflow its traversal stack or miss a hit:
 * every reference is in range, the tree is a tree of bounded depth, every
 * box contains everything below it, and every triangle is covered by the
 * boxes of the leaves that hold it.
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

/* ---- a triangle against the boxes of its leaves ----
 * Spatial splits put a triangle in several leaves, each under a box that
 * holds only part of it.  Traversal finds a hit at point x of the triangle
 * when some leaf holding it lies under boxes that contain x, so the tree
 * is right when the leaves' boxes (the slot above a leaf is the smallest
 * box on its path) together cover the triangle.  That is checked by
 * subtracting the boxes one after the other from the triangle, in double
 * precision, as convex pieces: each subtraction leaves at most six pieces
 * of a piece (the parts beyond each face).  A piece thinner than a
 * relative 2^-40 of the coordinates counts as nothing: rounding makes
 * those where boxes only touch. */

/* Convex polygons, their vertices in one growing array. */
typedef struct piece {
    size_t at; /* first vertex in pieces.v */
    int n;
} piece;

typedef struct pieces {
    piece *list;
    size_t count, cap;
    double (*v)[3];
    size_t used, vcap;
} pieces;

/* More pieces than this and the check gives up (rtk_bvh_check_fit says so). */
#define RTK_COVER_PIECES_MAX 65536u

static void pieces_free(pieces *ps)
{
    free(ps->list);
    free(ps->v);
}

/* Appends polygon v[n]; 0 when out of memory. */
static int pieces_add(pieces *ps, const double (*v)[3], int n)
{
    if (ps->count == ps->cap) {
        const size_t cap = ps->cap ? 2 * ps->cap : 16;
        piece *l = realloc(ps->list, cap * sizeof *l);
        if (!l)
            return 0;
        ps->list = l;
        ps->cap = cap;
    }
    if (ps->used + (size_t)n > ps->vcap) {
        size_t cap = ps->vcap ? 2 * ps->vcap : 64;
        while (cap < ps->used + (size_t)n)
            cap *= 2;
        double(*w)[3] = realloc(ps->v, cap * sizeof *w);
        if (!w)
            return 0;
        ps->v = w;
        ps->vcap = cap;
    }
    memcpy(ps->v + ps->used, v, (size_t)n * sizeof v[0]);
    ps->list[ps->count++] = (piece){ps->used, n};
    ps->used += (size_t)n;
    return 1;
}

/* The part of polygon in[n] with x[a] <= c (below) or x[a] >= c, into out;
 * its vertex count (at most n + 1). */
static int clip_poly(const double (*in)[3], int n, int a, double c, int below, double (*out)[3])
{
    int m = 0;
    for (int i = 0; i < n; i++) {
        const double *p = in[i], *q = in[i + 1 == n ? 0 : i + 1];
        const double dp = below ? c - p[a] : p[a] - c, dq = below ? c - q[a] : q[a] - c; /* >= 0: kept */
        if (dp >= 0.0)
            memcpy(out[m++], p, sizeof out[0]);
        if ((dp >= 0.0) != (dq >= 0.0)) {
            const double t = dp / (dp - dq);
            for (int k = 0; k < 3; k++)
                out[m][k] = p[k] + t * (q[k] - p[k]);
            out[m++][a] = c;
        }
    }
    return m;
}

/* Whether polygon v[n], beyond the plane x[a] = c, is more than a sliver. */
static int thick(const double (*v)[3], int n, int a, double c, double tol)
{
    double depth = 0.0;
    for (int i = 0; i < n; i++)
        depth = fmax(depth, fabs(v[i][a] - c));
    return n >= 3 && depth > tol;
}

/* A reference to a triangle whose leaf's box holds only part of it. */
typedef struct part_ref {
    size_t triangle; /* global index */
    uint64_t slot;   /* the slot above the leaf */
    uint32_t geom, prim;
} part_ref;

static int part_ref_order(const void *a, const void *b)
{
    const part_ref *x = a, *y = b;
    if (x->triangle != y->triangle)
        return x->triangle < y->triangle ? -1 : 1;
    return x->slot < y->slot ? -1 : x->slot > y->slot;
}

/* Whether the boxes of the slots above parts[0, n) (one triangle's, with
 * vertices v) cover the triangle: 1, 0, -1 when it takes more than
 * RTK_COVER_PIECES_MAX pieces, -2 when out of memory. */
static int triangle_covered(const float *const v[3], const rtk_bvh *t, const part_ref *parts, size_t n)
{
    double scale = 0.0, tri[3][3];
    for (int i = 0; i < 3; i++)
        for (int k = 0; k < 3; k++) {
            tri[i][k] = v[i][k];
            scale = fmax(scale, fabs(tri[i][k]));
        }
    const double tol = scale * 0x1p-40;
    pieces cur = {0}, next = {0};
    double(*a_buf)[3] = NULL, (*b_buf)[3] = NULL;
    int buf_cap = 0, result = -2;
    if (!pieces_add(&cur, (const double(*)[3])tri, 3))
        goto done;
    for (size_t b = 0; b < n && cur.count; b++) {
        const float *lo = t->child_lower + 3 * parts[b].slot, *hi = t->child_upper + 3 * parts[b].slot;
        next.count = next.used = 0;
        for (size_t i = 0; i < cur.count; i++) {
            /* what of piece i lies outside box b, face by face; each clip
             * adds at most one vertex */
            int m = cur.list[i].n;
            if (m + 7 > buf_cap) {
                buf_cap = 2 * (m + 7);
                double(*x)[3] = realloc(a_buf, (size_t)buf_cap * sizeof *x);
                if (x)
                    a_buf = x;
                double(*y)[3] = x ? realloc(b_buf, (size_t)buf_cap * sizeof *y) : NULL;
                if (!y)
                    goto done;
                b_buf = y;
            }
            double(*in)[3] = a_buf, (*out)[3] = b_buf;
            memcpy(in, cur.v + cur.list[i].at, (size_t)m * sizeof in[0]);
            for (int axis = 0; axis < 3 && m >= 3; axis++)
                for (int side = 0; side < 2 && m >= 3; side++) {
                    const double c = side ? hi[axis] : lo[axis];
                    /* beyond the face: x[axis] <= lo or x[axis] >= hi */
                    const int k = clip_poly((const double(*)[3])in, m, axis, c, !side, out);
                    if (thick((const double(*)[3])out, k, axis, c, tol) &&
                        !pieces_add(&next, (const double(*)[3])out, k))
                        goto done;
                    m = clip_poly((const double(*)[3])in, m, axis, c, side, out);
                    double(*swap)[3] = in;
                    in = out;
                    out = swap;
                }
        }
        const pieces p = cur;
        cur = next;
        next = p;
        if (cur.count > RTK_COVER_PIECES_MAX) {
            result = -1;
            goto done;
        }
    }
    result = cur.count == 0;
done:
    pieces_free(&cur);
    pieces_free(&next);
    free(a_buf);
    free(b_buf);
    return result;
}

rtk_error rtk_bvh_check_fit(const rtk_bvh *t, const rtk_build_geometry *geoms, uint32_t geom_count,
                            uint64_t *non_finite, uint64_t *degenerate, uint64_t *out_of_range, uint64_t *in_tree,
                            char *msg, size_t size)
{
    *non_finite = *degenerate = *out_of_range = *in_tree = 0;
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
    part_ref *parts = NULL;
    size_t part_count = 0, part_cap = 0;
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
            const uint32_t *tri = triangle_at(&geoms[g], p.prim_id);
            const float *v[3] = {vertex_at(&geoms[g], tri[0]), vertex_at(&geoms[g], tri[1]),
                                 vertex_at(&geoms[g], tri[2])};
            const size_t at = base[g] + p.prim_id;
            const enum rtk_triangle_class kind = rtk_triangle_classify(v[0], v[1], v[2]);
            const int flat = kind == RTK_TRIANGLE_DEGENERATE || kind == RTK_TRIANGLE_TINY;
            if (flat && (geoms[g].flags & RTK_BUILD_GEOMETRY_DEFORMS)) {
                marked[at] = 2; /* kept for a refit, never hit: no box needs to hold it */
                continue;
            }
            if (kind != RTK_TRIANGLE_HITTABLE) {
                err = bad(msg, size,
                          "leaf %llu: triangle %u of geometry %u can never be hit (zero area, a non-finite "
                          "vertex, or outside rtk's range), so it cannot be in a tree",
                          (unsigned long long)j, p.prim_id, p.geom_id);
                goto done;
            }
            /* Inside the leaf's box, or else part of it is: the parts are
             * checked below. */
            int inside = 1;
            if (slot_of[j] != UINT64_MAX) {
                const float *lo = t->child_lower + 3 * slot_of[j], *hi = t->child_upper + 3 * slot_of[j];
                for (int m = 0; m < 3; m++)
                    inside &= box_contains(lo, hi, v[m], v[m]);
            }
            if (inside) {
                marked[at] = 2;
                continue;
            }
            if (!marked[at])
                marked[at] = 1;
            if (part_count == part_cap) {
                size_t cap = part_cap ? 2 * part_cap : 256;
                part_ref *grown = realloc(parts, cap * sizeof *parts);
                if (!grown) {
                    err = RTK_ERROR_OUT_OF_MEMORY;
                    if (msg && size)
                        snprintf(msg, size, "out of memory checking the tree against the scene");
                    goto done;
                }
                parts = grown;
                part_cap = cap;
            }
            parts[part_count++] = (part_ref){.triangle = at, .slot = slot_of[j], .geom = g, .prim = p.prim_id};
        }
    }
    /* Triangles held only in parts: together the parts' boxes must cover them. */
    if (part_count)
        qsort(parts, part_count, sizeof *parts, part_ref_order);
    for (size_t i = 0, e; i < part_count; i = e) {
        for (e = i + 1; e < part_count && parts[e].triangle == parts[i].triangle;)
            e++;
        if (marked[parts[i].triangle] == 2)
            continue;
        const size_t n = e - i;
        const rtk_build_geometry *geo = &geoms[parts[i].geom];
        const uint32_t *tri = triangle_at(geo, parts[i].prim);
        const float *v[3] = {vertex_at(geo, tri[0]), vertex_at(geo, tri[1]), vertex_at(geo, tri[2])};
        const int covered = triangle_covered(v, t, parts + i, n);
        if (covered == -2) {
            err = RTK_ERROR_OUT_OF_MEMORY;
            if (msg && size)
                snprintf(msg, size, "out of memory checking the tree against the scene");
            goto done;
        }
        if (covered != 1) {
            err = bad(msg, size,
                      covered == 0 ? "triangle %u of geometry %u: the boxes of the %zu leaves that hold it do not "
                                     "cover it"
                                   : "triangle %u of geometry %u: the boxes of the %zu leaves that hold it cut it "
                                     "into too many pieces to check",
                      parts[i].prim, geo->geom_id, n);
            goto done;
        }
    }
    /* Every triangle that can be hit must be there; all are counted as a
     * build counts them. */
    for (uint32_t g = 0; g < geom_count; g++)
        for (size_t p = 0; p < geoms[g].prim_count; p++) {
            const int marks = marked[base[g] + p] != 0;
            *in_tree += (uint64_t)marks;
            const uint32_t *tri = triangle_at(&geoms[g], p);
            const float *v0 = vertex_at(&geoms[g], tri[0]), *v1 = vertex_at(&geoms[g], tri[1]),
                        *v2 = vertex_at(&geoms[g], tri[2]);
            const enum rtk_triangle_class kind = rtk_triangle_classify(v0, v1, v2);
            if (kind == RTK_TRIANGLE_NON_FINITE) {
                (*non_finite)++; /* never marked: refused above */
            } else if (kind == RTK_TRIANGLE_FAR ||
                       (kind == RTK_TRIANGLE_TINY && !(geoms[g].flags & RTK_BUILD_GEOMETRY_DEFORMS))) {
                (*out_of_range)++;
            } else if (kind != RTK_TRIANGLE_HITTABLE) { /* no area, or a deforming geometry's tiny one */
                (*degenerate)++;
            } else if (!marks) {
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
    free(parts);
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
