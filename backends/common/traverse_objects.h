/*
 * Two-level scenes walked in one loop (issue 58): the top level
 * (bvh4.object, objects.c) and, below its leaves, the trees of this
 * layout, with one set-up of the ray, one frame and one hit record per
 * ray.  objects.c's traversal calls each object's kernel through its
 * pointer, and each call set up the ray again (ray_pre_init), made its own
 * frame and, on a hit, wrote the normal and ids of a hit that a later
 * object could replace: on the dragon's dynamic scene about three objects
 * per ray, 284 instructions of set-up per call (callgrind,
 * docs/benchmarks/two-levels.md).
 *
 * Here an object whose tree has this layout (its kernel is this layout's
 * intersect1) is walked inline with closest_from_ / any_from_, from the
 * same ray_pre for every world-space object (the set-up of the fast
 * layouts depends on the ray alone; a robust tree's pads by its own extent,
 * and an instance's ray is its own, so those get a set-up each), from the
 * node the top level names (rtk_object_item: its root, or a node of it
 * where the builder opened the tree into the top level: objects.c,
 * open_objects), and the
 * closest hit is only written once the walk ends.  A ray that needs the
 * tree's masks, culling or filters takes the features' traversal from the
 * same node.  Objects of other kinds (user primitives, instances of
 * two-level scenes, trees of another layout) go through their own kernel
 * as objects.c calls them.
 *
 * Without opened trees every answer is the one objects.c's traversal
 * gives, bit for bit: the same top-level tests in the same order
 * (objects_ray.h), and below them the kernel's own traversal with the
 * ray_pre its entry point would have made.  With them, the same nearest
 * distance and a hit at it (two triangles at the same distance may be met
 * in another order).  tests/test_instance.c, merged_vs_each_object, holds
 * every answer to the nearest of each object's alone.
 *
 * A template included after traverse_bvhn.h (not for motion blur).
 */
#ifndef RTK_BVHN
#error "include traverse_bvhn.h first"
#endif
#if RTK_MOTION
#error "no merged two-level traversal for motion blur"
#endif

#include "objects_ray.h"

#define BVHN_OBJECTS_INTERSECT1 RTK_SYM(BVHN_NAME(BVHN_TAG, objects_intersect1))
#define BVHN_OBJECTS_OCCLUDED1 RTK_SYM(BVHN_NAME(BVHN_TAG, objects_occluded1))

/* An object's tree from `root` as its entry point walks it: for the usual
 * ray inline; for a ray that needs the tree's masks, culling or filters
 * (f), through the features' traversal.  (Through the out-of-line
 * closest_from_plain instead, the bunny's dynamic scene took 2,784
 * instructions a ray against 2,523, bench/work_per_ray.py --section
 * twolevel, though each layout's file compiled in 28 s instead of 40 under
 * the sanitizers.) */
static inline __attribute__((always_inline)) void objects_closest(const rtk_accel *a, uint32_t root, const ray_pre *p,
                                                                  float tnear, float *tfar, closest_hit *found,
                                                                  const feat_ctx *f)
{
    if (__builtin_expect(f != NULL, 0)) {
        closest_from_feat(a, root, p, tnear, tfar, found, f);
        return;
    }
#if RTK_SIMD_HAS_FMA
    if (__builtin_expect(!p->fma, 0)) {
        closest_from_plain(a, root, p, tnear, tfar, found);
        return;
    }
#endif
    closest_from_(a, root, p, tnear, tfar, found, BVHN_FUSED, NULL, 0);
}

static inline __attribute__((always_inline)) int objects_any(const rtk_accel *a, uint32_t root, const ray_pre *p,
                                                             float tnear, float tfar, const feat_ctx *f)
{
    if (__builtin_expect(f != NULL, 0))
        return any_from_feat(a, root, p, tnear, tfar, f);
#if RTK_SIMD_HAS_FMA
    if (__builtin_expect(!p->fma, 0))
        return any_from_plain(a, root, p, tnear, tfar);
#endif
    return any_from_usual_(a, root, p, tnear, tfar, BVHN_FUSED, NULL);
}

/* The ray set-up for item it (of top level `top`): the world's (made at
 * its first use) or its own (in own: an instance's ray taken into its
 * space, or a robust tree's, padded by its own extent); NULL when the
 * instance's ray is not finite.  The instance's ray is made in vectors and
 * set up from them, with no rtk_ray of its own written and read back: one
 * is made (objects_feat) only for a ray that needs the tree's features. */
