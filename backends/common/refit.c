/*
 * Refit (rtk_backend.h, rtk_accel_refit): a built accel keeps its tree and
 * takes its geometries' new vertex positions.  Every leaf block is written
 * again as a build writes it (build_write_block: the same floats a build of
 * the same tree would hold), and every box is recomputed bottom-up from its
 * leaves' triangles, so the boxes are as tight as the tree allows and the
 * answers are a rebuild's (only the tree's shape, and so its speed, is the
 * old one).  A triangle that spatial splits put in several leaves is whole
 * in each of them again: its parts' planes are not kept.
 *
 * If the triangles that go in the tree now (build_hittable: those that
 * can be hit, and a deforming geometry's zero-area and tiny ones) are not the ones
 * it holds, RTK_REFIT_NEEDS_BUILD, and the core builds afresh.  One walk
 * of the tree does the work, as Embree's refit does: each leaf is written
 * again (reading each triangle's vertices once) and its box taken into its
 * parent's at once; subtrees below a cut are walked as tasks on the
 * build's threads.
 */
#include <stdlib.h>

#include "block_bounds.h"
#include "build_common.h"
#include "kernels.h"

/* Triangles per task of the exact check; a multiple of 64, so its tasks
 * own whole words of the bit set. */
#define REFIT_CHUNK 8192u
/* Subtrees refitted as parallel tasks: those at this depth, of which a
 * 4-wide tree has up to 256 (an 8-wide one 512 at depth 3), enough for
 * the threads to share unequal subtrees evenly. */
#define REFIT_CUT_DEPTH(width) ((width) == 8 ? 3 : 4)
#define REFIT_MAX_CUTS 512
/* Tasks per thread the cuts are grouped into (group_cuts). */
#define REFIT_TASKS_PER_THREAD 8
/* Leaf blocks ahead of the one written whose vertices (REFIT_AHEAD) and
 * vertex indices (REFIT_AHEAD_INDEX) are prefetched.  With the indices
 * alone, 2 blocks on, the written block's first vertex load was an eighth
 * of the refit's time (perf), and decoding each block twice another 6%.
 * A 871,200-triangle mesh's refit on one thread (a scratch program: best of
 * 20 frames, builds in turns): 19.2-19.8 ms before, 16.5-17.4 with 2 and
 * 4, 16.1-16.9 with 3 and 6, 16.0-16.9 with 4 and 7. */
#define REFIT_AHEAD 3
#define REFIT_AHEAD_INDEX 6

/* What a walk found: triangles that failed the checks, lanes written never
 * to hit. */
typedef struct refit_counts {
    uint64_t bad, never_hit;
} refit_counts;

typedef struct refit {
    build *bd;
    struct rtk_accel *accel;
    const uint64_t *geom_first; /* build_geom_first */
    uint64_t total;             /* triangles over all geometries */
    uint64_t *kept;             /* exact check: one bit per triangle that goes in the tree, by global index */
    double *node_sah;           /* per node: build_node_sah */
    build_counts *counts;       /* per chunk of the exact check: what it left out */
    uint64_t *kept_counts;      /* and kept */
    const uint32_t *index_of;   /* triangle4 leaves: geometry id -> index in the input */
    uint32_t max_id;
    uint32_t cuts[REFIT_MAX_CUTS]; /* the subtrees refitted in parallel, in depth-first order */
    box4 cut_box[REFIT_MAX_CUTS];
    refit_counts cut_counts[REFIT_MAX_CUTS];
    uint32_t cut_count;
    /* the tasks: task t refits cuts[group[t]] to cuts[group[t + 1] - 1] */
    uint32_t group[REFIT_MAX_CUTS + 1];
    uint32_t group_count;
} refit;

/* Exact check, one chunk of triangles: which go in the tree now
 * (build_hittable). */
static void mark_kept(void *data, uint32_t chunk)
{
    refit *r = data;
    const rtk_build_input *in = r->bd->in;
    const uint64_t begin = (uint64_t)chunk * REFIT_CHUNK;
    const uint64_t end = begin + REFIT_CHUNK < r->total ? begin + REFIT_CHUNK : r->total;
    uint32_t gi = build_geometry_of(r->geom_first, in->geometry_count, begin);
    build_counts counts = {0, 0, 0};
    uint64_t kept = 0;
    for (uint64_t i = begin; i < end; i++) {
        while (i >= r->geom_first[gi + 1])
            gi++;
        vfloat4 p[3];
        if (build_hittable(&in->geometries[gi], i - r->geom_first[gi], p, &counts)) {
            r->kept[i / 64] |= (uint64_t)1 << (i % 64);
            kept++;
        }
    }
    r->counts[chunk] = counts;
    r->kept_counts[chunk] = kept;
}

