/*
 * The motion-blur builder: layouts bvh4.triangle4mb and bvh8.triangle4mb
 * (bvh4_triangle4.h) over triangle meshes with time_steps >= 2 vertex
 * buffers.
 *
 * One tree per time segment (between consecutive time steps).  A
 * segment's tree is shaped by the ordinary builders (Morton for low
 * quality, binned SAH otherwise) run over the triangles at the segment's
 * middle time (the SAH pricing a node test at two blocks of triangles:
 * build_sah.c, leaf_range), and then given linear bounds: every box is
 * recomputed bottom-up from the triangles' vertices at the segment's two
 * ends, and a node stores the start box and its change, so a ray at time
 * f in the segment tests the box interpolated to f.  Since every vertex
 * moves on a straight line, the box of the vertices at f lies inside the
 * interpolated box (the minimum of linear functions is concave); a small
 * pad covers the rounding of the interpolation.  The tree is shaped at
 * the middle time rather than over the boxes the triangles sweep
 * (Embree's motion-blur builders weigh those): that buys the parallel,
 * deterministic builders as they are.  Binning each triangle's swept box
 * (the union of its boxes at the segment's ends) was tried: on dragon.ply
 * (turning up to 0.6 radians) its diffuse rays traced about as much
 * faster as with the node priced at two blocks alone, while San Miguel's
 * traced 2-6% slower (rtktool bench --only motion, side by side).
 *
 * Leaves hold vertex indices into the accel's copy of every step's
 * vertices (bvh4_triangle4.h).
 *
 * A triangle is left out (at every time) when a vertex is NaN or infinite
 * at some time step, or beyond rtk's range (RTK_COORD_LIMIT); a triangle of zero area at some or every step stays
 * in (it may have area in between), hit only where it has area.
 */
#include <math.h>
#include <stdlib.h>

#include "build_common.h"
#include "kernels.h"

_Static_assert(offsetof(rtk_bvh4mb_node, dlower_x) - offsetof(rtk_bvh4mb_node, lower_x) == RTK_MB_DELTA, "delta");
_Static_assert(offsetof(rtk_bvh4mb_node, dupper_z) - offsetof(rtk_bvh4mb_node, upper_z) == RTK_MB_DELTA, "delta");
_Static_assert(sizeof(rtk_bvh4mb_node) == 208, "no padding");
_Static_assert(offsetof(rtk_bvh8mb_node, dlower_x) - offsetof(rtk_bvh8mb_node, lower_x) == RTK_MB8_DELTA, "delta");
_Static_assert(offsetof(rtk_bvh8mb_node, dupper_z) - offsetof(rtk_bvh8mb_node, upper_z) == RTK_MB8_DELTA, "delta");
_Static_assert(sizeof(rtk_bvh8mb_node) == 416, "no padding");
/* Both node types start with twelve arrays of `width` floats: lower x,
 * upper x, lower y, upper y, lower z, upper z, then their changes in the
 * same order (store_slot writes them so). */
_Static_assert(offsetof(rtk_bvh4mb_node, lower_x) == 0 && offsetof(rtk_bvh4mb_node, dupper_z) == 11 * 4 * sizeof(float),
               "plane order");
_Static_assert(offsetof(rtk_bvh8mb_node, lower_x) == 0 && offsetof(rtk_bvh8mb_node, dupper_z) == 11 * 8 * sizeof(float),
               "plane order");

#define MB_BLOCK_CHUNK 4096u

/* A box at each end of a segment. */
typedef struct lbox {
    box4 b[2];
} lbox;

typedef struct mb {
    const rtk_build_input *in;
    build bd;                  /* for run_parallel */
    uint32_t steps, seg;       /* time steps; the segment being converted */
    uint32_t width;            /* of the nodes: 4 or 8 */
    const uint32_t *index_of;  /* geometry id -> index in the input */
    uint32_t max_id;
    const struct rtk_accel *topo; /* the segment's shape (bvhN.triangle4 at the middle time) */
    struct rtk_accel *out;        /* the whole accel (its vertex copies) */
    struct rtk_accel *seg_out;    /* the segment's tree */
    lbox *block_box;
    uint64_t *lanes;              /* per chunk of blocks: triangles in them */
    /* a refit's: per geometry and vertex, copy_steps' flags; per chunk of
     * blocks, the triangles in them that must now be left out */
    const uint8_t *const *bad;
    uint64_t *dropped;
} mb;