static inline __attribute__((always_inline)) const ray_pre *objects_ray(const rtk_object_item *it,
                                                                        const rtk_accel *top, const rtk_ray *r,
                                                                        ray_pre *world, ray_mem *world_m, int *ready,
                                                                        ray_pre *own, ray_mem *own_m)
{
    if (it->flags & RTK_OBJECT_ITEM_WORLD) {
        if (RTK_ROBUST) {
            ray_pre_init(own, own_m, r, it->accel);
            return own;
        }
        if (!*ready) {
            ray_pre_init(world, world_m, r, it->accel);
            *ready = 1;
        }
        return world;
    }
    vfloat4 org, dir;
    if (!to_object_columns(top->object_xfms[it->object], r, &org, &dir))
        return NULL;
    ray_pre_init_v(own, own_m, org, dir, it->accel);
    return own;
}

/* The features (masks, culling, filters) ray r needs in item it's tree,
 * in fc; NULL for none (ray_feat and query_feat, with the tree's
 * mask_pass_all from the item).  An instance's tree gets r in its space,
 * made in *local from r and p's origin and direction (objects_ray).  cq:
 * the object's query (object_query). */
static inline const feat_ctx *objects_feat(feat_ctx *fc, const rtk_object_item *it, const rtk_ray *r,
                                           const ray_pre *p, rtk_ray *local, const rtk_query *q, rtk_query *cq,
                                           unsigned qfeat)
{
    const unsigned feat =
        (r->flags & RTK_FEAT_CULL) | (mask_needs_attrs(it->pass_all, r->mask) ? RTK_FEAT_ATTRS : 0u) | qfeat;
    if (__builtin_expect(!feat, 1))
        return NULL;
    if (!(it->flags & RTK_OBJECT_ITEM_WORLD)) {
        *local = *r;
        memcpy(&local->org_x, p->os, 4 * sizeof(float)); /* (lane 3: tnear, and time, as r's) */
        memcpy(&local->dir_x, p->ds, 4 * sizeof(float));
        r = local;
    }
    *cq = inst_query(it->inst_id, q);
    return feat_init(fc, r, it->accel, cq);
}

/* The closest hit so far (of object tree `leaves`, instance inst) written
 * into rh as the object's kernel writes it. */
static inline void objects_hit_write(const rtk_accel *leaves, uint32_t inst, const closest_hit *best, float tfar,
                                     rtk_rayhit *rh)
{
    closest_hit_write(leaves, leaves, best, NULL, tfar, rh);
    if (inst != RTK_INVALID_GEOMETRY_ID)
        rh->hit.instID = inst;
}

/* An object of another kind: through its own kernel (objects_ray.h), out
 * of the inlined loop. */
static __attribute__((noinline)) void objects_other1(const rtk_build_object *o, rtk_rayhit *rh, const rtk_query *q)
{
    object_intersect1(o, rh, q);
}

static __attribute__((noinline)) int objects_other_occluded(const rtk_build_object *o, rtk_ray *ray,
                                                            const rtk_query *q)
{
    return object_occluded1(o, ray, q);
}

/* What a ray's walk keeps besides its stack: the world's set-up (made at
 * its first use), an instance's or a robust tree's own, and the closest
 * hit not yet written (of the tree best_leaves, NULL: none pending). */
typedef struct objects_walk {
    ray_pre world, own;
    ray_mem world_m, own_m;
    int ready;
    closest_hit best;
    const rtk_accel *best_leaves;
    uint32_t best_inst;
} objects_walk;

/* A walk's start: the fields read before they are written, and no more.
 * The set-ups are written before they are read (objects_ray), and they
 * are most of its 1,024 bytes (avx2): an initializer that zeroed them all
 * took 114 instructions of a ray's 2,628 in the bunny's dynamic scene
 * (bench/work_per_ray.py --section twolevel, avx2). */
static inline __attribute__((always_inline)) void objects_walk_start(objects_walk *w)
{
    w->ready = 0;
    w->best = CLOSEST_HIT_NONE;
    w->best_leaves = NULL;
    w->best_inst = RTK_INVALID_GEOMETRY_ID;
}

/* Whether a ray with set-up p may walk a tree by the stream kernel's steps
 * (traverse_objects_stream.h), which take only the fused node test
 * (ray_pre.fma). */
static inline int objects_walkable(const ray_pre *p)
{
#if RTK_SIMD_HAS_FMA
    return p->fma;
#else
    (void)p;
    return 1;
#endif
}

