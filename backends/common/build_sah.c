/*
 * Binned SAH builder for the bvh4.triangle4, bvh8.triangle4 and
 * bvh4.triangle4i layouts (object splits only), parallel and deterministic.
 *
 * Builds the N-wide tree directly, as Embree's builders do: a node starts
 * with one child holding all its primitives, and the child with the largest
 * surface area is split with a binned SAH split (Wald 2007, RTK_SAH_BINS bins
 * per axis) until the node has N children or no child has more than a
 * leaf's worth of triangles.  The SAH counts leaf cost in blocks of four
 * triangles (a leaf tests four triangles for the price of one), so a range of
 * up to four triangles always becomes a leaf.
 *
 * How one range is split in two (binned object splits, the bins of its
 * sides made by its partition, spatial splits, stage 1's chunked splits)
 * is build_split.c's; this file builds the tree from those splits.
 *
 * The three stages of the Embree paper, on in->tasks (rtk_task_system):
 *  1. Nodes over RTK_TOP_MIN or more triangles (top nodes) are split with
 *     the references binned and partitioned in chunks.  While fewer top
 *     nodes are waiting than there are threads (the root, on two threads),
 *     all threads run the chunks of one; the rest are tasks of a queue
 *     (build_queue), each split by one thread, largest first.
 *  2. Every child under that size is a subtree task in the same queue,
 *     built by one thread into arrays of its own (nodes with local
 *     references, leaves as ranges of references), while other threads
 *     still split top nodes.
 *  3. Once the sizes are known, each subtree is copied to its place in the
 *     final arrays (the top nodes first, in the order of a depth-first walk,
 *     then the subtrees in the order that walk meets them) and its leaf
 *     blocks written, again in parallel.
 * The chunks, the stage a node falls in and the place of every subtree depend
 * on the triangle counts alone, and chunk results are combined in chunk
 * order whichever threads ran them, so the tree is the same, byte for byte,
 * on any number of threads.
 *
 * Past depth RTK_SAH_MEDIAN_DEPTH the builder falls back to median splits,
 * so no tree is deeper than RTK_BVH4_MAX_DEPTH whatever the input.
 */
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "build_split.h"
#include "kernels.h"
#include "geometry/triangle.h"

#define RTK_SAH_MEDIAN_DEPTH 30
/* Stage 1 takes nodes of at least this many references; smaller ones are
 * subtree tasks.  Chunks of stage 1 hold at least RTK_CHUNK_MIN references,
 * at most RTK_CHUNKS_MAX of them per split (build_split.h).  Stage 1's
 * passes stream the references from memory, where two threads slow each
 * other down (San Miguel's chunks: 53 ms of partitioning on one thread, 68
 * ms between two); a subtree task's fit the caches.  So stage 1 ends at 64K
 * references, not 16K: rtktool build, 2 threads, best of 8 interleaved
 * rounds: San Miguel 123 -> 114 ms, dragon 85 -> 82 (1 thread: 222 ->
 * 216).  Those meshes still make 71 and 50 subtrees of up to 59K
 * references, work for more threads than two. */
#define RTK_TOP_MIN 65536u
/* Triangles per task when the references are made. */
#define RTK_REF_CHUNK 16384u

/* References inside a part's own node array: an inner node of the same part
 * (its index there), or one of the part's external children (EXT | k): for
 * a subtree its k-th leaf, for the top nodes the k-th subtree. */
#define EXT 0x80000000u

typedef struct leafrange {
    uint32_t begin, end; /* references */
    uint32_t placed;     /* stage 3: the final leaf reference */
} leafrange;

/* The references' huge pages, and per page the subtrees over it that stage
 * 3 has not placed yet (see release_refs). */
typedef struct refpages {
    _Atomic uint32_t *users;
    size_t bytes; /* of the reservation */
} refpages;

/* A thread's node arrays of stage 2 (see build_subtree): the subtrees it
 * builds write their nodes one after another into chunks, reservations on
 * huge pages; `base` is the last chunk, `bytes` long, `used` of them taken.
 * A chunk starts with the previous chunk's address and its own size. */
typedef struct arena {
    char *base;
    size_t bytes, used;
} arena;
typedef struct arena_chunk {
    char *prev;
    size_t bytes;
} arena_chunk;
#define RTK_ARENA_CHUNK ((size_t)32 << 20)
#define RTK_ARENA_HEAD ((size_t)64) /* (a cache line, for the chunk's arena_chunk) */

/* A part of the tree in arrays of its own: the top nodes, or one subtree. */
typedef struct part {
    const build *bd;
    range r;         /* a subtree's references */
    uint32_t depth0; /* the depth of its root */
    char *nodes;     /* node_count nodes of bd->node_size bytes */
    uint32_t node_count, node_cap;
    size_t nodes_mapped; /* nodes is a reservation of this many bytes (a subtree's), else 0: malloc'd */
    int in_arena;        /* a subtree's nodes lie in its thread's arena (see build_subtree) */
    leafrange *leaves;
    uint32_t leaf_count, leaf_cap;
    uint64_t blocks;
    uint64_t refs;  /* references in the leaves */
    uint32_t depth; /* the deepest level reached */
    uint32_t root;  /* part-local reference */
    binpool pool;   /* its ranges' bins */
    const refpages *pages; /* a subtree's, in stage 3; NULL: its references' pages go back alone */
    int oom;
    uint64_t node_base, block_base; /* where stage 3 puts it */
} part;

/* ---- a part's own arrays ---- */

/* A new node of part p; UINT32_MAX (and p->oom) when out of memory. */
static uint32_t part_node(part *p)
{
    if ((p->nodes_mapped || p->in_arena) && p->node_count == p->node_cap) { /* (not expected: see build_subtree) */
        char *n = malloc((size_t)p->node_cap * p->bd->node_size);
        if (n)
            memcpy(n, p->nodes, (size_t)p->node_cap * p->bd->node_size);
        if (p->nodes_mapped)
            build_unreserve(p->bd->mem, p->nodes, p->nodes_mapped);
        p->nodes = n;
        p->nodes_mapped = 0;
        p->in_arena = 0;
        p->oom |= !n;
    }
    if (p->oom || !build_grow((void **)&p->nodes, &p->node_cap, p->node_count + 1, p->bd->node_size)) {
        p->oom = 1;
        return UINT32_MAX;
    }
    return p->node_count++;
}

