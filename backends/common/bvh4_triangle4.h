/*
 * Layouts "bvh4.triangle4" and "bvh8.triangle4": 4- or 8-wide BVH nodes whose
 * child boxes are stored as structure-of-arrays (ready for 4- or 8-wide SIMD
 * box tests), and leaves of one to four consecutive blocks of up to four
 * triangles with precomputed edges (a vertex copy: traversal never touches
 * the application's buffers; the builder's SAH sizes the leaves).  The 8-wide nodes are used by the AVX backends,
 * where one 8-wide box test costs what a 4-wide one does.
 *
 * Layout "bvh4.triangle4i", for scenes flagged compact: the same 4-wide
 * nodes, and leaves that hold only the vertex indices of their triangles
 * (80 bytes per block of four, against 176); traversal reads the vertices
 * from the geometries' vertex buffers, which must then stay valid and
 * unchanged while the scene is in use (rtk.h, RTK_SCENE_FLAG_COMPACT).
 *
 * This file is the layout only; the builder (build_sah.c) and the traversal
 * (traverse_bvh4.c) are separate, so either can change without the other.
 */
#ifndef RTK_BVH4_TRIANGLE4_H
#define RTK_BVH4_TRIANGLE4_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include "backend_common.h"
#include "memory.h"
#include "rtk/rtk_backend.h"

/* A child reference: an inner node index, a leaf, or RTK_BVH4_EMPTY.  A leaf
 * has the top bit set, its number of blocks minus one in the next two bits
 * and the index of its first block in the low 29 (its blocks are
 * consecutive).  An empty slot has an inverted box (lower = +inf,
 * upper = -inf) so no ray ever enters it. */
#define RTK_BVH4_LEAF_BIT 0x80000000u
#define RTK_BVH4_EMPTY 0xffffffffu
#define RTK_LEAF_MAX_BLOCKS 4
#define RTK_LEAF_INDEX_LIMIT (1u << 29) /* leaf blocks per BVH */
static inline uint32_t rtk_leaf_ref(uint32_t first, uint32_t blocks)
{
    return RTK_BVH4_LEAF_BIT | (blocks - 1) << 29 | first;
}
static inline uint32_t rtk_leaf_first(uint32_t ref) { return ref & (RTK_LEAF_INDEX_LIMIT - 1); }
static inline uint32_t rtk_leaf_blocks(uint32_t ref) { return (ref >> 29 & 3) + 1; }
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
    /* Per child, where its node or its first leaf block is, as the distance
     * from this node in 16-byte units (0 for an empty slot, or a distance
     * beyond 32 bits): what single-ray traversal prefetches, with two
     * instructions where the reference takes a dozen.  Never read for
     * anything else, so a wrong value costs speed only.  Set where a
     * builder gives the node its final references (build_store_node,
     * place_nodes); it pads the node to two cache lines. */
    int32_t prefetch[4];
} rtk_bvh4_node;

typedef struct rtk_bvh8_node {
    float lower_x[8], upper_x[8];
    float lower_y[8], upper_y[8];
    float lower_z[8], upper_z[8];
    uint32_t child[8];
    int32_t prefetch[8]; /* as in rtk_bvh4_node; pads the node to four cache lines */
} rtk_bvh8_node;

/* The byte offsets of the near and far planes along x, y and z in a node of
 * type T (rtk_bvh4_node or rtk_bvh8_node), by the signs of a ray's
 * direction (bit k of the index set: negative along axis k), as the
 * initializer of a size_t [8][2][3] table: near planes in [neg][0], far in
 * [neg][1].  A table, not a choice per axis and ray: a load instead of a
 * dozen instructions (the triangle kernels' plane_offsets, the top
 * level's obj_plane_offsets). */