/* Item it of a top-level leaf, for the closest hit within [tnear, *tfar]:
 * its tree walked from its node (an instance's or a robust tree's set-up
 * made in own, own_m), or an object of another kind through its kernel.
 * With defer (the stream kernel; NULL here, and the test folds away), a
 * tree the caller can walk by its own steps (no features, the fused test:
 * objects_walkable) is not walked: its set-up goes into *defer. */
static inline __attribute__((always_inline)) void objects_item_closest(const rtk_accel *accel,
                                                                       const rtk_object_item *it, rtk_rayhit *rh,
                                                                       const rtk_query *q, unsigned qfeat,
                                                                       float tnear, float *tfar, objects_walk *w,
                                                                       ray_pre *own, ray_mem *own_m,
                                                                       const ray_pre **defer)
{
    if (!(it->mask & rh->ray.mask))
        return;
    if (__builtin_expect(it->flags & RTK_OBJECT_ITEM_INLINE, 1)) {
        const ray_pre *p = objects_ray(it, accel, &rh->ray, &w->world, &w->world_m, &w->ready, own, own_m);
        if (!p)
            return;
        feat_ctx fc;
        rtk_query cq;
        rtk_ray local;
        const feat_ctx *f = objects_feat(&fc, it, &rh->ray, p, &local, q, &cq, qfeat);
        if (defer && __builtin_expect(!f && objects_walkable(p), 1)) {
            *defer = p;
            return;
        }
        closest_hit found = CLOSEST_HIT_NONE;
        objects_closest(it->accel, it->root, p, tnear, tfar, &found, f);
        if (found.lane >= 0) {
            w->best = found;
            w->best_leaves = it->accel;
            w->best_inst = it->inst_id;
        }
        return;
    }
    /* the hit so far goes into rh first: the object's kernel may replace it
     * (a tie included, as in objects.c) */
    if (w->best_leaves) {
        objects_hit_write(w->best_leaves, w->best_inst, &w->best, *tfar, rh);
        w->best_leaves = NULL;
    }
    objects_other1(&accel->objects[it->object], rh, q);
    *tfar = rh->ray.tfar;
}

/* Item it of a top-level leaf, for any hit: 1 when it occludes the ray;
 * own, own_m and defer as for objects_item_closest (a deferred tree: 0). */
static inline __attribute__((always_inline)) int objects_item_any(const rtk_accel *accel, const rtk_object_item *it,
                                                                  rtk_ray *ray, const rtk_query *q, unsigned qfeat,
                                                                  objects_walk *w, ray_pre *own, ray_mem *own_m,
                                                                  const ray_pre **defer)
{
    if (!(it->mask & ray->mask))
        return 0;
    if (__builtin_expect(it->flags & RTK_OBJECT_ITEM_INLINE, 1)) {
        const ray_pre *p = objects_ray(it, accel, ray, &w->world, &w->world_m, &w->ready, own, own_m);
        if (!p)
            return 0;
        feat_ctx fc;
        rtk_query cq;
        rtk_ray local;
        const feat_ctx *f = objects_feat(&fc, it, ray, p, &local, q, &cq, qfeat);
        if (defer && __builtin_expect(!f && objects_walkable(p), 1)) {
            *defer = p;
            return 0;
        }
        return objects_any(it->accel, it->root, p, ray->tnear, ray->tfar, f);
    }
    return objects_other_occluded(&accel->objects[it->object], ray, q);
}

/* The objects of top-level leaf `cur`, for the closest hit within
 * [tnear, *tfar]. */
static inline __attribute__((always_inline)) void objects_leaf_closest(const rtk_accel *accel, uint32_t cur,
                                                                       rtk_rayhit *rh, const rtk_query *q,
                                                                       unsigned qfeat, float tnear, float *tfar,
                                                                       objects_walk *w)
{
    const uint32_t first = rtk_leaf_first(cur), end = first + rtk_leaf_blocks(cur);
    for (uint32_t i = first; i < end; i++)
        objects_item_closest(accel, &accel->object_items[i], rh, q, qfeat, tnear, tfar, w, &w->own, &w->own_m, NULL);
}