static uint32_t part_leaf(part *p, uint32_t begin, uint32_t end)
{
    if (p->oom || !build_grow((void **)&p->leaves, &p->leaf_cap, p->leaf_count + 1, sizeof *p->leaves)) {
        p->oom = 1;
        return EXT;
    }
    p->leaves[p->leaf_count] = (leafrange){begin, end, 0};
    p->blocks += (end - begin + 3) / 4;
    p->refs += end - begin;
    return EXT | p->leaf_count++;
}

/* (an arena's nodes go with the arena: arenas_free) */
static void part_free_nodes(part *p)
{
    if (p->nodes_mapped)
        build_unreserve(p->bd->mem, p->nodes, p->nodes_mapped);
    else if (!p->in_arena)
        free(p->nodes);
    p->nodes = NULL;
    p->nodes_mapped = 0;
    p->in_arena = 0;
}

static void part_free(part *p)
{
    part_free_nodes(p);
    pool_release(&p->pool);
    free(p->leaves);
    p->leaves = NULL;
}

/* Writes node `index` of part p with the boxes of its nc children, child i
 * in slot slot[i]; empty slots get inverted boxes and RTK_BVH4_EMPTY.  The
 * references are set by set_child. */
static void write_node(part *p, uint32_t index, const range *child, int nc, const int *slot)
{
    if (index == UINT32_MAX)
        return;
    box4 box[8];
    for (int i = 0; i < nc; i++)
        box[slot[i]] = child[i].geom;
    build_store_node(p->bd, p->nodes, index, box, NULL, nc);
}

static void set_child(part *p, uint32_t index, int i, uint32_t ref)
{
    if (index != UINT32_MAX)
        view_node(p->bd, p->nodes, index).child[i] = ref;
}

/* The slot of each of a node's nc children (build_child_slots). */
static void child_slots(const build *bd, const range *child, int nc, int slot[8])
{
    box4 box[8];
    uint32_t count[8];
    for (int i = 0; i < nc; i++) {
        box[i] = child[i].geom;
        count[i] = child[i].end - child[i].begin;
    }
    build_child_slots(bd, box, count, nc, slot);
}

/* The children of a node over r: the child with the largest area (median:
 * the most references) is split until there are N or none has more than
 * four references.  `first`, if not NULL, is find_split's split of r.
 * Stage 1 (`parallel`) splits its large ranges with every thread.  The
 * bins of a range split go back to pool (r's among them); the children
 * keep theirs. */
static int split_children(const build *bd, binpool *pool, bins *scratch, sbins *sscratch, const range *r,
                          int median, const split *first, int parallel, range child[8])
{
    int nc = 1;
    child[0] = *r;
    while (nc < bd->width) {
        int pick = -1;
        float key = -1.0f;
        for (int i = 0; i < nc; i++) {
            uint32_t n = child[i].end - child[i].begin;
            if (n <= 4)
                continue;
            float k = median ? (float)n : box_half_area(&child[i].geom);
            if (k > key) {
                key = k;
                pick = i;
            }
        }
        if (pick < 0)
            break;
        range l, rr;
        if (parallel && !median && child[pick].end - child[pick].begin >= 2 * RTK_CHUNK_MIN)
            split_parallel(bd, pool, scratch, sscratch, &child[pick], &l, &rr);
        else
            split_range(bd, pool, &child[pick], median, nc == 1 ? first : NULL, &l, &rr);
        pool_put(pool, child[pick].bn);
        share_room(bd->refs, &child[pick], &l, &rr);
        child[pick] = l;
        child[nc++] = rr;
    }
    return nc;
}

/* ---- stage 2: a subtree on one thread ---- */

/* Whether r becomes one leaf: up to four references, or a small range
 * where the SAH says an inner node over its best split would cost more
 * than one leaf of several blocks (one box test, at the price of one block
 * of triangles, as in Embree: an inner node over a handful of triangles
 * would mostly hold empty slots).  Otherwise *first is that best split
 * when it was computed, else its axis is -1.
 *
 * The motion builder's trees (build_motion.c) price a box test at two
 * blocks (bd->node_cost).  Their nodes hold each box at a segment's start
 * and its change (416 bytes 8 wide, 208 four wide: every box twice),
 * interpolated in every test.  At one block, dragon.ply's tree at 2 time
 * steps had 55,269 nodes, at two 28,638 (leaves of more blocks, 3.50
 * triangles a block against 3.44): 48.5 bytes a triangle against 61.6
 * (Embree's 57.0), 176 against 228 at 5 steps (Embree's 195), San
 * Miguel's 47.5 and 172 against 56.9 and 208, builds up to a fifth
 * faster, and the rays traced as fast within this VM's noise (dragon at 5
 * steps: diffuse 0-20% faster over three runs; rtktool bench --only
 * motion, the two builds side by side, AMD EPYC).  Three blocks gave about
 * the same tree as two (26,985 nodes).  Static trees were tried the same
 * way (docs/benchmarks/history.md): smaller, no faster. */
static int leaf_range(part *p, const range *r, uint32_t depth, split *first)
{
    const uint32_t n = r->end - r->begin;
    first->axis = -1;
    if (n <= 4)
        return 1;
    if (n <= 4 * RTK_LEAF_MAX_BLOCKS && depth < RTK_SAH_MEDIAN_DEPTH) {
        *first = find_split(p->bd, r);
        const float area = box_half_area(&r->geom);
        if (first->axis < 0 || (float)((n + 3) / 4) * area <= p->bd->node_cost * area + first->cost) {
            pool_put(&p->pool, r->bn);
            return 1;
        }
    }
    return 0;
}

/* A node or leaf at `depth`: the subtree's depth is at least that. */
static void part_reach(part *p, uint32_t depth)
{
    if (depth > p->depth)
        p->depth = depth;
}

/* The leaf over r at `depth`. */
static uint32_t depth_leaf(part *p, const range *r, uint32_t depth)
{
    part_reach(p, depth);
    return part_leaf(p, r->begin, r->end);
}