/* The triangles of leaf block k: input geometry indices and primitive
 * indices; the count, or -1 if one is not a triangle of the input. */
static int block_triangles(const refit *r, uint64_t k, uint32_t geom[4], uint32_t prim[4])
{
    const rtk_build_input *in = r->bd->in;
    int n = 0;
    for (int lane = 0; lane < 4; lane++) {
        const uint32_t p = r->bd->indexed ? r->accel->trisi[k].prim[lane] : r->accel->tris[k].prim[lane];
        if (p == RTK_BVH4_EMPTY)
            break; /* the used lanes come first */
        uint32_t g;
        if (r->bd->indexed) {
            g = r->accel->trisi[k].geom[lane];
        } else {
            const uint32_t id = r->accel->tris[k].geom[lane];
            g = id <= r->max_id ? r->index_of[id] : UINT32_MAX;
        }
        if (g >= in->geometry_count || p >= in->geometries[g].prim_count)
            return -1;
        geom[n] = g;
        prim[n++] = p;
    }
    return n;
}

/* One walk's state (a task's, or the whole tree's on one thread): its
 * counts, and the blocks decoded ahead (block_triangles) for their
 * prefetch, kept for when they are written: block k in slot k % 8. */
#define REFIT_RING 8
typedef struct refit_walk {
    refit_counts counts;
    uint64_t block[REFIT_RING]; /* UINT64_MAX: nothing */
    int n[REFIT_RING];
    uint32_t geom[REFIT_RING][4], prim[REFIT_RING][4];
} refit_walk;

static void walk_init(refit_walk *w)
{
    w->counts = (refit_counts){0, 0};
    for (int i = 0; i < REFIT_RING; i++)
        w->block[i] = UINT64_MAX;
}

/* The blocks of leaf `ref` checked (every triangle finite, and with the
 * exact check one that goes in the tree) and written again; returns their
 * box. */
static box4 refit_leaf(const refit *r, uint32_t ref, refit_walk *w)
{
    _Static_assert(REFIT_AHEAD < REFIT_AHEAD_INDEX && REFIT_AHEAD_INDEX < REFIT_RING,
                   "the ring holds the blocks decoded ahead");
    box4 box = box_empty();
    refit_counts *c = &w->counts;
    const uint32_t first = rtk_leaf_first(ref);
    for (uint32_t k = first; k < first + rtk_leaf_blocks(ref); k++) {
        /* the leaves lie in walk order: the block REFIT_AHEAD_INDEX on is
         * decoded and its vertex indices fetched, and the vertices of the
         * block REFIT_AHEAD on, whose indices came in some blocks ago */
        const rtk_build_geometry *gs = r->bd->in->geometries;
        if (k + REFIT_AHEAD_INDEX < r->accel->leaf_count) {
            const int a = (k + REFIT_AHEAD_INDEX) % REFIT_RING;
            const int m = w->n[a] = block_triangles(r, k + REFIT_AHEAD_INDEX, w->geom[a], w->prim[a]);
            w->block[a] = k + REFIT_AHEAD_INDEX;
            for (int j = 0; j < m; j++)
                __builtin_prefetch(triangle_at(&gs[w->geom[a][j]], w->prim[a][j]));
        }
        const int b = (k + REFIT_AHEAD) % REFIT_RING;
        if (w->block[b] == k + REFIT_AHEAD)
            for (int j = 0; j < w->n[b]; j++) {
                const uint32_t *tri = triangle_at(&gs[w->geom[b][j]], w->prim[b][j]);
                for (int e = 0; e < 3; e++)
                    __builtin_prefetch(vertex_at(&gs[w->geom[b][j]], tri[e]));
            }
        const int s = k % REFIT_RING;
        if (w->block[s] != k) {
            w->n[s] = block_triangles(r, k, w->geom[s], w->prim[s]);
            w->block[s] = k;
        }
        const int n = w->n[s];
        const uint32_t *geom = w->geom[s], *prim = w->prim[s];
        if (n <= 0) {
            c->bad++;
            continue;
        }
        for (int j = 0; r->kept && j < n; j++) {
            const uint64_t i = r->geom_first[geom[j]] + prim[j];
            c->bad += !(r->kept[i / 64] >> (i % 64) & 1);
        }
        int finite = 1;
        c->never_hit += build_write_block(r->bd, k, geom, prim, (uint32_t)n, &box, &finite);
        c->bad += !finite;
    }
    return box;
}