static inline const float *step_vertex(const mb *m, uint32_t g, uint32_t step, uint32_t v)
{
    const rtk_build_vertices *b = &m->in->time_vertices[(size_t)g * m->steps + step];
    return (const float *)((const char *)b->vertices + (size_t)v * b->stride);
}

/* The same from the accel's copy. */
static inline const float *copy_vertex(const mb *m, uint32_t g, uint32_t step, uint32_t v)
{
    const rtk_mb_geometry *c = &m->out->mb_geoms[g];
    return c->vertices + 3 * ((size_t)v * c->steps + step);
}

/* Grows *box, at the segment's two ends, by the triangle of geometry gi
 * with vertices idx, from the accel's copy. */
static inline void grow_triangle(const mb *m, lbox *box, uint32_t gi, const uint32_t *idx)
{
    for (int e = 0; e < 2; e++)
        for (int v = 0; v < 3; v++) {
            const float *p = copy_vertex(m, gi, m->seg + (uint32_t)e, idx[v]);
            const vfloat4 x = vf4_set(p[0], p[1], p[2], 0.0f);
            box_grow(&box->b[e], x, x);
        }
}

/* Leaf blocks of one chunk: the topology's triangles by vertex index, and
 * their boxes at the segment's two ends. */
static void convert_blocks(void *data, uint32_t chunk)
{
    mb *m = data;
    const uint64_t begin = (uint64_t)chunk * MB_BLOCK_CHUNK;
    const uint64_t end = begin + MB_BLOCK_CHUNK < m->topo->leaf_count ? begin + MB_BLOCK_CHUNK : m->topo->leaf_count;
    uint64_t lanes = 0;
    for (uint64_t k = begin; k < end; k++) {
        const rtk_triangle4 *t = &m->topo->tris[k];
        rtk_triangle4i *d = &m->seg_out->trisi[k];
        lbox box = {{box_empty(), box_empty()}};
        for (int lane = 0; lane < 4; lane++) {
            d->prim[lane] = t->prim[lane];
            if (t->prim[lane] == RTK_BVH4_EMPTY) {
                d->v0[lane] = d->v1[lane] = d->v2[lane] = d->geom[lane] = 0;
                continue;
            }
            lanes++;
            const uint32_t gi = m->index_of[t->geom[lane]];
            const uint32_t *tri = triangle_at(&m->in->geometries[gi], t->prim[lane]);
            d->geom[lane] = gi;
            d->v0[lane] = tri[0];
            d->v1[lane] = tri[1];
            d->v2[lane] = tri[2];
            grow_triangle(m, &box, gi, tri);
        }
        m->block_box[k] = box;
    }
    m->lanes[chunk] = lanes;
}

/* One child slot of a node of `width` children whose planes start at
 * `planes`: the start box and its change, padded (see the file's comment)
 * by 2^-19 of the largest magnitude involved, about 16 units in the last
 * place, where the interpolations round by a few.  Where the padded values
 * overflow, the slot takes the union of both ends with no change
 * instead. */
static void store_slot(float *planes, uint32_t width, int c, const lbox *b)
{
    _Alignas(16) float lo[2][4], hi[2][4];
    for (int e = 0; e < 2; e++) {
        vf4_store(lo[e], b->b[e].lo);
        vf4_store(hi[e], b->b[e].hi);
    }
    for (int a = 0; a < 3; a++) {
        float *lower = planes + (2 * a) * width, *upper = planes + (2 * a + 1) * width;
        float *dlower = planes + (6 + 2 * a) * width, *dupper = planes + (7 + 2 * a) * width;
        const float mag = fmaxf(fmaxf(fabsf(lo[0][a]), fabsf(hi[0][a])), fmaxf(fabsf(lo[1][a]), fabsf(hi[1][a])));
        const float pad = mag * 0x1p-19f + 0x1p-126f;
        const float l0 = lo[0][a] - pad, l1 = lo[1][a] - pad, h0 = hi[0][a] + pad, h1 = hi[1][a] + pad;
        const float dl = l1 - l0, dh = h1 - h0;
        if (isfinite(l0) && isfinite(l1) && isfinite(h0) && isfinite(h1) && isfinite(dl) && isfinite(dh)) {
            lower[c] = l0;
            upper[c] = h0;
            dlower[c] = dl;
            dupper[c] = dh;
        } else {
            lower[c] = fminf(l0, l1);
            upper[c] = fmaxf(h0, h1);
            dlower[c] = dupper[c] = 0.0f;
        }
    }
}