/* The inner node over r (not a leaf by leaf_range, which gave `first`) and
 * its subtree.  Its leaf children are placed first, slot by slot, and only
 * then its inner children's subtrees, so the blocks of a node's leaves lie
 * side by side, ahead of its descendants', and the nodes follow in the same
 * depth-first order (the plain recursion strewed a node's leaves among its
 * descendants').  The same tree otherwise.  On rays from random points of
 * the mesh (a scratch driver, rtk avx2 and Embree isa=avx2 in turns) this
 * order alone measured within the noise (+0.5% on average over nine paired
 * runs on the dragon and on San Miguel); with the nodes' offset
 * (build_common.c, node_offset) 4-5% on both, which is the order that was
 * measured and kept. */
static uint32_t build_inner(part *p, const range *r, uint32_t depth, const split *first)
{
    const build *bd = p->bd;
    part_reach(p, depth);
    range child[8];
    const int nc = split_children(bd, &p->pool, NULL, NULL, r, depth >= RTK_SAH_MEDIAN_DEPTH,
                                  first->axis >= 0 ? first : NULL, 0, child);
    const uint32_t index = part_node(p);
    int slot[8] = {0, 1, 2, 3, 4, 5, 6, 7}, in_slot[8];
    child_slots(bd, child, nc, slot);
    write_node(p, index, child, nc, slot);
    for (int i = 0; i < nc; i++)
        in_slot[slot[i]] = i;
    split firsts[8];
    unsigned inner = 0;
    for (int s = 0; s < nc; s++) {
        const int i = in_slot[s];
        if (!leaf_range(p, &child[i], depth + 1, &firsts[i])) {
            inner |= 1u << s;
            continue;
        }
        set_child(p, index, s, depth_leaf(p, &child[i], depth + 1));
    }
    for (; inner; inner &= inner - 1) {
        const int s = __builtin_ctz(inner), i = in_slot[s];
        set_child(p, index, s, build_inner(p, &child[i], depth + 1, &firsts[i]));
    }
    return index;
}

static uint32_t build_node(part *p, const range *r, uint32_t depth)
{
    split first;
    return leaf_range(p, r, depth, &first) ? depth_leaf(p, r, depth) : build_inner(p, r, depth, &first);
}

/* Subtree p, built by the thread whose arena is a.  Its nodes go where
 * there is room for as many as it can have (fewer than its references, the
 * room for spatial splits included: every inner node has two children or
 * more, every leaf a reference), of which only the pages written are ever
 * memory.  That room is in the thread's arena, right behind the nodes of
 * the subtrees it built before (a new chunk when the last has too little
 * left), so the nodes of stage 2 are written on huge pages, a few subtrees
 * to a page, and stage 3 copies them all to their places before the leaves
 * (place_subtree_nodes), then gives the arenas back.  In a reservation of
 * 4 KiB pages per subtree, as before, a medium build of the 10M-triangle
 * mesh took 36,000 page faults for them, of the 49,000 it took in all
 * (perf record -e page-faults): now 12,400 in all; medium builds 3-8%
 * faster on the dragon and San Miguel, about 3% on that mesh, with the
 * same peak memory (docs/benchmarks/notes.md, session 44).  Without
 * an arena or its memory the subtree reserves its own. */
static void build_subtree(part *p, arena *a)
{
    const uint32_t n = p->r.end - p->r.begin;
    const uint32_t bound = range_room_end(&p->r) - p->r.begin + 1;
    const size_t room = (size_t)bound * p->bd->node_size;
    if (a && (!a->base || a->bytes - a->used < room)) { /* a new chunk */
        const size_t bytes = room + RTK_ARENA_HEAD > RTK_ARENA_CHUNK ? room + RTK_ARENA_HEAD : RTK_ARENA_CHUNK;
        char *chunk = build_reserve_huge(p->bd->mem, bytes);
        if (chunk) {
            *(arena_chunk *)chunk = (arena_chunk){a->base, a->bytes};
            *a = (arena){chunk, bytes, RTK_ARENA_HEAD};
        }
    }
    if (a && a->base && a->bytes - a->used >= room) {
        p->nodes = a->base + a->used;
        p->node_cap = bound;
        p->in_arena = 1;
    } else {
        p->nodes = build_reserve(p->bd->mem, room);
        if (p->nodes) {
            p->nodes_mapped = room;
            p->node_cap = bound;
        }
    }
    build_grow((void **)&p->leaves, &p->leaf_cap, n / 3 + 1, sizeof *p->leaves);
    p->root = build_node(p, &p->r, p->depth0);
    if (p->in_arena) /* the next subtree's nodes on the next cache line */
        a->used += ((size_t)p->node_count * p->bd->node_size + 63) & ~(size_t)63;
    pool_release(&p->pool); /* (its root's bins are the top's, which frees them) */
}

/* ---- stage 1: the top nodes, as tasks ---- */

/* A top node: its references, and once split its children, each another
 * top node or a subtree (kid[i], a tnode where bit i of tops is set, else
 * a part). */
typedef struct tnode {
    range r;
    uint32_t depth;
    int nc;
    unsigned tops;
    range child[8];
    int slot[8];
    void *kid[8];
    binpool pool; /* its ranges' bins (its subtrees' roots take some): freed after stage 2 */
} tnode;

/* A worker's scratch for stage 1's splits. */
typedef struct scratch {
    bins *bins;    /* 2 * RTK_CHUNKS_MAX of them */
    sbins *sbins;  /* the same, for spatial splits */
} scratch;

typedef struct top {
    part nodes; /* the top nodes; EXT | k is subtree k */
    part *subtrees;
    uint32_t subtree_count, subtree_cap;
    build serial;     /* the build, without its threads: a task's splits run on its own */
    build_queue queue;
    int queue_ready;
    scratch *scratch; /* one per thread, and the main thread's (all threads) last */
    arena *arenas;    /* one per thread */
} top;

/* Bit 0 of a queued task's key: a top node (else a subtree). */
static uint64_t task_key(const range *r, int is_top)
{
    return (uint64_t)(r->end - r->begin) << 1 | (uint64_t)is_top;
}

static int scratch_get(top *t, scratch *s)
{
    if (!s->bins)
        s->bins = aligned_alloc(_Alignof(bins), 2 * RTK_CHUNKS_MAX * sizeof *s->bins);
    if (t->nodes.bd->spatial && !s->sbins)
        s->sbins = malloc(RTK_CHUNKS_MAX * sizeof *s->sbins);
    return s->bins && (s->sbins || !t->nodes.bd->spatial);
}