/* The slots of node v's children in the order their builder placed them
 * (rtk_accel.leaves_first): in a tree of the SAH builders (build_sah.c,
 * build_inner) its leaves first, then its inner children's subtrees, each
 * in slot order; in others (the Morton builder, imported trees) in slot
 * order.  The walk then reads the leaf blocks in the order they lie, as
 * refit_leaf's prefetch of the block REFIT_AHEAD on assumes.  (Walked in
 * slot order, a SAH tree of the dragon took 36-37 ms per refit instead of
 * 30-31.  The slots listed in an array instead of the two masks cost a
 * Morton tree's refit about 4%.)  order[0], then order[1]: the slots to
 * visit, as bit masks. */
static void walk_order(const node_view *v, int width, int leaves_first, unsigned order[2])
{
    unsigned leaves = 0, inner = 0;
    for (int c = 0; c < width; c++) {
        const uint32_t ch = v->child[c];
        if (ch != RTK_BVH4_EMPTY)
            *(ch & RTK_BVH4_LEAF_BIT ? &leaves : &inner) |= 1u << c;
    }
    order[0] = leaves_first ? leaves : leaves | inner;
    order[1] = leaves_first ? inner : 0;
}

/* The subtree `ref` refitted: its leaves written (refit_leaf) and its
 * nodes' boxes; returns the subtree's box.  Above the cut (depth < cut),
 * the subtrees at the cut were refitted already: their boxes are taken in
 * depth-first order from r->cut_box through *next.  Depth is at most
 * RTK_BVH4_MAX_DEPTH. */
static box4 refit_subtree(refit *r, uint32_t ref, int depth, int cut, uint32_t *next, refit_walk *w)
{
    if (depth == cut || (cut > 0 && (ref & RTK_BVH4_LEAF_BIT)))
        return r->cut_box[(*next)++];
    if (ref & RTK_BVH4_LEAF_BIT)
        return refit_leaf(r, ref, w);
    box4 all = box_empty();
    node_view v = view_node(r->bd, r->bd->nodes, ref);
    unsigned order[2];
    walk_order(&v, r->bd->width, (int)r->accel->leaves_first, order);
    for (int k = 0; k < 2; k++)
        for (unsigned m = order[k]; m; m &= m - 1) {
            const int c = __builtin_ctz(m);
            const box4 b = refit_subtree(r, v.child[c], depth + 1, cut, next, w);
            _Alignas(16) float lo[4], hi[4];
            vf4_store(lo, b.lo);
            vf4_store(hi, b.hi);
            v.lx[c] = lo[0], v.ly[c] = lo[1], v.lz[c] = lo[2];
            v.ux[c] = hi[0], v.uy[c] = hi[1], v.uz[c] = hi[2];
            box_grow(&all, b.lo, b.hi);
        }
    r->node_sah[ref] = build_node_sah(r->bd, ref); /* while the node is in the cache */
    return all;
}

/* The subtrees at depth `cut` (and leaves above it), in depth-first order. */
static void collect_cuts(refit *r, uint32_t ref, int depth, int cut)
{
    if (depth == cut || (ref & RTK_BVH4_LEAF_BIT)) {
        r->cuts[r->cut_count++] = ref;
        return;
    }
    node_view v = view_node(r->bd, r->bd->nodes, ref);
    unsigned order[2];
    walk_order(&v, r->bd->width, (int)r->accel->leaves_first, order);
    for (int k = 0; k < 2; k++)
        for (unsigned m = order[k]; m; m &= m - 1)
            collect_cuts(r, v.child[__builtin_ctz(m)], depth + 1, cut);
}

static void refit_cut(void *data, uint32_t t)
{
    refit *r = data;
    for (uint32_t i = r->group[t]; i < r->group[t + 1]; i++) {
        uint32_t unused = 0;
        refit_walk w; /* on the stack: the tasks' entries share cache lines */
        walk_init(&w);
        r->cut_box[i] = refit_subtree(r, r->cuts[i], 0, -1, &unused, &w);
        r->cut_counts[i] = w.counts;
    }
}