/* The nodes of the subtree `ref`, written with the boxes of both ends;
 * returns its boxes.  The topology's node `ref` (rtk_bvh4_node or
 * rtk_bvh8_node) becomes the motion node `ref` of the same width; with no
 * topology (a refit), the motion node keeps its children. */
static lbox convert_subtree(mb *m, uint32_t ref)
{
    lbox all = {{box_empty(), box_empty()}};
    if (ref & RTK_BVH4_LEAF_BIT) {
        const uint32_t first = rtk_leaf_first(ref);
        for (uint32_t k = first; k < first + rtk_leaf_blocks(ref); k++)
            for (int e = 0; e < 2; e++)
                box_grow(&all.b[e], m->block_box[k].b[e].lo, m->block_box[k].b[e].hi);
        return all;
    }
    const uint32_t w = m->width;
    float *planes;
    uint32_t *child;
    if (w == 8) {
        rtk_bvh8mb_node *n = &((rtk_bvh8mb_node *)m->seg_out->nodes)[ref];
        planes = (float *)n;
        child = n->child;
    } else {
        rtk_bvh4mb_node *n = &((rtk_bvh4mb_node *)m->seg_out->nodes)[ref];
        planes = (float *)n;
        child = n->child;
    }
    /* a build copies the topology's children; a refit keeps its own */
    const uint32_t *tchild = !m->topo ? child
                             : w == 8 ? ((const rtk_bvh8_node *)m->topo->nodes)[ref].child
                                      : ((const rtk_bvh4_node *)m->topo->nodes)[ref].child;
    memset(planes, 0, 12 * w * sizeof *planes);
    for (uint32_t c = 0; c < w; c++) {
        child[c] = tchild[c];
        if (tchild[c] == RTK_BVH4_EMPTY) {
            for (int a = 0; a < 3; a++) {
                planes[(2 * a) * w + c] = INFINITY;
                planes[(2 * a + 1) * w + c] = -INFINITY;
            }
            continue;
        }
        const lbox b = convert_subtree(m, tchild[c]);
        store_slot(planes, w, (int)c, &b);
        for (int e = 0; e < 2; e++)
            box_grow(&all.b[e], b.b[e].lo, b.b[e].hi);
    }
    return all;
}

/* A segment's build reporting into the motion build's progress: segment
 * s of n covers [s / n, (s + 1) / n). */
typedef struct mb_progress {
    const rtk_build_input *in;
    uint32_t segment, segments;
} mb_progress;

static int mb_report(void *user, double done)
{
    const mb_progress *p = user;
    return p->in->progress(p->in->progress_user, ((double)p->segment + done) / (double)p->segments);
}

/* The tree's arrays go through its memory accounting (memory.h), cache-line
 * aligned. */
static void release_segments(struct rtk_accel *accel)
{
    const rtk_memory *m = &accel->memory;
    for (uint32_t s = 0; accel->segments && s < accel->segment_count; s++) {
        mem_free(m, accel->segments[s].nodes);
        mem_free(m, accel->segments[s].trisi);
    }
    mem_free(m, accel->segments);
    for (uint32_t g = 0; accel->mb_geoms && g < accel->mb_geom_count; g++)
        mem_free(m, accel->mb_geoms[g].vertices);
    mem_free(m, accel->mb_geoms);
    mem_free(m, accel->attrs);
}

void RTK_SYM(rtk_motion_release)(rtk_accel *accel)
{
    if (!accel)
        return;
    release_segments(accel);
    free(accel);
}