#define RTK_PLANE_OFF(T, neg, k, lo, up) (((neg) >> (k) & 1) ? offsetof(T, up) : offsetof(T, lo))
#define RTK_PLANE_OFFSETS(T, neg)                                                                                   \
    {{RTK_PLANE_OFF(T, neg, 0, lower_x, upper_x), RTK_PLANE_OFF(T, neg, 1, lower_y, upper_y),                       \
      RTK_PLANE_OFF(T, neg, 2, lower_z, upper_z)},                                                                  \
     {RTK_PLANE_OFF(T, neg, 0, upper_x, lower_x), RTK_PLANE_OFF(T, neg, 1, upper_y, lower_y),                       \
      RTK_PLANE_OFF(T, neg, 2, upper_z, lower_z)}}
#define RTK_PLANE_OFFSET_TABLE(T)                                                                                   \
    {RTK_PLANE_OFFSETS(T, 0), RTK_PLANE_OFFSETS(T, 1), RTK_PLANE_OFFSETS(T, 2), RTK_PLANE_OFFSETS(T, 3),           \
     RTK_PLANE_OFFSETS(T, 4), RTK_PLANE_OFFSETS(T, 5), RTK_PLANE_OFFSETS(T, 6), RTK_PLANE_OFFSETS(T, 7)}

/* Up to four triangles: v0, e1 = v1 - v0, e2 = v2 - v0.  Unused lanes have
 * prim = RTK_BVH4_EMPTY and NaN vertices, so they never hit. */
typedef struct rtk_triangle4 {
    float v0x[4], v0y[4], v0z[4];
    float e1x[4], e1y[4], e1z[4];
    float e2x[4], e2y[4], e2z[4];
    uint32_t geom[4];
    uint32_t prim[4];
} rtk_triangle4;

/* Writes one lane of a triangle4 block: v0 and the two edges from it, the
 * same subtractions as the builders' four-lane writer (build_write_block),
 * so the triangle4i traversal, which goes through here, and the triangle4
 * layout hold the same floats and give the same answers to the bit. */
static inline void rtk_triangle4_set_lane(rtk_triangle4 *t, int lane, const float *v0, const float *v1,
                                          const float *v2, uint32_t geom, uint32_t prim)
{
    t->v0x[lane] = v0[0];
    t->v0y[lane] = v0[1];
    t->v0z[lane] = v0[2];
    t->e1x[lane] = v1[0] - v0[0];
    t->e1y[lane] = v1[1] - v0[1];
    t->e1z[lane] = v1[2] - v0[2];
    t->e2x[lane] = v2[0] - v0[0];
    t->e2y[lane] = v2[1] - v0[1];
    t->e2z[lane] = v2[2] - v0[2];
    t->geom[lane] = geom;
    t->prim[lane] = prim;
}

/* Layouts "bvh4.triangle4v" and "bvh8.triangle4v" (robust scenes): the
 * nodes of bvh4/bvh8.triangle4 and leaf blocks holding the three vertices
 * of each triangle as the application gave them, which the watertight
 * intersector needs (v0 + (v1 - v0) is not v1).  The same size as a
 * triangle4 block, with geom and prim at the same offsets, so the code that
 * reads only the ids (refit, export) takes either through rtk_accel.tris.
 * Unused and never-hit lanes have NaN vertices. */
typedef struct rtk_triangle4v {
    float v0x[4], v0y[4], v0z[4];
    float v1x[4], v1y[4], v1z[4];
    float v2x[4], v2y[4], v2z[4];
    uint32_t geom[4];
    uint32_t prim[4];
} rtk_triangle4v;
_Static_assert(sizeof(rtk_triangle4v) == sizeof(rtk_triangle4), "triangle4v and triangle4 blocks differ in size");
_Static_assert(offsetof(rtk_triangle4v, geom) == offsetof(rtk_triangle4, geom) &&
                   offsetof(rtk_triangle4v, prim) == offsetof(rtk_triangle4, prim),
               "triangle4v and triangle4 keep their ids at different offsets");

