/* The builders' shared parts (build_common.h). */
#define _DEFAULT_SOURCE /* MAP_ANONYMOUS, MAP_NORESERVE */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "block_bounds.h"
#include "build_common.h"
#include "kernels.h"

/* The SAH terms of node `index`'s slots, each slot's half-area times its
 * blocks for a leaf (once for an inner node), summed in slot order.  Not
 * inlined: a refit sums a node's terms as it writes the node, a build or
 * an import after the tree is done, and both must round alike. */
__attribute__((noinline)) double build_node_sah(const build *bd, uint64_t index)
{
    node_view v = view_node(bd, bd->nodes, index);
    double sah = 0.0;
    for (int c = 0; c < bd->width; c++) {
        const uint32_t ref = v.child[c];
        if (ref == RTK_BVH4_EMPTY)
            continue;
        box4 b = {vf4_set(v.lx[c], v.ly[c], v.lz[c], 0.0f), vf4_set(v.ux[c], v.uy[c], v.uz[c], 0.0f)};
        sah += box_half_area_d(&b) * (ref & RTK_BVH4_LEAF_BIT ? rtk_leaf_blocks(ref) : 1);
    }
    return sah;
}

/* The SAH cost of the final tree: the root's box (an inner node or a leaf
 * of some blocks), then every node's terms (build_node_sah, or
 * bd->node_sah where a refit kept them), summed in node order in chunks of
 * RTK_SAH_CHUNK nodes on the build's threads, the chunks' sums added in
 * order.  The chunks depend on the node count alone, so a tree gets the
 * same figure to the bit on any number of threads, and so does its export
 * imported again.  (One thread summing a 10M-triangle tree took 15 ms.) */
#define RTK_SAH_CHUNK 16384u

typedef struct sah_sum {
    const build *bd;
    uint64_t node_count;
    double *chunk;
} sah_sum;

static double sah_chunk_sum(const build *bd, uint64_t node_count, uint32_t k)
{
    const uint64_t begin = (uint64_t)k * RTK_SAH_CHUNK;
    const uint64_t end = begin + RTK_SAH_CHUNK < node_count ? begin + RTK_SAH_CHUNK : node_count;
    double sum = 0.0;
    for (uint64_t i = begin; i < end; i++)
        sum += bd->node_sah ? bd->node_sah[i] : build_node_sah(bd, i);
    return sum;
}

static void sah_chunk_task(void *data, uint32_t k)
{
    sah_sum *s = data;
    s->chunk[k] = sah_chunk_sum(s->bd, s->node_count, k);
}

double build_tree_sah(const build *bd, uint64_t node_count, uint32_t root, const box4 *bounds)
{
    if (root == RTK_BVH4_EMPTY)
        return 0.0;
    double sah = box_half_area_d(bounds) * (root & RTK_BVH4_LEAF_BIT ? rtk_leaf_blocks(root) : 1);
    const uint32_t chunks = (uint32_t)((node_count + RTK_SAH_CHUNK - 1) / RTK_SAH_CHUNK);
    sah_sum s = {bd, node_count, chunks > 1 ? malloc(chunks * sizeof *s.chunk) : NULL};
    if (s.chunk)
        run_parallel(bd, chunks, sah_chunk_task, &s);
    for (uint32_t k = 0; k < chunks; k++) /* without the array (one chunk, or no memory): the same sums here */
        sah += s.chunk ? s.chunk[k] : sah_chunk_sum(bd, node_count, k);
    free(s.chunk);
    return sah;
}

/* ---- memory ---- */

/* The node and leaf arrays are anonymous mappings of the exact size, so
 * freeing them returns the memory at once. */
static size_t page_round(size_t size)
{
    return (size + 4095) & ~(size_t)4095;
}