/* A task over r at `depth`: a top node to split, or a subtree to build;
 * NULL when out of memory. */
static void *new_task(const build *bd, const range *r, uint32_t depth, int is_top)
{
    if (is_top) {
        tnode *n = malloc(sizeof *n);
        if (n)
            *n = (tnode){.r = *r, .depth = depth};
        return n;
    }
    part *p = malloc(sizeof *p);
    if (p)
        *p = (part){.bd = bd, .r = *r, .depth0 = depth};
    return p;
}

/* Splits top node n into its children (on bd's threads) and queues them:
 * each a top node of its own while it has RTK_TOP_MIN references or more,
 * else a subtree task.  The chunks of a split, and so the split, are the
 * same whichever threads run them. */
static void top_split(top *t, const build *bd, scratch *s, tnode *n)
{
    build_queue *q = &t->queue;
    if (!scratch_get(t, s)) {
        build_queue_fail(q);
        return;
    }
    n->nc = split_children(bd, &n->pool, s->bins, s->sbins, &n->r, n->depth >= RTK_SAH_MEDIAN_DEPTH, NULL, 1, n->child);
    for (int i = 0; i < 8; i++)
        n->slot[i] = i;
    child_slots(bd, n->child, n->nc, n->slot);
    for (int i = 0; i < n->nc; i++) {
        const int is_top = n->child[i].end - n->child[i].begin >= RTK_TOP_MIN;
        void *kid = new_task(t->nodes.bd, &n->child[i], n->depth + 1, is_top);
        if (!kid) {
            build_queue_fail(q);
            continue;
        }
        if (!build_queue_push(q, task_key(&n->child[i], is_top), kid)) { /* (which marks q out of memory) */
            free(kid);
            continue;
        }
        n->kid[i] = kid;
        n->tops |= (unsigned)is_top << i;
    }
}

static void top_task(build_queue *q, uint64_t key, void *item, uint32_t worker)
{
    top *t = q->data;
    /* once the build is told to stop, the tasks left do nothing: a top
     * node stays unsplit, a subtree unbuilt, and the build frees them */
    if (build_stopped(&t->serial))
        return;
    if (key & 1) {
        top_split(t, &t->serial, &t->scratch[worker], item);
    } else {
        part *p = item;
        build_subtree(p, t->arenas ? &t->arenas[worker] : NULL);
        build_report_work(&t->serial, p->r.end - p->r.begin, 0.1, 0.9); /* (a subtree's refs: its share) */
    }
}

/* Subtree p (built) as the next of t's subtrees; frees p. */
static uint32_t add_subtree(top *t, part *p)
{
    if (!p || t->nodes.oom ||
        !build_grow((void **)&t->subtrees, &t->subtree_cap, t->subtree_count + 1, sizeof *t->subtrees)) {
        t->nodes.oom = 1;
        if (p)
            part_free(p);
        free(p);
        return EXT;
    }
    t->subtrees[t->subtree_count] = *p;
    free(p);
    return EXT | t->subtree_count++;
}

/* The top nodes in the order of a depth-first walk (a node before its
 * children, in split order), and the subtrees in the order it meets them:
 * the order of one thread splitting them one after another.  Frees the
 * tnodes. */
static uint32_t top_place(top *t, tnode *n)
{
    part *p = &t->nodes;
    part_reach(p, n->depth);
    const uint32_t index = part_node(p);
    write_node(p, index, n->child, n->nc, n->slot);
    for (int i = 0; i < n->nc; i++) {
        const uint32_t ref = (n->tops >> i & 1) ? top_place(t, n->kid[i]) : add_subtree(t, n->kid[i]);
        set_child(p, index, n->slot[i], ref);
    }
    pool_release(&n->pool);
    free(n);
    return index;
}

/* Stages 1 and 2 of the tree over root: the top nodes split with every
 * thread while fewer of them are left than threads (the root, on two
 * threads), then the rest as tasks, each on one thread, beside the
 * subtrees as they come.  Returns the root's part-local reference. */
static uint32_t top_build(top *t, const build *bd, const range *root)
{
    const uint32_t threads = build_threads(bd);
    const int is_top = root->end - root->begin >= RTK_TOP_MIN;
    void *item = new_task(bd, root, 1, is_top);
    if (!item || !build_queue_push(&t->queue, task_key(root, is_top), item)) {
        free(item);
        t->nodes.oom = 1;
        return EXT;
    }
    for (;;) {
        uint32_t tops = 0;
        for (uint32_t i = 0; i < t->queue.count; i++)
            tops += (uint32_t)(t->queue.heap[i].key & 1);
        if (!tops || tops >= threads)
            break;
        /* the largest task is a top node: those have RTK_TOP_MIN references or more, subtrees fewer */
        top_split(t, bd, &t->scratch[threads], build_queue_pop_top(&t->queue, 1));
    }
    build_queue_run(bd, &t->queue);
    if (t->queue.oom)
        t->nodes.oom = 1;
    return is_top ? top_place(t, item) : add_subtree(t, item);
}

/* ---- stage 3: the final arrays ---- */

/* The leaf block of the (up to) four references from `first` below `end`. */
static void write_block(const build *bd, uint32_t first, uint32_t end, uint64_t index)
{
    uint32_t geom[4], prim[4], count = 0;
    for (uint32_t k = first; k < end && count < 4; k++, count++) {
        geom[count] = ref_geom(&bd->refs[k]);
        prim[count] = ref_prim(&bd->refs[k]);
    }
    build_write_block(bd, index, geom, prim, count, NULL, NULL);
}

/* Copies part p's nodes to the final array at p->node_base, turning its
 * references into final ones (and setting the nodes' prefetch[]): ext[k *
 * stride] is the final reference of external child k. */