static inline void rtk_triangle4v_set_lane(rtk_triangle4v *t, int lane, const float *v0, const float *v1,
                                           const float *v2, uint32_t geom, uint32_t prim)
{
    t->v0x[lane] = v0[0];
    t->v0y[lane] = v0[1];
    t->v0z[lane] = v0[2];
    t->v1x[lane] = v1[0];
    t->v1y[lane] = v1[1];
    t->v1z[lane] = v1[2];
    t->v2x[lane] = v2[0];
    t->v2y[lane] = v2[1];
    t->v2z[lane] = v2[2];
    t->geom[lane] = geom;
    t->prim[lane] = prim;
}

/* Layout "bvh4.triangle4i.robust" (scenes both compact and robust) is
 * bvh4.triangle4i traced with the watertight intersector. */

/* Up to four triangles by vertex index; geom[] indexes rtk_accel.geoms (not
 * the geometry's id).  Unused lanes have prim = RTK_BVH4_EMPTY and all three
 * vertices equal to lane 0's first one, so they have no area and never hit. */
typedef struct rtk_triangle4i {
    uint32_t v0[4], v1[4], v2[4];
    uint32_t geom[4];
    uint32_t prim[4];
} rtk_triangle4i;

/* Layout "bvh4.triangle4mb" (motion blur, build_motion.c): one 4-wide tree
 * per time segment (between two consecutive time steps), all over the same
 * triangles.  A node holds each child's box at the segment's start and its
 * change over the segment (lower + f * dlower at the segment's time f in
 * [0, 1], padded so that this covers the triangles whatever the rounding).
 * Leaves are triangle4i blocks (vertex indices; geom[] indexes
 * rtk_accel.mb_geoms) over the accel's own copy of every time step's
 * vertices, shared by the segments' trees: the traversal interpolates a
 * vertex as (1 - f) * a + f * b, which is a exactly at f = 0 and b at
 * f = 1.  (Leaves holding both ends' vertices, as triangle4 blocks hold
 * one, took twice Embree's memory at two time steps, for no speed.) */
#define RTK_MB_DELTA 96 /* bytes from a plane at the start to its change */
typedef struct rtk_bvh4mb_node {
    float lower_x[4], upper_x[4];
    float lower_y[4], upper_y[4];
    float lower_z[4], upper_z[4];
    float dlower_x[4], dupper_x[4];
    float dlower_y[4], dupper_y[4];
    float dlower_z[4], dupper_z[4];
    uint32_t child[4];
    /* (208 bytes, not padded to 256: on dragon.ply as fast, and 5 bytes
     * per triangle less) */
} rtk_bvh4mb_node;

/* Layout "bvh8.triangle4mb" (where vectors are 8 wide): the same with
 * 8-wide nodes, as Embree's motion-blur default on AVX2 (BVH8 over
 * triangle4i leaves).  416 bytes: six and a half cache lines, against
 * three and a quarter for a 4-wide one that holds half the children. */
#define RTK_MB8_DELTA 192 /* bytes from a plane at the start to its change */
typedef struct rtk_bvh8mb_node {
    float lower_x[8], upper_x[8];
    float lower_y[8], upper_y[8];
    float lower_z[8], upper_z[8];
    float dlower_x[8], dupper_x[8];
    float dlower_y[8], dupper_y[8];
    float dlower_z[8], dupper_z[8];
    uint32_t child[8];
} rtk_bvh8mb_node;

/* A moving geometry's vertices: vertex i at time step k at
 * vertices[3 * (i * steps + k)], a vertex's steps side by side (the two a
 * ray interpolates between usually share a cache line), and one float
 * more at the end, so a 4-wide load of the last one stays inside. */
typedef struct rtk_mb_geometry {
    float *vertices;
    size_t vertex_count;
    uint32_t steps;
    uint32_t reserved2;
    uint32_t geom_id;
    uint32_t reserved;
} rtk_mb_geometry;

/* Where a triangle4i leaf finds its vertices. */
typedef struct rtk_leaf_geometry {
    const char *vertices; /* the geometry's vertex buffer at build time */
    size_t stride;
    uint32_t geom_id;
    uint32_t reserved;
} rtk_leaf_geometry;