/* The first leaf block of subtree ref in walk order. */
static uint32_t first_block(const refit *r, uint32_t ref)
{
    while (!(ref & RTK_BVH4_LEAF_BIT)) {
        const node_view v = view_node(r->bd, r->bd->nodes, ref);
        unsigned order[2];
        walk_order(&v, r->bd->width, (int)r->accel->leaves_first, order);
        const unsigned m = order[0] ? order[0] : order[1];
        if (!m)
            return UINT32_MAX;
        ref = v.child[__builtin_ctz(m)];
    }
    return rtk_leaf_first(ref);
}

/* The cuts as tasks of consecutive cuts, about REFIT_TASKS_PER_THREAD per
 * thread, of about equal numbers of leaf blocks: the cuts' subtrees lie one
 * after the other in the leaf array, in walk order, so where each starts
 * gives its size.  The dragon's tree has 512 subtrees at the cut, most of
 * a few hundred blocks; as a task each, two threads spent 35-39 ms of work
 * on them where one thread took 30 (timers in a scratch build), and its
 * 2-thread refit took 17.8-19.9 ms; grouped, 15.5-16.4 ms with 4 or 8
 * tasks per thread, 16.2-16.5 with 32 (rtktool bench --only refit --threads
 * 2, two runs).  A shallower cut made fewer tasks too, but San Miguel's
 * subtrees there are unequal (one of 8.7 ms of its 29), and its refit
 * slowed from 14.1 to 16.2 ms.  Where the subtrees do not lie in walk
 * order (an imported tree), each is its own task. */
static void group_cuts(refit *r)
{
    const uint64_t target = r->accel->leaf_count / ((uint64_t)build_threads(r->bd) * REFIT_TASKS_PER_THREAD) + 1;
    uint32_t start[REFIT_MAX_CUTS + 1];
    int ordered = 1;
    for (uint32_t i = 0; i < r->cut_count; i++) {
        start[i] = first_block(r, r->cuts[i]);
        ordered &= start[i] != UINT32_MAX && (i == 0 || start[i] >= start[i - 1]);
    }
    start[r->cut_count] = (uint32_t)r->accel->leaf_count;
    ordered &= r->cut_count == 0 || start[r->cut_count] >= start[r->cut_count - 1];
    r->group_count = 0;
    r->group[0] = 0;
    for (uint32_t i = 0; i < r->cut_count; i++)
        if (!ordered || start[i + 1] - start[r->group[r->group_count]] >= target || i + 1 == r->cut_count)
            r->group[++r->group_count] = i + 1;
}

/* The root's box, the whole tree refitted: the subtrees below the cut as
 * parallel tasks, then the nodes above it; *counts sums what the walks
 * found. */
static box4 refit_tree(refit *r, refit_counts *counts)
{
    const uint32_t root = r->accel->root;
    if (root == RTK_BVH4_EMPTY)
        return box_empty();
    uint32_t next = 0;
    refit_walk w;
    walk_init(&w);
    box4 box;
    if (!r->bd->tasks) { /* one thread: no cut */
        box = refit_subtree(r, root, 0, -1, &next, &w);
    } else {
        const int cut = REFIT_CUT_DEPTH(r->bd->width);
        collect_cuts(r, root, 0, cut);
        group_cuts(r);
        run_parallel(r->bd, r->group_count, refit_cut, r);
        for (uint32_t i = 0; i < r->cut_count; i++) {
            counts->bad += r->cut_counts[i].bad;
            counts->never_hit += r->cut_counts[i].never_hit;
        }
        box = refit_subtree(r, root, 0, cut, &next, &w);
    }
    counts->bad += w.counts.bad;
    counts->never_hit += w.counts.never_hit;
    return box;
}

static int refit_fail(rtk_build_output *out, int rc, const char *text)
{
    build_set_message(out, text);
    return rc;
}