static void place_nodes(const part *p, const uint32_t *ext, size_t stride)
{
    const build *bd = p->bd;
    if (!p->node_count)
        return;
    char *to = (char *)bd->nodes + p->node_base * bd->node_size;
    memcpy(to, p->nodes, (size_t)p->node_count * bd->node_size);
    for (uint32_t i = 0; i < p->node_count; i++) {
        const node_view v = view_node(bd, to, i);
        const char *node = to + (size_t)i * bd->node_size;
        for (int c = 0; c < bd->width; c++) {
            const uint32_t ref = v.child[c];
            if (ref != RTK_BVH4_EMPTY)
                v.child[c] = ref & EXT ? ext[(size_t)(ref & ~EXT) * stride] : (uint32_t)(p->node_base + ref);
            v.prefetch[c] = build_prefetch(bd, node, v.child[c]);
        }
    }
}

/* A subtree's final root reference (after place_subtree_nodes). */
static uint32_t subtree_root(const part *p)
{
    return p->root & EXT ? p->leaves[p->root & ~EXT].placed : (uint32_t)(p->node_base + p->root);
}

/* Prefetches the triangles of a leaf for write_block, which otherwise
 * waits on the application's arrays (perf: a quarter of its time on the
 * load of the indices): their indices, or (once those have come) their
 * vertices.  place_subtree asks for the indices eight leaves ahead, the
 * vertices four, and before both for the leaf's references themselves
 * (prefetch_refs).  An earlier try with the indices alone made no
 * difference. */
static void prefetch_leaf(const build *bd, const leafrange *l, int vertices)
{
    for (uint32_t k = l->begin; k < l->end; k++) {
        const rtk_build_geometry *g = &bd->in->geometries[ref_geom(&bd->refs[k])];
        const uint32_t *tri = triangle_at(g, ref_prim(&bd->refs[k]));
        if (!vertices) {
            __builtin_prefetch(tri);
            continue;
        }
        for (int j = 0; j < 3; j++)
            __builtin_prefetch(vertex_at(g, tri[j]));
    }
}

/* Prefetches the references of a leaf, sixteen leaves ahead of the one
 * written: written in stage 2, they have mostly left the caches by the time
 * their subtree is placed, and prefetch_leaf's loads of their ids waited on
 * memory (perf: half of place_subtree's own samples on that load, the
 * hardware's prefetcher not keeping up with a stream read between the
 * gathers of indices and vertices).  With it and the indices and vertices
 * asked for twice as far ahead as before (4 and 2 leaves), San Miguel's
 * stage 3 took 74 -> 57 million TSC cycles on one thread, 42 -> 33 on two
 * (a scratch timer around it, 8 builds per run, three rounds in turns). */
static void prefetch_refs(const build *bd, const leafrange *l)
{
    const char *at = (const char *)((uintptr_t)&bd->refs[l->begin] & ~(uintptr_t)63);
    for (const char *end = (const char *)&bd->refs[l->end]; at < end; at += 64)
        __builtin_prefetch(at);
}

/* Stage 3, first half, subtree i: its leaves' final references, and its
 * nodes copied to their place with those; its own node array then goes
 * (an arena's, with the arena after this pass). */
static void place_subtree_nodes(void *data, uint32_t i)
{
    part *p = (part *)data + i;
    uint64_t block = p->block_base;
    for (uint32_t k = 0; k < p->leaf_count; k++) {
        leafrange *l = &p->leaves[k];
        const uint32_t blocks = (l->end - l->begin + 3) / 4;
        l->placed = rtk_leaf_ref((uint32_t)block, blocks);
        block += blocks;
    }
    place_nodes(p, p->leaves ? &p->leaves[0].placed : NULL, sizeof *p->leaves / sizeof(uint32_t));
    part_free_nodes(p);
}

/* Stage 3, second half, subtree i: its leaf blocks. */
static void place_subtree_leaves(void *data, uint32_t i)
{
    part *p = (part *)data + i;
    uint64_t block = p->block_base;
    for (uint32_t k = 0; k < p->leaf_count; k++) {
        const leafrange *l = &p->leaves[k];
        if (k + 16 < p->leaf_count)
            prefetch_refs(p->bd, &p->leaves[k + 16]);
        if (k + 8 < p->leaf_count)
            prefetch_leaf(p->bd, &p->leaves[k + 8], 0);
        if (k + 4 < p->leaf_count)
            prefetch_leaf(p->bd, &p->leaves[k + 4], 1);
        const uint32_t blocks = (l->end - l->begin + 3) / 4;
        for (uint32_t b = 0; b < blocks; b++)
            write_block(p->bd, l->begin + 4 * b, l->end, block + b);
        block += blocks;
    }
}

static void place_subtree(void *data, uint32_t i)
{
    place_subtree_nodes(data, i);
    place_subtree_leaves(data, i);
}

typedef struct refspan {
    size_t lo, hi;                /* bytes into the references */
    size_t first_page, end_page; /* the huge pages they lie on */
} refspan;

/* Where subtree p's references (and the room behind them) lie. */
static refspan subtree_refs(const part *p)
{
    const size_t lo = (size_t)p->r.begin * sizeof *p->bd->refs, hi = (size_t)range_room_end(&p->r) * sizeof *p->bd->refs;
    return (refspan){.lo = lo, .hi = hi, .first_page = lo / RTK_HUGE_PAGE,
                     .end_page = hi > lo ? (hi - 1) / RTK_HUGE_PAGE + 1 : lo / RTK_HUGE_PAGE};
}

/* Gives back the pages of references only subtree p used, now placed.  On
 * huge pages, one given back in part would be split by the kernel (which
 * made stage 3 of San Miguel take 35 to 170 ms on one thread, rtktool
 * build): each huge page goes back whole, when the last subtree over it
 * has been placed. */
static void release_refs(const part *p)
{
    char *base = (char *)p->bd->refs;
    const refspan span = subtree_refs(p);
    if (!p->pages) {
        build_release_pages(base + span.lo, span.hi - span.lo);
        return;
    }
    for (size_t k = span.first_page; k < span.end_page; k++)
        if (atomic_fetch_sub_explicit(&p->pages->users[k], 1, memory_order_acq_rel) == 1) {
            const size_t at = k * RTK_HUGE_PAGE;
            build_release_pages(base + at, p->pages->bytes - at < RTK_HUGE_PAGE ? p->pages->bytes - at : RTK_HUGE_PAGE);
        }
}

/* Counts each huge page's subtrees into pages (refs reserved with
 * build_reserve_huge, `bytes` of them), for release_refs; with too few
 * references for huge pages, or no memory for the counts, the pages go
 * back per subtree. */