struct rtk_accel {
    uint32_t layout; /* RTK_LAYOUT_* */
    uint32_t root;   /* a child reference */
    void *nodes;     /* rtk_bvh4_node or rtk_bvh8_node, by layout */
    rtk_triangle4 *tris;   /* the leaf blocks of the triangle4 and triangle4v layouts (the latter
                              rtk_triangle4v, read through this only for the ids), else NULL */
    rtk_triangle4i *trisi; /* those of bvh4.triangle4i, else NULL */
    rtk_leaf_geometry *geoms; /* bvh4.triangle4i: one per geometry in the build input */
    uint64_t node_count, leaf_count;
    size_t nodes_mapped, tris_mapped; /* bytes mapped for the node and leaf arrays (page-rounded) */
    size_t nodes_offset; /* the node array starts this many bytes into its mapping (build_common.c) */
    /* bvh4.object (objects.c): what the top level's leaves name, in leaf
     * order (rtk_object_item: object_count of them); the full records of
     * the objects not walked inline (rtk_build_object), and the transforms
     * of the instances that are (each object once, however many items
     * opening gave it); else NULL */
    struct rtk_object_item *object_items;
    uint64_t object_count;
    struct rtk_build_object *objects;
    float (*object_xfms)[12]; /* (as columns: xfm_to_columns, objects_ray.h) */
    /* bvh4.object: the merged traversal (traverse_objects.h) of the layout
     * most of its objects' trees have (bvh4.triangle4's if none), and that
     * layout's own kernels, which the inline objects have */
    rtk_intersect1_fn objects_intersect1;
    rtk_occluded1_fn objects_occluded1;
    rtk_intersect_stream_fn objects_intersect_stream; /* (traverse_objects_stream.h) */
    rtk_occluded_stream_fn objects_occluded_stream;
    rtk_intersect1_fn inline_intersect1;
    rtk_occluded1_fn inline_occluded1;
    /* bvh4.object: some tree was opened into the top level (objects.c,
     * open_objects); the width of its nodes: 4 (rtk_bvh4_node) or 8
     * (rtk_bvh8_node, for the merged traversal of bvh8.triangle4) */
    uint32_t objects_opened, objects_width;
    /* bvh4.object built for refitting (rtk_build_input.quality
     * RTK_BUILD_QUALITY_REFIT; else NULL and 0): where each item's box
     * comes from (rtk_object_src, object_count of them), and what the
     * refit checks the objects against (rtk_objects_refit, objects.c):
     * rtk_build_input.object_count, how many of them the top level kept,
     * and the width of the opened trees' nodes */
    struct rtk_object_src *object_src;
    uint32_t objects_input_count, objects_kept, objects_open_width;
    /* bvh4/bvh8.triangle4mb: the trees of the time segments, else NULL.
     * Each is an accel of its own (root, nodes: rtk_bvh4mb_node or
     * rtk_bvh8mb_node, trisi, and
     * mb_geoms, segment its time segment), sharing the top accel's
     * mb_geoms. */
    struct rtk_accel *segments;
    uint32_t segment_count;
    uint32_t segment;
    rtk_mb_geometry *mb_geoms;
    uint32_t mb_geom_count;
    /* the largest side of the tree's box: the robust traversal pads every
     * box by a few ulps of it (traverse_bvhn.h) */
    float extent;
    /* Any-hit packets whose origins lie far apart (traverse_packet.h,
     * PK_(occluded_spread)): the way they take (0 the packet traversal, 1
     * interleaved), and the cycles, rays and calls of the sampled calls
     * by way.  Only ever a choice of speed, which the traversals change
     * as they measure (relaxed atomics, shared by the threads). */
    _Atomic uint32_t pk_way;
    _Atomic uint32_t pk_calls[2];
    _Atomic uint64_t pk_cycles[2], pk_rays[2];
    /* masks and filters by geometry id (attr_count entries), copied from
     * rtk_build_input.attrs; NULL when the build had none, and then the
     * kernels never look (traverse_bvhn.h, ray_pre.feat) */
    rtk_geometry_attrs *attrs;
    uint32_t attr_count;
    /* some geometry has a filter (else a ray that needs the attributes
     * needs its masks alone, which the single-ray kernels test inline,
     * traverse_bvhn.h) */
    uint32_t attr_filter;
    /* A ray whose mask shares a bit with this one passes every geometry's
     * mask in the tree and meets no filter, so it takes the usual path
     * (feat_init): all ones in a tree without masks or filters, the AND of
     * its geometries' masks when it has masks alone, 0 when a geometry has
     * a filter.  (The core passes no ray of mask 0.) */
    uint32_t mask_pass_all;
    /* some geometry is quads (RTK_GEOMETRY_ATTR_QUAD): hits are translated */
    uint32_t quads;
    /* the memory monitor's accounting the tree's memory goes through
     * (memory.h): rtk_build_input.memory's, or none */
    rtk_memory memory;
    /* 1: every node's leaf children lie ahead of its inner children's
     * subtrees (the SAH builders, build_sah.c, build_inner); 0: each child's
     * subtree whole, in slot order (the Morton builder, imported trees).
     * The order refit walks the tree in (refit.c, walk_order). */
    uint32_t leaves_first;
    /* closest points (point_query.c): each leaf block's oriented box,
     * made at the first query, else NULL */
    struct rtk_block_bounds *_Atomic block_bounds;
};