static void *reserve(size_t size)
{
    void *p = mmap(NULL, page_round(size), PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    return p == MAP_FAILED ? NULL : p;
}

void *build_reserve(const rtk_memory *m, size_t size)
{
    if (!mem_take(m, page_round(size)))
        return NULL;
    void *p = reserve(size);
    if (!p)
        mem_give(m, page_round(size));
    return p;
}

/* A reservation for what traversal reads (nodes, leaves) and for a
 * builder's large working arrays: large ones start on a 2 MiB boundary and
 * ask for transparent huge pages, as Embree's allocator does.  Incoherent
 * rays touch nodes and leaves all over tens of megabytes; with 4 KiB pages
 * nearly every such access also misses the TLB.  A builder writing its
 * references takes one page fault per 2 MiB instead of per 4 KiB (the SAH
 * builder's references of San Miguel, 32 MB: 16 -> 7 ms on one thread).
 * The advice is only a hint (the kernel may not have huge pages); the memory
 * is the same either way. */
void *build_reserve_huge(const rtk_memory *m, size_t size)
{
    size = page_round(size);
    if (size < RTK_HUGE_PAGE)
        return build_reserve(m, size);
    if (!mem_take(m, size))
        return NULL;
    void *p = mem_map(size); /* (memory.c) */
    if (!p)
        mem_give(m, size);
    return p;
}

void build_unreserve(const rtk_memory *m, void *p, size_t size)
{
    if (!p)
        return;
    munmap(p, page_round(size));
    mem_give(m, page_round(size));
}

void build_release_pages(void *p, size_t size)
{
    const uintptr_t lo = ((uintptr_t)p + 4095) & ~(uintptr_t)4095, hi = ((uintptr_t)p + size) & ~(uintptr_t)4095;
    if (hi > lo)
        madvise((void *)lo, hi - lo, MADV_DONTNEED);
}

void build_set_message(rtk_build_output *out, const char *text)
{
    snprintf(out->message, sizeof out->message, "%s", text);
}

int build_layout_setup(build *bd, const rtk_build_input *in, rtk_build_output *out)
{
    *bd = (build){.in = in, .leaf_size = sizeof(rtk_triangle4), .width = 4, .node_size = sizeof(rtk_bvh4_node),
                  .node_cost = 1.0f};
    switch (in->layout) {
    case RTK_LAYOUT_BVH8_TRIANGLE4V:
        bd->vertex_leaves = 1;
        /* fall through */
    case RTK_LAYOUT_BVH8_TRIANGLE4:
        bd->width = 8;
        bd->node_size = sizeof(rtk_bvh8_node);
        break;
    case RTK_LAYOUT_BVH4_TRIANGLE4I:
    case RTK_LAYOUT_BVH4_TRIANGLE4I_ROBUST:
        bd->leaf_size = sizeof(rtk_triangle4i);
        bd->indexed = 1;
        break;
    case RTK_LAYOUT_BVH4_TRIANGLE4V:
        bd->vertex_leaves = 1;
        break;
    case RTK_LAYOUT_BVH4_TRIANGLE4:
        break;
    default:
        build_set_message(out, "this backend makes the bvh4/bvh8 triangle4, triangle4v and triangle4i layouts only");
        return RTK_ERROR_INVALID_ARGUMENT;
    }
    if (in->struct_size >= offsetof(rtk_build_input, tasks) + sizeof in->tasks && in->tasks &&
        in->tasks->threads > 1)
        bd->tasks = in->tasks;
    bd->mem = build_input_memory(in);
    bd->out = out;
    rtk_accel *r = in->struct_size >= offsetof(rtk_build_input, recycle) + sizeof in->recycle ? in->recycle : NULL;
    if (r && r->layout == in->layout && !r->segments && !r->objects)
        bd->recycle = r;
    return RTK_OK;
}

void build_progress_init(build *bd, build_progress *p, uint64_t work_total)
{
    const rtk_build_input *in = bd->in;
    if (in->struct_size < offsetof(rtk_build_input, progress_user) + sizeof in->progress_user || !in->progress)
        return;
    p->fn = in->progress;
    p->user = in->progress_user;
    atomic_init(&p->stopped, 0);
    atomic_init(&p->work_done, 0);
    p->work_total = work_total;
    bd->progress = p;
}

int build_begin(build *bd, const rtk_build_input *in, rtk_build_output *out, uint64_t *total)
{
    *total = 0;
    for (uint32_t g = 0; g < in->geometry_count; g++)
        *total += in->geometries[g].prim_count;
    if (*total >= RTK_LEAF_INDEX_LIMIT) {
        build_set_message(out, "too many triangles for one BVH (limit 2^29 - 1)");
        return RTK_ERROR_INVALID_ARGUMENT;
    }
    return build_layout_setup(bd, in, out);
}

uint64_t *build_geom_first(const rtk_build_input *in)
{
    uint64_t *first = malloc(((size_t)in->geometry_count + 1) * sizeof *first);
    if (!first)
        return NULL;
    first[0] = 0;
    for (uint32_t gi = 0; gi < in->geometry_count; gi++)
        first[gi + 1] = first[gi] + in->geometries[gi].prim_count;
    return first;
}

uint32_t *build_geometry_index(const rtk_build_input *in, uint32_t *max_id)
{
    *max_id = 0;
    for (uint32_t gi = 0; gi < in->geometry_count; gi++)
        *max_id = in->geometries[gi].geom_id > *max_id ? in->geometries[gi].geom_id : *max_id;
    uint32_t *index_of = malloc(((size_t)*max_id + 1) * sizeof *index_of);
    if (!index_of)
        return NULL;
    for (uint32_t id = 0; id <= *max_id; id++)
        index_of[id] = UINT32_MAX;
    for (uint32_t gi = 0; gi < in->geometry_count; gi++)
        index_of[in->geometries[gi].geom_id] = gi;
    return index_of;
}

static int cmp_u64(const void *a, const void *b)
{
    const uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return x < y ? -1 : x > y;
}

void build_largest_first(uint64_t *order, uint32_t count)
{
    for (uint32_t i = 0; i < count; i++)
        order[i] = (uint64_t)(UINT32_MAX - (uint32_t)order[i]) << 32 | i;
    qsort(order, count, sizeof *order, cmp_u64);
}

typedef struct ordered {
    const uint64_t *order;
    rtk_task_fn fn;
    void *data;
} ordered;

static void run_one_ordered(void *data, uint32_t i)
{
    const ordered *o = data;
    o->fn(o->data, (uint32_t)o->order[i]);
}

void build_run_ordered(const build *bd, const uint64_t *order, uint32_t count, rtk_task_fn fn, void *data)
{
    ordered o = {order, fn, data};
    run_parallel(bd, count, run_one_ordered, &o);
}

int build_queue_init(build_queue *q, build_queue_fn fn, void *data)
{
    *q = (build_queue){.fn = fn, .data = data};
    if (pthread_mutex_init(&q->lock, NULL))
        return 0;
    if (pthread_cond_init(&q->idle, NULL)) {
        pthread_mutex_destroy(&q->lock);
        return 0;
    }
    return 1;
}

void build_queue_free(build_queue *q)
{
    pthread_cond_destroy(&q->idle);
    pthread_mutex_destroy(&q->lock);
    free(q->heap);
    q->heap = NULL;
}

/* Under the lock: a max-heap on the keys. */
static int queue_add(build_queue *q, uint64_t key, void *item)
{
    if (!build_grow((void **)&q->heap, &q->cap, q->count + 1, sizeof *q->heap)) {
        q->oom = 1;
        return 0;
    }
    uint32_t i = q->count++;
    while (i && q->heap[(i - 1) / 2].key < key) {
        q->heap[i] = q->heap[(i - 1) / 2];
        i = (i - 1) / 2;
    }
    q->heap[i] = (build_task){key, item};
    return 1;
}

static build_task queue_take(build_queue *q)
{
    const build_task top = q->heap[0], last = q->heap[--q->count];
    uint32_t i = 0;
    for (;;) {
        uint32_t c = 2 * i + 1;
        if (c >= q->count)
            break;
        if (c + 1 < q->count && q->heap[c + 1].key > q->heap[c].key)
            c++;
        if (q->heap[c].key <= last.key)
            break;
        q->heap[i] = q->heap[c];
        i = c;
    }
    if (q->count)
        q->heap[i] = last;
    return top;
}

int build_queue_push(build_queue *q, uint64_t key, void *item)
{
    pthread_mutex_lock(&q->lock);
    const int ok = queue_add(q, key, item);
    if (ok)
        pthread_cond_signal(&q->idle);
    pthread_mutex_unlock(&q->lock);
    return ok;
}

void build_queue_fail(build_queue *q)
{
    pthread_mutex_lock(&q->lock);
    q->oom = 1;
    pthread_mutex_unlock(&q->lock);
}

void *build_queue_pop_top(build_queue *q, uint64_t min)
{
    return q->count && q->heap[0].key >= min ? queue_take(q).item : NULL;
}

static void queue_worker(void *data, uint32_t worker)
{
    build_queue *q = data;
    pthread_mutex_lock(&q->lock);
    for (;;) {
        if (q->count) {
            const build_task t = queue_take(q);
            q->running++;
            pthread_mutex_unlock(&q->lock);
            q->fn(q, t.key, t.item, worker);
            pthread_mutex_lock(&q->lock);
            if (!--q->running && !q->count)
                pthread_cond_broadcast(&q->idle);
            continue;
        }
        if (!q->running)
            break;
        pthread_cond_wait(&q->idle, &q->lock);
    }
    pthread_mutex_unlock(&q->lock);
}

void build_queue_run(const build *bd, build_queue *q)
{
    run_parallel(bd, build_threads(bd), queue_worker, q);
}

void *build_recycle_take(build *bd, int leaves, size_t size, size_t *mapped)
{
    rtk_accel *r = bd->recycle;
    if (!r)
        return NULL;
    void *p = leaves ? (r->tris ? (void *)r->tris : (void *)r->trisi) : r->nodes;
    const size_t have = leaves ? r->tris_mapped : r->nodes_mapped;
    if (!p || have < size)
        return NULL;
    if (leaves) {
        r->tris = NULL;
        r->trisi = NULL;
        r->tris_mapped = 0;
    } else {
        r->nodes = NULL;
        r->nodes_mapped = 0;
    }
    if (bd->out->struct_size >= offsetof(rtk_build_output, recycled) + sizeof bd->out->recycled)
        bd->out->recycled = 1;
    *mapped = have;
    return p;
}

/* Gives back the mapping of a tree's array p (tree_array's, `offset` bytes
 * into its mapping of `mapped` bytes; NULL: nothing). */
static void tree_array_unreserve(const rtk_memory *m, void *p, size_t mapped, size_t offset)
{
    if (p)
        build_unreserve(m, (char *)p - offset, mapped);
}

/* An array of `size` bytes for the new tree, `offset` bytes into its
 * mapping: p (an old array or a builder's spare leaves, `mapped` bytes of
 * mapping, or NULL) when it holds them, else fresh; *mapped is then the
 * mapping's size.  Whole huge pages past the array are given back: the
 * mapping stays for the next rebuild, unless it is more than twice the
 * array (a tree that shrank a lot, or a builder's reservation for the
 * most leaves it could need), which is cut where the array ends. */
static void *tree_array(const rtk_memory *m, void *p, size_t *mapped, size_t size, size_t offset)
{
    size += offset;
    if (p && *mapped < size) {
        tree_array_unreserve(m, p, *mapped, offset);
        p = NULL;
    }
    if (!p) {
        char *fresh = build_reserve_huge(m, size);
        *mapped = size;
        return fresh ? fresh + offset : NULL;
    }
    if (*mapped - size > size + RTK_HUGE_PAGE) {
        /* to the array's last page, as a fresh one would end: the mapping
         * then ends inside the last huge page, which stays in small ones */
        const size_t cut = page_round(size);
        build_unreserve(m, (char *)p - offset + cut, *mapped - cut);
        *mapped = cut;
        return p;
    }
    const size_t keep = (size + RTK_HUGE_PAGE - 1) / RTK_HUGE_PAGE * RTK_HUGE_PAGE;
    if (*mapped > keep)
        build_release_pages((char *)p - offset + keep, *mapped - keep);
    return p;
}

/* Where an 8-wide node array starts in its mapping: 64 bytes in, so every
 * node lies 64 bytes past a multiple of 256 (its four cache lines the last
 * three of one 256-byte block and the first of the next).  Rays from
 * random points of the whole mesh (a scratch driver tracing them through
 * rtk avx2 and Embree isa=avx2 in turns, the development VM's AMD EPYC)
 * ran 3-6% faster on the dragon and San Miguel than with the nodes at
 * multiples of 256, or of 256 plus 128 or 192; the bench's diffuse rays,
 * whose neighbours find the tree in the caches, within the noise.  Why
 * that CPU prefers it is not known (docs/benchmarks/notes.md).  4-wide nodes
 * keep offset 0 (not measured). */
static size_t node_offset(const build *bd)
{
    return bd->node_size == sizeof(rtk_bvh8_node) ? 64 : 0;
}

struct rtk_accel *build_accel_alloc(build *bd, uint64_t nodes, uint64_t blocks)
{
    const rtk_build_input *in = bd->in;
    struct rtk_accel *accel = calloc(1, sizeof *accel);
    if (!accel) {
        build_unreserve(bd->mem, bd->spare_leaves, bd->spare_mapped);
        bd->spare_leaves = NULL;
        return NULL;
    }
    accel->layout = in->layout;
    if (bd->mem)
        accel->memory = *bd->mem;
    /* the previous tree's arrays (build_recycle_take), else fresh ones */
    const size_t nodes_size = page_round((nodes ? nodes : 1) * bd->node_size);
    const size_t tris_size = page_round((blocks ? blocks : 1) * bd->leaf_size);
    void *old_nodes = build_recycle_take(bd, 0, nodes_size, &accel->nodes_mapped);
    accel->nodes_offset = node_offset(bd);
    bd->nodes = tree_array(bd->mem, old_nodes, &accel->nodes_mapped, nodes_size, accel->nodes_offset);
    void *old_leaves = bd->spare_leaves;
    accel->tris_mapped = bd->spare_mapped;
    bd->spare_leaves = NULL;
    if (!old_leaves)
        old_leaves = build_recycle_take(bd, 1, tris_size, &accel->tris_mapped);
    bd->leaves = tree_array(bd->mem, old_leaves, &accel->tris_mapped, tris_size, 0);
    if (bd->indexed)
        accel->geoms = mem_alloc(&accel->memory, (in->geometry_count ? in->geometry_count : 1) * sizeof *accel->geoms, 0);
    if (!bd->nodes || !bd->leaves || (bd->indexed && !accel->geoms) || !rtk_accel_copy_attrs(accel, in)) {
        tree_array_unreserve(bd->mem, bd->nodes, accel->nodes_mapped, accel->nodes_offset);
        tree_array_unreserve(bd->mem, bd->leaves, accel->tris_mapped, 0);
        mem_free(&accel->memory, accel->geoms);
        mem_free(&accel->memory, accel->attrs);
        free(accel);
        return NULL;
    }
    for (uint32_t gi = 0; bd->indexed && gi < in->geometry_count; gi++) {
        const rtk_build_geometry *g = &in->geometries[gi];
        accel->geoms[gi] = (rtk_leaf_geometry){.vertices = g->vertices, .stride = g->vertex_stride,
                                               .geom_id = g->geom_id};
    }
    accel->nodes = bd->nodes;
    accel->tris = bd->indexed ? NULL : bd->leaves;
    accel->trisi = bd->indexed ? bd->leaves : NULL;
    accel->node_count = nodes;
    accel->leaf_count = blocks;
    return accel;
}

void build_accel_finish(const build *bd, struct rtk_accel *accel, uint32_t root, uint64_t prims, uint32_t depth,
                         const box4 *bounds, rtk_build_output *out)
{
    accel->root = root;
    const size_t geom_bytes = accel->geoms ? (bd->in->geometry_count ? bd->in->geometry_count : 1) * sizeof *accel->geoms : 0;
    out->accel = accel;
    out->prims = prims;
    out->nodes = accel->node_count;
    out->leaves = accel->leaf_count;
    out->bytes = accel->node_count * bd->node_size + accel->leaf_count * bd->leaf_size + geom_bytes +
                 accel->attr_count * sizeof *accel->attrs;
    out->depth = prims ? depth : 0;
    const double root_area = box_half_area_d(bounds);
    out->sah_cost = root_area > 0.0 ? build_tree_sah(bd, accel->node_count, root, bounds) / root_area : 0.0;
    accel->extent = 0.0f;
    for (int k = 0; k < 3; k++) {
        out->lower[k] = prims ? box_lo(bounds, k) : 0.0f;
        out->upper[k] = prims ? box_hi(bounds, k) : 0.0f;
        const float side = out->upper[k] - out->lower[k]; /* may round up to inf: then no robust padding helps */
        accel->extent = side > accel->extent ? side : accel->extent;
    }
    if (out->struct_size >= offsetof(rtk_build_output, threads) + sizeof out->threads)
        out->threads = bd->tasks ? bd->tasks->threads : 1;
    if (out->struct_size >= offsetof(rtk_build_output, refs) + sizeof out->refs)
        out->refs = prims;
}

/* The lanes of `live` (a mask) whose triangle has zero area by
 * rtk_triangle_is_degenerate, given the float edges a = v1 - v0 and
 * b = v2 - v0 of four triangles across the lanes: only the lanes where no
 * component of the float cross product is surely nonzero
 * (build_cross_nonzero) take the exact test. */
static uint32_t zero_area_lanes(uint32_t live, vfloat4 ax, vfloat4 ay, vfloat4 az, vfloat4 bx, vfloat4 by,
                                vfloat4 bz, const float *const (*v)[3])
{
    const vbool4 sure = vb4_or(vb4_or(build_cross_nonzero(vf4_mul(ay, bz), vf4_mul(az, by)),
                                      build_cross_nonzero(vf4_mul(az, bx), vf4_mul(ax, bz))),
                               build_cross_nonzero(vf4_mul(ax, by), vf4_mul(ay, bx)));
    uint32_t zero = 0;
    for (uint32_t unsure = live & ~(uint32_t)vb4_mask(sure); unsure; unsure &= unsure - 1) {
        const int lane = __builtin_ctz(unsure);
        zero |= (uint32_t)(rtk_triangle_is_degenerate(v[lane][0], v[lane][1], v[lane][2]) ||
                           rtk_triangle_is_tiny(v[lane][0], v[lane][1], v[lane][2]))
                << lane;
    }
    return zero;
}

uint32_t build_write_block(const build *bd, uint64_t index, const uint32_t *geom, const uint32_t *prim,
                           uint32_t count, box4 *bounds, int *finite)
{
    const rtk_build_input *in = bd->in;
    if (bd->indexed) {
        box4 b = box_empty();
        uint32_t never_hit = 0;
        rtk_triangle4i *t = (rtk_triangle4i *)bd->leaves + index;
        for (uint32_t lane = 0; lane < 4; lane++) {
            if (lane >= count) {
                t->v0[lane] = t->v1[lane] = t->v2[lane] = t->v0[0];
                if (!bd->ids_kept) {
                    t->geom[lane] = t->geom[0];
                    t->prim[lane] = RTK_BVH4_EMPTY;
                }
                continue;
            }
            const rtk_build_geometry *g = &in->geometries[geom[lane]];
            const uint32_t *tri = triangle_at(g, prim[lane]);
            const float *v0 = vertex_at(g, tri[0]), *v1 = vertex_at(g, tri[1]), *v2 = vertex_at(g, tri[2]);
            if (finite && !rtk_triangle_coords_in_range(v0, v1, v2))
                *finite = 0;
            const int never = build_unhittable_lane(g, v0, v1, v2);
            never_hit += (uint32_t)never;
            t->v0[lane] = tri[0];
            t->v1[lane] = never ? tri[0] : tri[1];
            t->v2[lane] = never ? tri[0] : tri[2];
            if (!bd->ids_kept) {
                t->geom[lane] = geom[lane];
                t->prim[lane] = prim[lane];
            }
            if (bounds) {
                const vfloat4 p0 = vf4_set(v0[0], v0[1], v0[2], 0.0f), p1 = vf4_set(v1[0], v1[1], v1[2], 0.0f);
                const vfloat4 p2 = vf4_set(v2[0], v2[1], v2[2], 0.0f);
                box_grow(&b, vf4_min(vf4_min(p0, p1), p2), vf4_max(vf4_max(p0, p1), p2));
            }
        }
        if (bounds)
            box_grow(bounds, b.lo, b.hi);
        return never_hit;
    }

    /* triangle4 and triangle4v: the four lanes at once.  p[k][lane] is
     * vertex k of the lane's triangle as (x, y, z, 0); unused lanes repeat
     * lane 0, so they change neither the box nor the finite check. */
    vfloat4 p[3][4];
    const float *v[4][3];
    uint32_t ids[2][4], deforms = 0;
    for (uint32_t lane = 0; lane < count; lane++) {
        const rtk_build_geometry *g = &in->geometries[geom[lane]];
        const uint32_t *tri = triangle_at(g, prim[lane]);
        for (int k = 0; k < 3; k++) {
            const float *q = v[lane][k] = vertex_at(g, tri[k]);
            p[k][lane] = vf4_set(q[0], q[1], q[2], 0.0f);
        }
        deforms |= (uint32_t)((g->flags & RTK_BUILD_GEOMETRY_DEFORMS) != 0) << lane;
        ids[0][lane] = g->geom_id;
        ids[1][lane] = prim[lane];
    }
    for (uint32_t lane = count; lane < 4; lane++) {
        for (int k = 0; k < 3; k++)
            p[k][lane] = p[k][0];
        ids[0][lane] = ids[1][lane] = RTK_BVH4_EMPTY;
    }
    const vfloat4 zero = vf4_set1(0.0f);
    if (bounds || finite) {
        vfloat4 lo = p[0][0], hi = p[0][0], s = zero;
        for (int k = 0; k < 3; k++)
            for (int lane = 0; lane < 4; lane++) {
                lo = vf4_min(lo, p[k][lane]);
                hi = vf4_max(hi, p[k][lane]);
                s = vf4_add(s, vf4_mul(zero, p[k][lane])); /* NaN for any NaN or infinity */
            }
        if (bounds)
            box_grow(bounds, lo, hi);
        const vfloat4 limit = vf4_set1(RTK_COORD_LIMIT);
        if (finite && (vb4_mask(vf4_eq(s, zero)) != 0xf ||
                       vb4_mask(vb4_and(vf4_le(hi, limit), vf4_ge(lo, vf4_set1(-RTK_COORD_LIMIT)))) != 0xf))
            *finite = 0;
    }
    for (int k = 0; k < 3; k++) /* rows of lanes become x, y, z (and zeros) across the lanes */
        vf4_transpose(&p[k][0], &p[k][1], &p[k][2], &p[k][3]);
    const vfloat4 ax = vf4_sub(p[1][0], p[0][0]), ay = vf4_sub(p[1][1], p[0][1]), az = vf4_sub(p[1][2], p[0][2]);
    const vfloat4 bx = vf4_sub(p[2][0], p[0][0]), by = vf4_sub(p[2][1], p[0][1]), bz = vf4_sub(p[2][2], p[0][2]);
    const uint32_t live = (1u << count) - 1;
    const uint32_t never = deforms ? zero_area_lanes(deforms, ax, ay, az, bx, by, bz, v) : 0;
    if (!bd->vertex_leaves) { /* triangle4 holds v0 and the edges from it */
        p[1][0] = ax, p[1][1] = ay, p[1][2] = az;
        p[2][0] = bx, p[2][1] = by, p[2][2] = bz;
    }
    /* unused and never-hit lanes: NaN vertices (and no edges) */
    const vbool4 dead = vb4_from_bits((int)(never | (~live & 0xf)));
    const vfloat4 nan = vf4_set1(NAN);
    float *out = (float *)((rtk_triangle4 *)bd->leaves + index);
    for (int k = 0; k < 3; k++)
        for (int j = 0; j < 3; j++)
            vf4_storeu(out + 4 * (3 * k + j), vf4_select(dead, k == 0 || bd->vertex_leaves ? nan : zero, p[k][j]));
    rtk_triangle4 *t = (rtk_triangle4 *)bd->leaves + index;
    if (!bd->ids_kept) {
        memcpy(t->geom, ids[0], sizeof t->geom);
        memcpy(t->prim, ids[1], sizeof t->prim);
    }
    return (uint32_t)__builtin_popcount(never);
}

void RTK_SYM(rtk_bvh4_release)(rtk_accel *accel)
{
    if (!accel)
        return;
    rtk_block_bounds_drop(accel);
    tree_array_unreserve(&accel->memory, accel->nodes, accel->nodes_mapped, accel->nodes_offset);
    tree_array_unreserve(&accel->memory, accel->tris ? (void *)accel->tris : (void *)accel->trisi, accel->tris_mapped,
                         0);
    mem_free(&accel->memory, accel->geoms);
    mem_free(&accel->memory, accel->attrs);
    free(accel);
}