/* Whether any object of top-level leaf `cur` occludes the ray. */
static inline __attribute__((always_inline)) int objects_leaf_any(const rtk_accel *accel, uint32_t cur, rtk_ray *ray,
                                                                  const rtk_query *q, unsigned qfeat, objects_walk *w)
{
    const uint32_t first = rtk_leaf_first(cur), end = first + rtk_leaf_blocks(cur);
    for (uint32_t i = first; i < end; i++)
        if (objects_item_any(accel, &accel->object_items[i], ray, q, qfeat, w, &w->own, &w->own_m, NULL))
            return 1;
    return 0;
}

#if RTK_BVHN == 8 && !RTK_ROBUST
/* A top level of 8-wide nodes (objects.c builds it so for the trees of
 * this layout from OBJ_WIDE_REFS references on, objects_width 8): walked
 * with 8-wide box tests and this layout's sorted pushes and prefetch, as
 * Embree walks its two-level tree with its ordinary 8-wide kernel.  The
 * 4-wide top level cost a ray in a forest of 10,000 instances a quarter of
 * its time (perf on rtktool bench --only forest: the scalar-sorted 4-wide
 * tests and their node loads).
 *
 * The ray for those boxes: the 4-wide top level's set-up (obj_ray_scalars:
 * one division, planes picked by the direction's signs), broadcast 8 wide.
 * The world's full set-up (ray_pre_init) is made only if a world-space tree
 * is entered (an instance's ray has its own). */
typedef struct top_ray {
    vnode org[3], inv[3], inv_far[3];
    size_t near_off[3], far_off[3];
} top_ray;

static inline __attribute__((always_inline)) void top_ray_init(top_ray *t, const rtk_ray *r)
{
    _Alignas(16) float o[4], in[4], inf[4];
    const unsigned neg = obj_ray_scalars(r, o, in, inf);
    for (int k = 0; k < 3; k++) {
        t->org[k] = vn_set1(o[k]);
        t->inv[k] = vn_set1(in[k]);
        t->inv_far[k] = vn_set1(inf[k]);
    }
    memcpy(t->near_off, plane_offsets[neg][0], sizeof t->near_off);
    memcpy(t->far_off, plane_offsets[neg][1], sizeof t->far_off);
}

/* The top level's node test (as node_entered, 8 boxes at once). */
static inline __attribute__((always_inline)) unsigned top_node(const node_t *n, const top_ray *t, vnode tnear,
                                                               vnode tfar, vnode *dist)
{
    vnode tmin = tnear, tmax = tfar;
    for (int k = 0; k < 3; k++) { /* (a NaN slab dropped, as there) */
        tmin = vn_max(vn_mul(vn_sub(plane(n, t->near_off[k]), t->org[k]), t->inv[k]), tmin);
        tmax = vn_min(vn_mul(vn_sub(plane(n, t->far_off[k]), t->org[k]), t->inv_far[k]), tmax);
    }
    *dist = tmin;
    return (unsigned)vn_mask(vn_le(tmin, tmax));
}

static void objects_intersect_top8(const rtk_accel *accel, rtk_rayhit *rh, const rtk_query *q)
{
    const unsigned qfeat = query_feat(q);
    objects_walk w;
    objects_walk_start(&w);
    top_ray tr;
    top_ray_init(&tr, &rh->ray);
    const float tnear = rh->ray.tnear;
    float tfar = rh->ray.tfar;
    const vnode ntnear = vn_set1(tnear + 0.0f); /* (-0.0 -> +0.0, as the other walks) */
    const node_t *nodes = BVHN_NODES(accel);
    stack_entry stack[RTK_BVHN_STACK_SIZE(8)];
    int sp = 0;
    stack[sp++] = (stack_entry){accel->root, tnear};
    while (sp) {
        const stack_entry e = stack[--sp];
        if (e.dist > tfar)
            continue;
        if (!(e.ref & RTK_BVH4_LEAF_BIT)) {
            const node_t *n = &nodes[e.ref];
            vnode dist;
            const unsigned mask = top_node(n, &tr, ntnear, vn_set1(tfar), &dist);
            sp = push_children(accel, n, mask, dist, stack, sp);
            continue;
        }
        objects_leaf_closest(accel, e.ref, rh, q, qfeat, tnear, &tfar, &w);
    }
    if (w.best_leaves)
        objects_hit_write(w.best_leaves, w.best_inst, &w.best, tfar, rh);
}