static void count_page_users(top *t, refpages *pages, size_t bytes)
{
    pages->users = NULL;
    pages->bytes = bytes;
    if (bytes < RTK_HUGE_PAGE)
        return;
    const size_t count = (bytes + RTK_HUGE_PAGE - 1) / RTK_HUGE_PAGE;
    pages->users = malloc(count * sizeof *pages->users);
    if (!pages->users)
        return;
    for (size_t k = 0; k < count; k++)
        atomic_init(&pages->users[k], 0);
    for (uint32_t i = 0; i < t->subtree_count; i++) {
        part *p = &t->subtrees[i];
        const refspan span = subtree_refs(p);
        for (size_t k = span.first_page; k < span.end_page; k++)
            atomic_fetch_add_explicit(&pages->users[k], 1, memory_order_relaxed);
        p->pages = pages;
    }
}

/* Gives back the arenas' memory (once stage 3 has copied their nodes). */
static void arenas_free(top *t)
{
    for (uint32_t w = 0; t->arenas && w < build_threads(t->nodes.bd); w++) {
        arena *a = &t->arenas[w];
        while (a->base) {
            const arena_chunk c = *(const arena_chunk *)a->base;
            build_unreserve(t->nodes.bd->mem, a->base, a->bytes);
            a->base = c.prev;
            a->bytes = c.bytes;
        }
        a->used = 0;
    }
}

/* Stage 3 of a build, one subtree's leaves (its nodes were placed first,
 * all subtrees' in one pass, and the arenas given back): its leaf blocks
 * written, then its references' pages given back.  The final arrays grow
 * as these shrink, so the
 * peak of a build stays near the references and the tree (dragon, medium:
 * 108 bytes per triangle when both were held to the end, against Embree's
 * 104).  The subtrees are placed in the order of their references (not
 * largest first as they were built), so that the huge pages of references
 * are given back as the placing goes: San Miguel's peak 108.5 -> 73.2
 * bytes per triangle, Embree's 99.5 (rtktool bench --only build). */
static void place_and_release(void *data, uint32_t i)
{
    place_subtree_leaves(data, i);
    release_refs((part *)data + i);
}

/* ---- the references ---- */

typedef struct refgen {
    const build *bd;
    const uint64_t *geom_first; /* global index of each geometry's first triangle; [count] = total */
    uint64_t total;
    uint32_t chunks;
    uint32_t *kept;  /* per chunk: references written from the chunk's start */
    build_counts *counts; /* what it left out */
    range *bounds;
} refgen;

/* Chunk k: triangles [k, k + 1) * RTK_REF_CHUNK of the concatenated
 * geometries; the hittable ones become references from the chunk's first
 * slot on.  Triangles with a non-finite vertex or no area cannot be hit and
 * are left out. */
static void make_refs(void *data, uint32_t k)
{
    refgen *g = data;
    const rtk_build_input *in = g->bd->in;
    const uint64_t begin = (uint64_t)k * RTK_REF_CHUNK;
    const uint64_t end = begin + RTK_REF_CHUNK < g->total ? begin + RTK_REF_CHUNK : g->total;
    uint32_t gi = build_geometry_of(g->geom_first, in->geometry_count, begin);
    range bounds; /* on the stack: chunks' entries in g->bounds share cache lines */
    range_init(&bounds, 0, 0);
    primref *out = g->bd->refs + begin;
    uint32_t n = 0;
    build_counts counts = {0, 0, 0};
    for (uint64_t i = begin; i < end; i++) {
        while (i >= g->geom_first[gi + 1])
            gi++;
        const size_t prim = (size_t)(i - g->geom_first[gi]);
        vfloat4 p[3];
        if (!build_hittable(&in->geometries[gi], prim, p, &counts))
            continue;
        primref *ref = &out[n++];
        const vfloat4 blo = vf4_min(vf4_min(p[0], p[1]), p[2]), bhi = vf4_max(vf4_max(p[0], p[1]), p[2]);
        range_add(&bounds, blo, bhi);
        vf4_store(ref->lo, blo);
        vf4_store(ref->hi, bhi);
        ref->lo[3] = rtk_bits_float(gi);
        ref->hi[3] = rtk_bits_float((uint32_t)prim);
    }
    g->bounds[k] = bounds;
    g->kept[k] = n;
    g->counts[k] = counts;
}

/* ---- the builder ---- */

static void free_parts(top *t)
{
    part_free(&t->nodes);
    for (uint32_t i = 0; i < t->subtree_count; i++)
        part_free(&t->subtrees[i]);
    free(t->subtrees);
    if (t->scratch)
        for (uint32_t i = 0; i <= build_threads(t->nodes.bd); i++) {
            free(t->scratch[i].bins);
            free(t->scratch[i].sbins);
        }
    free(t->scratch);
    arenas_free(t);
    free(t->arenas);
    if (t->queue_ready)
        build_queue_free(&t->queue);
}