static int mb_fail(rtk_build_output *out, int rc, const char *text)
{
    build_set_message(out, text);
    return rc;
}

/* The vertices at the middle of segment s, into mid[g] (3 floats each); a
 * vertex non-finite at any time step is NaN there, and one beyond rtk's
 * range at any step lies beyond it there, so every triangle using it is
 * left out of every segment's tree. */
static void middle_vertices(const mb *m, uint32_t s, float *const *mid, const uint8_t *const *bad)
{
    const rtk_build_input *in = m->in;
    for (uint32_t g = 0; g < in->geometry_count; g++)
        for (size_t v = 0; v < in->geometries[g].vertex_count; v++) {
            float *q = &mid[g][3 * v];
            if (bad[g][v]) { /* NaN, or finite beyond the range, so the build counts it alike */
                q[0] = q[1] = q[2] = bad[g][v] & 1 ? NAN : 2.0f * RTK_COORD_LIMIT;
                continue;
            }
            const float *a = step_vertex(m, g, s, (uint32_t)v), *b = step_vertex(m, g, s + 1, (uint32_t)v);
            for (int c = 0; c < 3; c++)
                q[c] = 0.5f * a[c] + 0.5f * b[c];
        }
}

/* Geometry g's vertices at every step into the accel's copy, and per
 * vertex into bad[]: 1 NaN or infinite at some step, 2 beyond rtk's range
 * (a triangle using either is left out). */
static void copy_steps(const mb *m, uint32_t g, uint8_t *bad)
{
    rtk_mb_geometry *c = &m->out->mb_geoms[g];
    const size_t nv = c->vertex_count;
    c->vertices[3 * nv * m->steps] = 0.0f;
    memset(bad, 0, nv ? nv : 1);
    for (uint32_t k = 0; k < m->steps; k++)
        for (size_t v = 0; v < nv; v++) {
            const float *p = step_vertex(m, g, k, (uint32_t)v);
            memcpy(&c->vertices[3 * (v * m->steps + k)], p, 3 * sizeof *p);
            const int finite = 0.0f * p[0] + 0.0f * p[1] + 0.0f * p[2] == 0.0f;
            const int near = fabsf(p[0]) <= RTK_COORD_LIMIT && fabsf(p[1]) <= RTK_COORD_LIMIT &&
                             fabsf(p[2]) <= RTK_COORD_LIMIT;
            bad[v] |= !finite ? 1 : !near ? 2 : 0;
        }
}

/* A segment tree's root box b, padded as a slot's is (a node of width 1),
 * taken into both ends of *total. */
static void grow_total(lbox *total, const lbox *b)
{
    float root[12] = {0};
    store_slot(root, 1, 0, b);
    const float lo[3] = {root[0], root[2], root[4]}, hi[3] = {root[1], root[3], root[5]};
    const float dlo[3] = {root[6], root[8], root[10]}, dhi[3] = {root[7], root[9], root[11]};
    _Alignas(16) float l[4] = {0}, h[4] = {0};
    for (int e = 0; e < 2; e++) {
        for (int a = 0; a < 3; a++) {
            l[a] = e ? lo[a] + dlo[a] : lo[a];
            h[a] = e ? hi[a] + dhi[a] : hi[a];
        }
        box_grow(&total->b[0], vf4_load(l), vf4_load(h));
    }
}

/* The accel's box over all times into out, and the robust traversal's
 * padding (traverse_bvhn.h) from it. */
static void finish_bounds(struct rtk_accel *accel, const lbox *total, uint64_t prims, rtk_build_output *out)
{
    _Alignas(16) float lo[4], hi[4];
    vf4_store(lo, total->b[0].lo);
    vf4_store(hi, total->b[0].hi);
    accel->extent = 0.0f;
    for (int a = 0; a < 3; a++) {
        out->lower[a] = prims ? lo[a] : INFINITY;
        out->upper[a] = prims ? hi[a] : -INFINITY;
        const float side = prims ? hi[a] - lo[a] : 0.0f;
        accel->extent = side > accel->extent ? side : accel->extent;
    }
    for (uint32_t s = 0; s < accel->segment_count; s++)
        accel->segments[s].extent = accel->extent;
}