/* What the merged two-level traversal (traverse_objects.h) reads of an
 * object of a top level's leaves: 32 bytes, where rtk_build_object is 128
 * (on a dynamic scene of 16 overlapping pieces of the bunny, rays entered
 * 12 objects each, and reading their rtk_build_object missed the first
 * level cache about every other time: callgrind, bench/work_per_ray.py
 * --section twolevel).  The top level keeps no rtk_build_object for the
 * objects walked inline: an instance's is 32 bytes of item and 48 of
 * transform instead of 160 (rtktool bench --only forest: 202 bytes per
 * instance, where Embree's memory monitor saw 91). */
typedef struct rtk_object_item {
    const struct rtk_accel *accel; /* the object's tree */
    uint32_t root;     /* the node its walk starts at: its root, or where open_objects opened it */
    uint32_t mask;     /* rtk_build_object.mask */
    uint32_t pass_all; /* RTK_OBJECT_ITEM_INLINE: the tree's mask_pass_all */
    uint32_t flags;    /* RTK_OBJECT_ITEM_* */
    uint32_t inst_id;  /* rtk_build_object.inst_id */
    /* INLINE: its transform, object_xfms[object] (unless WORLD); otherwise
     * its record, objects[object] */
    uint32_t object;
} rtk_object_item;
/* Where a top level built for refitting takes an item's box from: the
 * object's box (rtk_build_object.lower/upper) when parent is
 * RTK_OBJECT_SRC_WHOLE, else child slot (parent & 7) of node
 * (parent >> 3) of the object's tree (the item was opened there). */
typedef struct rtk_object_src {
    uint32_t input;  /* the object, an index into rtk_build_input.objects */
    uint32_t parent;
} rtk_object_src;
#define RTK_OBJECT_SRC_WHOLE UINT32_MAX
/* a tree of the merged traversal's layout with a root: walked inline */
#define RTK_OBJECT_ITEM_INLINE 1u
/* rtk_build_object.flags has RTK_BUILD_OBJECT_IDENTITY */
#define RTK_OBJECT_ITEM_WORLD 2u

/* What a node's prefetch[] slot should hold for child reference ref (see
 * rtk_bvh4_node): the distance from the node at address `node` to the
 * child's node (in the array at `nodes`) or first leaf block (at
 * `leaves`), in 16-byte units, or 0. */