static int build_sah(const rtk_build_input *in, rtk_build_output *out, int spatial, float node_cost)
{
    uint64_t total;
    build bd;
    int rc = build_begin(&bd, in, out, &total);
    if (rc)
        return rc;
    bd.node_cost = node_cost;
    build_progress progress;
    build_progress_init(&bd, &progress, total);
    /* Room for the references spatial splits add, while every leaf block
     * (at least one reference each) stays addressable. */
    uint64_t room = spatial ? total / RTK_SPATIAL_ROOM_DIV : 0;
    if (total + room >= RTK_LEAF_INDEX_LIMIT)
        room = RTK_LEAF_INDEX_LIMIT - 1 - total;
    bd.spatial = room > 0;
    const size_t ref_bytes = (total + room ? total + room : 1) * sizeof *bd.refs;
    bd.refs = build_reserve_huge(bd.mem, ref_bytes);
    refgen g = {.bd = &bd, .total = total, .chunks = (uint32_t)((total + RTK_REF_CHUNK - 1) / RTK_REF_CHUNK)};
    const size_t nc = g.chunks ? g.chunks : 1;
    uint64_t *geom_first = build_geom_first(in);
    g.geom_first = geom_first;
    g.kept = malloc(nc * sizeof *g.kept);
    g.counts = malloc(nc * sizeof *g.counts);
    g.bounds = malloc(nc * sizeof *g.bounds);
    refpages pages = {0};
    top t = {.nodes = {.bd = &bd}, .scratch = calloc(build_threads(&bd) + 1, sizeof *t.scratch)};
    t.queue_ready = build_queue_init(&t.queue, top_task, &t);
    if (!bd.refs || !geom_first || !g.kept || !g.counts || !g.bounds || !t.scratch ||
        !t.queue_ready) {
        rc = RTK_ERROR_OUT_OF_MEMORY;
        build_set_message(out, "out of memory for the build's primitive references");
        goto done;
    }

    /* The references, in input order: each chunk's kept ones are moved
     * down behind the previous chunk's. */
    run_parallel(&bd, g.chunks, make_refs, &g);
    range root;
    range_init(&root, 0, 0);
    uint32_t n = 0;
    build_counts counts = {0, 0, 0};
    for (uint32_t k = 0; k < g.chunks; k++) {
        const uint64_t from = (uint64_t)k * RTK_REF_CHUNK;
        if (n != from && g.kept[k])
            memmove(bd.refs + n, bd.refs + from, (size_t)g.kept[k] * sizeof *bd.refs);
        n += g.kept[k];
        build_counts_add(&counts, &g.counts[k]);
        range_merge(&root, &g.bounds[k]);
    }
    root.end = n;
    if (build_report(&bd, 0.1)) {
        rc = RTK_ERROR_CANCELLED;
        build_set_message(out, "cancelled by the progress callback");
        goto done;
    }
    /* the room, from the triangles kept */
    root.ext = n + (uint32_t)(room * n / (total ? total : 1));
    bd.spatial_overlap = RTK_SPATIAL_ALPHA * box_half_area(&root.geom);

    /* The arenas (see build_subtree; without them every subtree reserves
     * its own node array). */
    t.arenas = calloc(build_threads(&bd), sizeof *t.arenas);

    /* Stages 1 and 2. */
    uint32_t root_local = RTK_BVH4_EMPTY;
    t.serial = bd;
    t.serial.tasks = NULL;
    if (n)
        root_local = top_build(&t, &bd, &root);
    if (build_stopped(&bd)) {
        rc = RTK_ERROR_CANCELLED;
        build_set_message(out, "cancelled by the progress callback");
        goto done;
    }
    if (t.nodes.oom) {
        rc = RTK_ERROR_OUT_OF_MEMORY;
        build_set_message(out, "out of memory for the BVH");
        goto done;
    }

    /* Places: the top nodes, then the subtrees in the order stage 1 found them. */
    uint64_t nodes = t.nodes.node_count, blocks = 0, refs = 0;
    uint32_t depth = t.nodes.depth;
    int oom = 0;
    for (uint32_t i = 0; i < t.subtree_count; i++) {
        part *p = &t.subtrees[i];
        p->node_base = nodes;
        p->block_base = blocks;
        nodes += p->node_count;
        blocks += p->blocks;
        refs += p->refs;
        depth = p->depth > depth ? p->depth : depth;
        oom |= p->oom;
    }
    /* (the last point where the build may stop, or fail for memory, with
     * nothing written into a recycled tree: roots is allocated first) */
    uint32_t *roots = oom ? NULL : malloc((t.subtree_count ? t.subtree_count : 1) * sizeof *roots);
    if (roots && build_report(&bd, 0.95)) {
        free(roots);
        rc = RTK_ERROR_CANCELLED;
        build_set_message(out, "cancelled by the progress callback");
        goto done;
    }
    struct rtk_accel *accel = roots ? build_accel_alloc(&bd, nodes, blocks) : NULL;
    if (!accel) {
        free(roots);
        rc = RTK_ERROR_OUT_OF_MEMORY;
        build_set_message(out, "out of memory for the BVH");
        goto done;
    }
    accel->leaves_first = 1; /* (build_inner) */
    count_page_users(&t, &pages, ref_bytes);
    run_parallel(&bd, t.subtree_count, place_subtree_nodes, t.subtrees);
    arenas_free(&t);
    run_parallel(&bd, t.subtree_count, place_and_release, t.subtrees);
    for (uint32_t i = 0; i < t.subtree_count; i++)
        roots[i] = subtree_root(&t.subtrees[i]);
    place_nodes(&t.nodes, roots, 1);
    const uint32_t root_ref = root_local == RTK_BVH4_EMPTY ? RTK_BVH4_EMPTY
                              : root_local & EXT            ? roots[root_local & ~EXT]
                                                            : root_local;
    free(roots);
    build_accel_finish(&bd, accel, root_ref, n, depth, &root.geom, out);
    if (out->struct_size >= offsetof(rtk_build_output, refs) + sizeof out->refs)
        out->refs = refs;
    build_counts_store(out, &counts);
    rc = RTK_OK;
done:
    free_parts(&t);
    free(pages.users);
    free(geom_first);
    free(g.kept);
    free(g.counts);
    free(g.bounds);
    build_unreserve(bd.mem, bd.refs, ref_bytes);
    return rc;
}

/* ---- a tree given as data (rtk_bvh) ----
 * Node i of the tree becomes node i and leaf j the j-th run of blocks, through
 * the same writers as a build, so a tree exported from an accel imports to
 * the same bytes and the same statistics. */

static uint32_t tree_depth(const rtk_bvh *t, uint32_t ref, uint32_t depth)
{
    if (ref & RTK_BVH_LEAF_BIT)
        return depth;
    uint32_t deepest = depth;
    for (uint32_t c = 0; c < t->width; c++) {
        const uint32_t child = t->children[(uint64_t)ref * t->width + c];
        if (child != RTK_BVH_EMPTY) {
            const uint32_t d = tree_depth(t, child, depth + 1);
            deepest = d > deepest ? d : deepest;
        }
    }
    return deepest;
}

static box4 slot_box(const rtk_bvh *t, uint64_t slot)
{
    const float *lo = t->child_lower + 3 * slot, *hi = t->child_upper + 3 * slot;
    return (box4){vf4_set(lo[0], lo[1], lo[2], 0.0f), vf4_set(hi[0], hi[1], hi[2], 0.0f)};
}