int RTK_SYM(rtk_build_motion)(const rtk_build_input *in, rtk_build_output *out)
{
    if (in->struct_size < offsetof(rtk_build_input, time_vertices) + sizeof in->time_vertices || in->time_steps < 2 ||
        !in->time_vertices)
        return mb_fail(out, RTK_ERROR_INVALID_ARGUMENT, "the motion builder needs at least two time steps");
    uint32_t width = 4;
    switch (in->layout) {
    case RTK_LAYOUT_BVH4_TRIANGLE4MB:
    case RTK_LAYOUT_BVH4_TRIANGLE4MB_ROBUST: break;
#ifdef RTK_SIMD_HAS_8
    case RTK_LAYOUT_BVH8_TRIANGLE4MB:
    case RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST: width = 8; break;
#endif
    default:
        return mb_fail(out, RTK_ERROR_INVALID_ARGUMENT,
                       "the motion builder produces the bvh4 and bvh8 .triangle4mb layouts and their robust ones only");
    }
    const size_t node_size = width == 8 ? sizeof(rtk_bvh8mb_node) : sizeof(rtk_bvh4mb_node);
    mb m = {.in = in, .steps = in->time_steps, .width = width};
    size_t vertex_bytes = 0;
    const uint32_t segments = in->time_steps - 1;
    int rc = RTK_OK;
    struct rtk_accel *accel = calloc(1, sizeof *accel);
    float **mid = calloc(in->geometry_count + 1, sizeof *mid);
    uint8_t **bad = calloc(in->geometry_count + 1, sizeof *bad);
    rtk_build_geometry *geoms = calloc(in->geometry_count + 1, sizeof *geoms);
    uint32_t *index_of = build_geometry_index(in, &m.max_id);
    m.index_of = index_of;
    if (accel) {
        const rtk_memory *mem = build_input_memory(in);
        if (mem)
            accel->memory = *mem;
        accel->segments = mem_alloc(&accel->memory, segments * sizeof *accel->segments, 1);
        accel->mb_geoms = mem_alloc(&accel->memory, (in->geometry_count + 1) * sizeof *accel->mb_geoms, 1);
        accel->mb_geom_count = in->geometry_count;
    }
    m.out = accel;
    if (!accel || !accel->segments || !accel->mb_geoms || !mid || !bad || !geoms || !index_of ||
        !rtk_accel_copy_attrs(accel, in)) {
        rc = mb_fail(out, RTK_ERROR_OUT_OF_MEMORY, "out of memory for the motion build");
        goto done;
    }
    accel->layout = in->layout;
    accel->segment_count = segments;
    for (uint32_t g = 0; g < in->geometry_count; g++) {
        const size_t nv = in->geometries[g].vertex_count;
        mid[g] = malloc((nv ? nv : 1) * 3 * sizeof **mid);
        bad[g] = calloc(nv ? nv : 1, 1);
        rtk_mb_geometry *c = &accel->mb_geoms[g];
        c->vertices = mem_alloc(&accel->memory, (3 * nv * m.steps + 1) * sizeof *c->vertices, 0);
        c->vertex_count = nv;
        c->steps = m.steps;
        c->geom_id = in->geometries[g].geom_id;
        vertex_bytes += (3 * nv * m.steps + 1) * sizeof *c->vertices;
        if (!mid[g] || !bad[g] || !c->vertices) {
            rc = mb_fail(out, RTK_ERROR_OUT_OF_MEMORY, "out of memory for the motion build");
            goto done;
        }
        copy_steps(&m, g, bad[g]);
        geoms[g] = in->geometries[g];
        geoms[g].vertices = mid[g];
        geoms[g].vertex_stride = 3 * sizeof(float);
        /* triangles of zero area at the middle time stay in the shape */
        geoms[g].flags |= RTK_BUILD_GEOMETRY_DEFORMS;
    }
    rtk_build_input topo_in = *in;
    topo_in.struct_size = sizeof topo_in;
    topo_in.geometries = geoms;
    topo_in.layout = width == 8 ? RTK_LAYOUT_BVH8_TRIANGLE4 : RTK_LAYOUT_BVH4_TRIANGLE4;
    topo_in.recycle = NULL;
    /* each segment's build reports its share of the whole */
    mb_progress prog = {.in = in, .segments = segments};
    if (in->struct_size >= offsetof(rtk_build_input, progress_user) + sizeof in->progress_user && in->progress) {
        topo_in.progress = mb_report;
        topo_in.progress_user = &prog;
    } else {
        topo_in.progress = NULL;
    }
    topo_in.time_steps = 0;
    topo_in.time_vertices = NULL;
    m.bd = (build){.in = in, .tasks = in->tasks && in->threads > 1 && in->struct_size >= offsetof(rtk_build_input, tasks) + sizeof in->tasks ? in->tasks : NULL};

    lbox total = {{box_empty(), box_empty()}};
    uint64_t nodes = 0, blocks = 0, prims = 0, skipped = 0, out_of_range = 0;
    uint32_t depth = 0, threads = 1;
    double sah = 0.0;
    for (uint32_t s = 0; s < segments && !rc; s++) {
        prog.segment = s;
        middle_vertices(&m, s, mid, (const uint8_t *const *)bad);
        rtk_build_output topo_out = {.struct_size = sizeof topo_out};
        rc = in->quality == RTK_BUILD_QUALITY_LOW ? RTK_SYM(rtk_build_morton)(&topo_in, &topo_out)
                                                  : RTK_SYM(rtk_build_sah_motion)(&topo_in, &topo_out);
        if (rc) {
            build_set_message(out, topo_out.message);
            break;
        }
        struct rtk_accel *topo = topo_out.accel;
        struct rtk_accel *seg = &accel->segments[s];
        seg->layout = in->layout;
        seg->root = topo->root;
        seg->node_count = topo->node_count;
        seg->leaf_count = topo->leaf_count;
        seg->segment = s;
        seg->mb_geoms = accel->mb_geoms;
        seg->nodes = mem_alloc(&accel->memory, (topo->node_count ? topo->node_count : 1) * node_size, 0);
        seg->trisi = mem_alloc(&accel->memory, (topo->leaf_count ? topo->leaf_count : 1) * sizeof(rtk_triangle4i), 0);
        const uint32_t chunks = (uint32_t)((topo->leaf_count + MB_BLOCK_CHUNK - 1) / MB_BLOCK_CHUNK);
        m.block_box = malloc((topo->leaf_count ? topo->leaf_count : 1) * sizeof *m.block_box);
        m.lanes = calloc(chunks ? chunks : 1, sizeof *m.lanes);
        if (!seg->nodes || !seg->trisi || !m.block_box || !m.lanes) {
            rc = mb_fail(out, RTK_ERROR_OUT_OF_MEMORY, "out of memory for the motion build");
        } else {
            m.seg = s;
            m.topo = topo;
            m.seg_out = seg;
            run_parallel(&m.bd, chunks, convert_blocks, &m);
            if (topo->root != RTK_BVH4_EMPTY) {
                const lbox b = convert_subtree(&m, topo->root);
                grow_total(&total, &b);
            }
            uint64_t lanes = 0;
            for (uint32_t c = 0; c < chunks; c++)
                lanes += m.lanes[c];
            nodes += topo->node_count;
            blocks += topo->leaf_count;
            prims = lanes;
            skipped = topo_out.prims_skipped;
            out_of_range = topo_out.prims_out_of_range;
            depth = topo_out.depth > depth ? topo_out.depth : depth;
            threads = topo_out.threads > threads ? topo_out.threads : threads;
            sah += topo_out.sah_cost;
        }
        free(m.block_box);
        free(m.lanes);
        m.block_box = NULL;
        m.lanes = NULL;
        RTK_SYM(rtk_bvh4_release)(topo);
    }
    if (rc)
        goto done;
    accel->root = prims ? 0 : RTK_BVH4_EMPTY;
    accel->node_count = nodes;
    accel->leaf_count = blocks;
    out->accel = accel;
    out->depth = depth;
    out->prims = prims;
    build_counts_store(out, &(build_counts){skipped, 0, out_of_range});
    out->nodes = nodes;
    out->leaves = blocks;
    out->bytes = nodes * node_size + blocks * sizeof(rtk_triangle4i) + vertex_bytes + sizeof *accel +
                 segments * sizeof *accel->segments + in->geometry_count * sizeof *accel->mb_geoms;
    out->sah_cost = sah / segments;
    finish_bounds(accel, &total, prims, out);
    if (out->struct_size >= offsetof(rtk_build_output, threads) + sizeof out->threads)
        out->threads = threads;
    if (out->struct_size >= offsetof(rtk_build_output, refs) + sizeof out->refs)
        out->refs = prims;
    accel = NULL;

done:
    if (accel) {
        release_segments(accel);
        free(accel);
    }
    for (uint32_t g = 0; mid && bad && g < in->geometry_count; g++) {
        free(mid[g]);
        free(bad[g]);
    }
    free(mid);
    free(bad);
    free(geoms);
    free(index_of);
    return rc;
}