int RTK_SYM(rtk_bvh_refit)(rtk_accel *accel_, const rtk_build_input *in, rtk_build_output *out)
{
    struct rtk_accel *accel = accel_;
    build bd;
    int rc = build_layout_setup(&bd, in, out);
    if (rc)
        return rc;
    if (in->layout != accel->layout)
        return refit_fail(out, RTK_ERROR_INVALID_ARGUMENT, "the input asks for another layout than the accel's");
    rtk_block_bounds_drop(accel); /* the blocks move: the next closest-point query makes new boxes */
    bd.nodes = accel->nodes;
    bd.leaves = bd.indexed ? (void *)accel->trisi : (void *)accel->tris;
    bd.ids_kept = 1; /* unwritten, so a task may read the ids of blocks ahead in another task's subtree */

    /* The quick check serves when nothing was left out for a non-finite
     * vertex or for rtk's range and every triangle is in one leaf: then
     * the tree holds every triangle of the deforming geometries, and the
     * others have not changed (rtk_accel_refit), so the walk need only
     * find every triangle still finite and within the range.  Otherwise the exact check first marks the
     * triangles that go in the tree now. */
    const uint64_t refs = out->refs ? out->refs : out->prims;
    const int has_range = out->struct_size >= offsetof(rtk_build_output, prims_out_of_range) +
                                                  sizeof out->prims_out_of_range;
    const int exact = out->prims_skipped != 0 || (has_range && out->prims_out_of_range != 0) || refs != out->prims;
    refit r = {.bd = &bd, .accel = accel};
    uint64_t *geom_first = build_geom_first(in);
    r.geom_first = geom_first;
    r.total = geom_first ? geom_first[in->geometry_count] : 0;
    const uint32_t tri_chunks = (uint32_t)((r.total + REFIT_CHUNK - 1) / REFIT_CHUNK);
    if (exact) {
        r.kept = mem_alloc(bd.mem, (r.total / 64 + 1) * sizeof *r.kept, 1);
        r.counts = calloc(tri_chunks ? tri_chunks : 1, sizeof *r.counts);
        r.kept_counts = calloc(tri_chunks ? tri_chunks : 1, sizeof *r.kept_counts);
    }
    uint32_t *index_of = bd.indexed ? NULL : build_geometry_index(in, &r.max_id);
    r.index_of = index_of;
    r.node_sah = mem_alloc(bd.mem, (accel->node_count ? accel->node_count : 1) * sizeof *r.node_sah, 0);
    if (!geom_first || (exact && (!r.kept || !r.counts || !r.kept_counts)) || (!bd.indexed && !index_of) || !r.node_sah) {
        rc = refit_fail(out, RTK_ERROR_OUT_OF_MEMORY, "out of memory for the refit");
        goto done;
    }

    build_counts left = {0, 0, 0};
    if (exact) {
        run_parallel(&bd, tri_chunks, mark_kept, &r);
        uint64_t kept = 0;
        for (uint32_t c = 0; c < tri_chunks; c++) {
            build_counts_add(&left, &r.counts[c]);
            kept += r.kept_counts[c];
        }
        if (kept != out->prims) {
            rc = RTK_REFIT_NEEDS_BUILD;
            goto done;
        }
    }

    /* The tree: leaves checked and written, boxes recomputed. */
    for (uint32_t gi = 0; bd.indexed && gi < in->geometry_count; gi++) {
        accel->geoms[gi].vertices = in->geometries[gi].vertices;
        accel->geoms[gi].stride = in->geometries[gi].vertex_stride;
    }
    refit_counts counts = {0, 0};
    const box4 bounds = refit_tree(&r, &counts);
    if (counts.bad) {
        rc = RTK_REFIT_NEEDS_BUILD;
        goto done;
    }
    if (!exact) /* left out: the unchanged geometries' zero-area triangles */
        left.degenerate = r.total - out->prims + counts.never_hit;
    bd.node_sah = r.node_sah;
    build_accel_finish(&bd, accel, accel->root, out->prims, out->depth, &bounds, out);
    if (out->struct_size >= offsetof(rtk_build_output, refs) + sizeof out->refs)
        out->refs = refs;
    build_counts_store(out, &left);

done:
    if (rc == RTK_REFIT_NEEDS_BUILD)
        build_set_message(out, "the triangles that go in the tree have changed: a vertex became or stopped being "
                               "NaN, infinite or beyond rtk's range");
    free(geom_first);
    mem_free(bd.mem, r.kept);
    free(r.counts);
    free(r.kept_counts);
    mem_free(bd.mem, r.node_sah);
    free(index_of);
    return rc;
}