static inline int32_t rtk_prefetch_distance(uintptr_t node, uint32_t ref, uintptr_t nodes, uintptr_t node_size,
                                            uintptr_t leaves, uintptr_t leaf_size)
{
    if (ref == RTK_BVH4_EMPTY)
        return 0;
    const uintptr_t to = ref & RTK_BVH4_LEAF_BIT ? leaves + rtk_leaf_first(ref) * leaf_size : nodes + ref * node_size;
    /* both 16-byte aligned; the distance as a signed integer */
    const intptr_t units = (intptr_t)(to - node) / 16;
    return units >= INT32_MIN && units <= INT32_MAX ? (int32_t)units : 0;
}

/* Asks for the four cache lines from a: a node, or a leaf's first blocks. */
static inline __attribute__((always_inline)) void rtk_prefetch4(const char *a)
{
    __builtin_prefetch(a);
    __builtin_prefetch(a + 64);
    __builtin_prefetch(a + 128);
    __builtin_prefetch(a + 192);
}

/* Asks for what a node's prefetch[] slot (units of 16 bytes from the node)
 * names: the child's node or its leaf's first block. */
static inline __attribute__((always_inline)) void rtk_prefetch_slot(const void *node, int32_t units)
{
    rtk_prefetch4((const char *)node + (intptr_t)units * 16);
}

/* The same for a finished accel (its own node and leaf arrays). */
static inline int32_t rtk_prefetch_units(const struct rtk_accel *a, const void *node, uint32_t ref, size_t node_size)
{
    const uintptr_t leaves = a->tris ? (uintptr_t)a->tris : (uintptr_t)a->trisi;
    const uintptr_t leaf_size = a->tris ? sizeof *a->tris : sizeof *a->trisi;
    return rtk_prefetch_distance((uintptr_t)node, ref, (uintptr_t)a->nodes, node_size, leaves, leaf_size);
}

/* Copies in->attrs into accel->attrs, by geometry id; 0 when out of memory. */
static inline int rtk_accel_copy_attrs(struct rtk_accel *accel, const rtk_build_input *in)
{
    accel->attrs = NULL;
    accel->attr_count = 0;
    accel->attr_filter = 0;
    accel->mask_pass_all = ~0u;
    accel->quads = 0;
    if (in->struct_size < offsetof(rtk_build_input, attrs) + sizeof in->attrs || !in->attrs)
        return 1;
    uint32_t count = 0;
    for (uint32_t g = 0; g < in->geometry_count; g++)
        count = in->geometries[g].geom_id + 1 > count ? in->geometries[g].geom_id + 1 : count;
    rtk_geometry_attrs *a = mem_alloc(&accel->memory, (count ? count : 1) * sizeof *a, 0);
    if (!a)
        return 0;
    for (uint32_t i = 0; i < count; i++)
        a[i] = (rtk_geometry_attrs){.mask = ~0u};
    for (uint32_t g = 0; g < in->geometry_count; g++) {
        const rtk_geometry_attrs *x = &in->attrs[g];
        a[in->geometries[g].geom_id] = *x;
        accel->attr_filter |= x->intersect_filter || x->occluded_filter;
        accel->mask_pass_all &= x->mask;
        accel->quads |= x->flags & RTK_GEOMETRY_ATTR_QUAD;
    }
    if (accel->attr_filter)
        accel->mask_pass_all = 0;
    accel->attrs = a;
    accel->attr_count = count;
    return 1;
}

/* A hit on triangle *prim of geometry geom, in an accel whose attributes
 * are attrs (quads set), as the application sees it: a quad's half
 * becomes the quad, with u, v over the quad (rtk_backend.h). */
static inline void rtk_quad_hit(const rtk_geometry_attrs *attrs, uint32_t geom, uint32_t *prim, float *u, float *v)
{
    if (!(attrs[geom].flags & RTK_GEOMETRY_ATTR_QUAD))
        return;
    if (*prim & 1u) {
        *u = 1.0f - *u;
        *v = 1.0f - *v;
    }
    *prim >>= 1;
}

#endif