/* ---- refit ---- */

/* Refit, one chunk of a segment's leaf blocks: their boxes at the
 * segment's two ends from the accel's copy of the new vertices, the
 * triangles in them, and of those the ones that must now be left out. */
static void refit_blocks(void *data, uint32_t chunk)
{
    mb *m = data;
    const struct rtk_accel *seg = m->seg_out;
    const uint64_t begin = (uint64_t)chunk * MB_BLOCK_CHUNK;
    const uint64_t end = begin + MB_BLOCK_CHUNK < seg->leaf_count ? begin + MB_BLOCK_CHUNK : seg->leaf_count;
    uint64_t lanes = 0, dropped = 0;
    for (uint64_t k = begin; k < end; k++) {
        const rtk_triangle4i *d = &seg->trisi[k];
        lbox box = {{box_empty(), box_empty()}};
        for (int lane = 0; lane < 4; lane++) {
            if (d->prim[lane] == RTK_BVH4_EMPTY)
                continue;
            lanes++;
            const uint32_t gi = d->geom[lane];
            const uint32_t idx[3] = {d->v0[lane], d->v1[lane], d->v2[lane]};
            dropped += (m->bad[gi][idx[0]] | m->bad[gi][idx[1]] | m->bad[gi][idx[2]]) != 0;
            grow_triangle(m, &box, gi, idx);
        }
        m->block_box[k] = box;
    }
    m->lanes[chunk] = lanes;
    m->dropped[chunk] = dropped;
}