static void objects_occluded_top8(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q)
{
    const unsigned qfeat = query_feat(q);
    objects_walk w;
    objects_walk_start(&w);
    top_ray tr;
    top_ray_init(&tr, ray);
    const vnode ntnear = vn_set1(ray->tnear + 0.0f), ntfar = vn_set1(ray->tfar + 0.0f);
    const node_t *nodes = BVHN_NODES(accel);
    uint32_t stack[RTK_BVHN_STACK_SIZE(8)];
    int sp = 0;
    stack[sp++] = accel->root;
    while (sp) {
        const uint32_t cur = stack[--sp];
        if (!(cur & RTK_BVH4_LEAF_BIT)) {
            const node_t *n = &nodes[cur];
            vnode dist;
            unsigned mask = top_node(n, &tr, ntnear, ntfar, &dist);
            for (; mask; mask &= mask - 1) {
                const int c = __builtin_ctz(mask);
                prefetch_child(accel, n, c);
                stack[sp++] = n->child[c];
            }
            continue;
        }
        if (objects_leaf_any(accel, cur, ray, q, qfeat, &w)) {
            ray->tfar = -INFINITY;
            return;
        }
    }
}
#endif

void BVHN_OBJECTS_INTERSECT1(const rtk_accel *accel, rtk_rayhit *rh, const rtk_query *q)
{
    if (accel->root == RTK_BVH4_EMPTY)
        return;
#if RTK_BVHN == 8 && !RTK_ROBUST
    if (accel->objects_width == 8) {
        objects_intersect_top8(accel, rh, q);
        return;
    }
#endif
    obj_ray op;
    obj_ray_init(&op, &rh->ray);
    const unsigned qfeat = query_feat(q);
    objects_walk w;
    objects_walk_start(&w);
    const float tnear = rh->ray.tnear;
    float tfar = rh->ray.tfar;
    const rtk_bvh4_node *nodes = accel->nodes;
    uint32_t stack[OBJ_STACK];
    float sdist[OBJ_STACK];
    int sp = 0;
    uint32_t cur = accel->root;
    /* The nearest child entered is walked next, the others pushed farthest
     * first: the order of pushing them all and popping the nearest (the
     * order objects.c's walk keeps), without the push and pop (callgrind on
     * the bunny's dynamic scene: 2,455 instructions a ray against 2,509). */
    while (!(tnear > tfar)) {
        if (!(cur & RTK_BVH4_LEAF_BIT)) {
            uint32_t ref[4];
            float dist[4];
            const int nc = node_children(&nodes[cur], &op, tnear, tfar, ref, dist);
            if (nc) {
                for (int c = nc - 1; c > 0; c--) {
                    stack[sp] = ref[c];
                    sdist[sp++] = dist[c];
                }
                cur = ref[0];
                continue;
            }
        } else {
            objects_leaf_closest(accel, cur, rh, q, qfeat, tnear, &tfar, &w);
        }
        while (sp && sdist[sp - 1] > tfar)
            sp--;
        if (!sp)
            break;
        cur = stack[--sp];
    }
    if (w.best_leaves)
        objects_hit_write(w.best_leaves, w.best_inst, &w.best, tfar, rh);
}

void BVHN_OBJECTS_OCCLUDED1(const rtk_accel *accel, rtk_ray *ray, const rtk_query *q)
{
    if (accel->root == RTK_BVH4_EMPTY)
        return;
#if RTK_BVHN == 8 && !RTK_ROBUST
    if (accel->objects_width == 8) {
        objects_occluded_top8(accel, ray, q);
        return;
    }
#endif
    obj_ray op;
    obj_ray_init(&op, ray);
    const unsigned qfeat = query_feat(q);
    objects_walk w;
    objects_walk_start(&w);
    const rtk_bvh4_node *nodes = accel->nodes;
    uint32_t stack[OBJ_STACK];
    int sp = 0;
    uint32_t cur = accel->root;
    for (;;) { /* (the nearest child next, as BVHN_OBJECTS_INTERSECT1 walks) */
        if (!(cur & RTK_BVH4_LEAF_BIT)) {
            uint32_t ref[4];
            float dist[4];
            const int nc = node_children(&nodes[cur], &op, ray->tnear, ray->tfar, ref, dist);
            if (nc) {
                for (int c = nc - 1; c > 0; c--)
                    stack[sp++] = ref[c];
                cur = ref[0];
                continue;
            }
        } else if (objects_leaf_any(accel, cur, ray, q, qfeat, &w)) {
            ray->tfar = -INFINITY;
            return;
        }
        if (!sp)
            return;
        cur = stack[--sp];
    }
}

#undef BVHN_OBJECTS_INTERSECT1
#undef BVHN_OBJECTS_OCCLUDED1