int RTK_SYM(rtk_bvh_import)(const rtk_build_input *in, const rtk_bvh *t, rtk_build_output *out)
{
    build bd;
    int rc = build_layout_setup(&bd, in, out);
    if (rc)
        return rc;
    bd.tasks = NULL;
    if (t->width != (uint32_t)bd.width) {
        snprintf(out->message, sizeof out->message, "the tree has %u-wide nodes, the layout %d-wide ones", t->width,
                 bd.width);
        return RTK_ERROR_INVALID_ARGUMENT;
    }
    uint64_t blocks = 0;
    for (uint64_t j = 0; j < t->leaf_count; j++) {
        const uint64_t n = t->leaf_first[j + 1] - t->leaf_first[j];
        if (n > 4 * RTK_LEAF_MAX_BLOCKS) {
            snprintf(out->message, sizeof out->message, "leaf %llu holds %llu triangles; the layout's leaves hold %d",
                     (unsigned long long)j, (unsigned long long)n, 4 * RTK_LEAF_MAX_BLOCKS);
            return RTK_ERROR_INVALID_ARGUMENT;
        }
        blocks += (n + 3) / 4;
    }
    if (blocks >= RTK_LEAF_INDEX_LIMIT || t->node_count >= RTK_BVH4_LEAF_BIT || t->leaf_count >= EXT) {
        build_set_message(out, "too many leaf blocks or nodes for the layout");
        return RTK_ERROR_INVALID_ARGUMENT;
    }

    /* The triangles as primitive references in tree order: the leaf
     * writers read them from there.  geom_id -> index in the input. */
    uint32_t max_id;
    uint32_t *index_of = build_geometry_index(in, &max_id);
    const size_t ref_bytes = (t->prim_count ? t->prim_count : 1) * sizeof *bd.refs;
    bd.refs = build_reserve_huge(bd.mem, ref_bytes);
    part p = {.bd = &bd, .node_count = (uint32_t)t->node_count, .leaf_count = (uint32_t)t->leaf_count};
    p.nodes = malloc((t->node_count ? t->node_count : 1) * bd.node_size);
    p.leaves = malloc((t->leaf_count ? t->leaf_count : 1) * sizeof *p.leaves);
    struct rtk_accel *accel =
        index_of && bd.refs && p.nodes && p.leaves ? build_accel_alloc(&bd, t->node_count, blocks) : NULL;
    if (!accel) {
        free(index_of);
        part_free(&p);
        build_unreserve(bd.mem, bd.refs, ref_bytes);
        build_set_message(out, "out of memory for the BVH");
        return RTK_ERROR_OUT_OF_MEMORY;
    }
    for (uint64_t k = 0; k < t->prim_count; k++) {
        bd.refs[k].lo[3] = rtk_bits_float(index_of[t->prims[k].geom_id]);
        bd.refs[k].hi[3] = rtk_bits_float(t->prims[k].prim_id);
    }
    free(index_of);

    /* The nodes with their used slots first, as a build writes them. */
    for (uint32_t i = 0; i < p.node_count; i++) {
        range child[8];
        memset(child, 0, sizeof child);
        uint32_t refs[8];
        int nc = 0;
        for (uint32_t c = 0; c < t->width; c++) {
            const uint64_t slot = (uint64_t)i * t->width + c;
            const uint32_t ref = t->children[slot];
            if (ref == RTK_BVH_EMPTY)
                continue;
            child[nc].geom = slot_box(t, slot);
            refs[nc++] = ref & RTK_BVH_LEAF_BIT ? EXT | (ref & ~RTK_BVH_LEAF_BIT) : ref;
        }
        static const int keep[8] = {0, 1, 2, 3, 4, 5, 6, 7}; /* the tree's own order */
        write_node(&p, i, child, nc, keep);
        for (int c = 0; c < nc; c++)
            set_child(&p, i, c, refs[c]);
    }
    for (uint32_t j = 0; j < p.leaf_count; j++)
        p.leaves[j] = (leafrange){(uint32_t)t->leaf_first[j], (uint32_t)t->leaf_first[j + 1], 0};
    place_subtree(&p, 0);

    /* The scene's box: the union of the root's slots, or of a root leaf's
     * triangles. */
    box4 bounds = box_empty();
    if (t->root != RTK_BVH_EMPTY && !(t->root & RTK_BVH_LEAF_BIT)) {
        for (uint32_t c = 0; c < t->width; c++)
            if (t->children[(uint64_t)t->root * t->width + c] != RTK_BVH_EMPTY) {
                box4 s = slot_box(t, (uint64_t)t->root * t->width + c);
                box_grow(&bounds, s.lo, s.hi);
            }
    } else if (t->root != RTK_BVH_EMPTY) {
        for (uint64_t k = 0; k < t->prim_count; k++) {
            const rtk_build_geometry *g = &in->geometries[ref_geom(&bd.refs[k])];
            const uint32_t *tri = triangle_at(g, ref_prim(&bd.refs[k]));
            for (int v = 0; v < 3; v++) {
                const float *q = vertex_at(g, tri[v]);
                const vfloat4 x = vf4_set(q[0], q[1], q[2], 0.0f);
                box_grow(&bounds, x, x);
            }
        }
    }
    const uint32_t root = t->root == RTK_BVH_EMPTY        ? RTK_BVH4_EMPTY
                          : t->root & RTK_BVH_LEAF_BIT ? p.leaves[t->root & ~RTK_BVH_LEAF_BIT].placed
                                                       : t->root;
    const uint32_t depth = t->root == RTK_BVH_EMPTY ? 0 : tree_depth(t, t->root, 1);
    part_free(&p);
    build_unreserve(bd.mem, bd.refs, ref_bytes);
    build_accel_finish(&bd, accel, root, t->prim_count, depth, &bounds, out);
    return RTK_OK;
}

int RTK_SYM(rtk_build_sah)(const rtk_build_input *in, rtk_build_output *out)
{
    return build_sah(in, out, 0, 1.0f);
}

int RTK_SYM(rtk_build_sah_spatial)(const rtk_build_input *in, rtk_build_output *out)
{
    return build_sah(in, out, 1, 1.0f);
}

int RTK_SYM(rtk_build_sah_motion)(const rtk_build_input *in, rtk_build_output *out)
{
    return build_sah(in, out, 0, 2.0f);
}