/*
 * Refit (rtk_accel_refit) of a motion accel: the geometries' new vertices
 * at every time step into the accel's copy, and every box of every
 * segment's tree recomputed bottom-up from them, exactly as a build
 * computes the boxes of its tree (the same padding), so the answers are
 * those of a build of the same trees: only the trees' shapes, shaped by
 * the old vertices, are kept.  RTK_REFIT_NEEDS_BUILD when the time steps,
 * the geometries or their vertex counts are not the build's, or the
 * triangles that go in the trees are not the ones they hold (a vertex
 * turned NaN, infinite or out of range, or back).  Everything is allocated
 * before the accel is written, so an error other than that one leaves it
 * as it was.
 */
int RTK_SYM(rtk_motion_refit)(rtk_accel *accel, const rtk_build_input *in, rtk_build_output *out)
{
    if (in->layout != accel->layout)
        return mb_fail(out, RTK_ERROR_INVALID_ARGUMENT, "the input asks for another layout than the accel's");
    const uint32_t width =
        accel->layout == RTK_LAYOUT_BVH8_TRIANGLE4MB || accel->layout == RTK_LAYOUT_BVH8_TRIANGLE4MB_ROBUST ? 8 : 4;
    if (in->struct_size < offsetof(rtk_build_input, time_vertices) + sizeof in->time_vertices || in->time_steps < 2 ||
        !in->time_vertices || in->time_steps - 1 != accel->segment_count || in->geometry_count != accel->mb_geom_count)
        return mb_fail(out, RTK_REFIT_NEEDS_BUILD, "the time steps or the geometries changed");
    uint64_t leaves = 0;
    for (uint32_t g = 0; g < in->geometry_count; g++) {
        const rtk_mb_geometry *c = &accel->mb_geoms[g];
        if (in->geometries[g].geom_id != c->geom_id || in->geometries[g].vertex_count != c->vertex_count)
            return mb_fail(out, RTK_REFIT_NEEDS_BUILD, "a geometry or its vertex count changed");
    }
    for (uint32_t s = 0; s < accel->segment_count; s++)
        leaves = accel->segments[s].leaf_count > leaves ? accel->segments[s].leaf_count : leaves;
    mb m = {.in = in, .steps = in->time_steps, .width = width, .out = accel};
    m.bd = (build){.in = in, .tasks = in->tasks && in->threads > 1 &&
                                              in->struct_size >= offsetof(rtk_build_input, tasks) + sizeof in->tasks
                                          ? in->tasks
                                          : NULL};
    const uint32_t max_chunks = (uint32_t)((leaves + MB_BLOCK_CHUNK - 1) / MB_BLOCK_CHUNK);
    uint8_t **bad = calloc(in->geometry_count + 1, sizeof *bad);
    m.block_box = malloc((leaves ? leaves : 1) * sizeof *m.block_box);
    m.lanes = calloc(max_chunks ? max_chunks : 1, sizeof *m.lanes);
    m.dropped = calloc(max_chunks ? max_chunks : 1, sizeof *m.dropped);
    int rc = bad && m.block_box && m.lanes && m.dropped ? RTK_OK : RTK_ERROR_OUT_OF_MEMORY;
    for (uint32_t g = 0; !rc && g < in->geometry_count; g++) {
        const size_t nv = in->geometries[g].vertex_count;
        bad[g] = malloc(nv ? nv : 1);
        rc = bad[g] ? RTK_OK : RTK_ERROR_OUT_OF_MEMORY;
    }
    if (rc) {
        mb_fail(out, rc, "out of memory for the motion refit");
        goto done;
    }
    m.bad = (const uint8_t *const *)bad;
    /* the new vertices, and the triangles that go in the trees now */
    build_counts left = {0, 0, 0};
    uint64_t kept = 0;
    for (uint32_t g = 0; g < in->geometry_count; g++) {
        copy_steps(&m, g, bad[g]);
        const rtk_build_geometry *geo = &in->geometries[g];
        for (size_t prim = 0; prim < geo->prim_count; prim++) {
            const uint32_t *tri = triangle_at(geo, prim);
            const unsigned b = bad[g][tri[0]] | bad[g][tri[1]] | bad[g][tri[2]];
            kept += !b;
            left.skipped += (b & 1) != 0;
            left.out_of_range += b == 2;
        }
    }
    lbox total = {{box_empty(), box_empty()}};
    for (uint32_t s = 0; s < accel->segment_count && !rc; s++) {
        struct rtk_accel *seg = &accel->segments[s];
        uint64_t lanes = 0, dropped = 0;
        if (seg->root != RTK_BVH4_EMPTY) {
            const uint32_t chunks = (uint32_t)((seg->leaf_count + MB_BLOCK_CHUNK - 1) / MB_BLOCK_CHUNK);
            m.seg = s;
            m.seg_out = seg;
            m.topo = NULL;
            run_parallel(&m.bd, chunks, refit_blocks, &m);
            for (uint32_t c = 0; c < chunks; c++) {
                lanes += m.lanes[c];
                dropped += m.dropped[c];
            }
        }
        if (dropped || lanes != kept) {
            rc = mb_fail(out, RTK_REFIT_NEEDS_BUILD, "the triangles that go in the trees changed");
            break;
        }
        if (seg->root != RTK_BVH4_EMPTY) {
            const lbox b = convert_subtree(&m, seg->root);
            grow_total(&total, &b);
        }
    }
    if (!rc) {
        finish_bounds(accel, &total, kept, out);
        build_counts_store(out, &left);
        out->prims = kept;
    }

done:
    for (uint32_t g = 0; bad && g < in->geometry_count; g++)
        free(bad[g]);
    free(bad);
    free(m.block_box);
    free(m.lanes);
    free(m.dropped);
    return rc;
}
