/*
 * Streams through two-level scenes (issues 56 and 58): many rays in
 * flight through a top level (bvh4.object) and, below it, the trees of
 * this layout, interleaved as traverse_stream.h interleaves rays through
 * one tree.
 *
 * Each slot holds one ray's whole two-level walk: its top-level stack and
 * the objects of the top-level leaf it is in (the top level is small and
 * mostly in the caches, so a slot walks it without pausing), and the walk
 * in the object tree it has entered, which is traverse_stream.h's slot
 * (stream_slot) set up from the object's ray (an instance's ray taken into
 * its space, objects_ray) at the node the top level names.  A step
 * advances one slot by one node or leaf of its object's tree and prefetches
 * the next; when that walk ends, its hit goes into the ray's closest so
 * far, and the slot walks the top level on to the next object, or takes the
 * next ray of the stream.
 *
 * Every ray gets rtk_intersect1's answer to the bit (the merged traversal,
 * traverse_objects.h): the top level is walked with its tests, in its
 * order and with its pruning by the closest hit so far; each object's tree
 * with the stream steps, which are closest_from_'s and any_from_'s; objects
 * of other kinds, and rays that need a tree's masks, culling or filters or
 * the unfused node test, are handled on the spot as the merged traversal
 * handles them.  As in traverse_stream.h, the stream is measured in
 * windows, interleaved against one ray after the other (the merged
 * single-ray traversal), and the faster way kept (stream_window).
 *
 * A template included after traverse_objects.h.
 */
#ifndef RTK_BVHN
#error "include traverse_bvhn.h first"
#endif

#define OBJS_INTERSECT1 RTK_SYM(BVHN_NAME(BVHN_TAG, objects_intersect1))
#define OBJS_OCCLUDED1 RTK_SYM(BVHN_NAME(BVHN_TAG, objects_occluded1))
#define OBJS_INTERSECT_STREAM RTK_SYM(BVHN_NAME(BVHN_TAG, objects_intersect_stream))
#define OBJS_OCCLUDED_STREAM RTK_SYM(BVHN_NAME(BVHN_TAG, objects_occluded_stream))

#if RTK_BVHN == 8 && !RTK_ROBUST
#define OBJS_TOP8 1
#define OBJS_TOP_STACK (OBJ_STACK > RTK_BVHN_STACK_SIZE(8) ? OBJ_STACK : RTK_BVHN_STACK_SIZE(8))
#else
#define OBJS_TOP8 0
#define OBJS_TOP_STACK OBJ_STACK
#endif

/* One ray in flight through both levels. */
typedef struct objs_slot {
    stream_slot s; /* the walk in the object's tree (s.ray: the ray; s.p: an instance's or robust tree's set-up) */
    objects_walk w;
    const rtk_object_item *it; /* the item whose tree s walks */
    const ray_pre *pre;        /* with this set-up: s.p, or the world's in w, not copied */
    uint32_t item, item_end;   /* the items of the top-level leaf still to come */
    float tnear, tfar;         /* the ray's, tfar the closest hit so far */
    int top_sp;
    obj_ray op; /* the ray for 4-wide top-level nodes */
#if OBJS_TOP8
    top_ray tr; /* for 8-wide ones */
#endif
    stack_entry top[OBJS_TOP_STACK];
} objs_slot;

/* Slot o's top-level walk begun for ray r. */
static inline __attribute__((always_inline)) void objs_top_start(const rtk_accel *accel, objs_slot *o, void *r)
{
    const rtk_ray *ray = r;
    o->s.ray = r;
    objects_walk_start(&o->w);
    o->tnear = ray->tnear;
    o->tfar = ray->tfar;
    o->item = o->item_end = 0;
#if OBJS_TOP8
    if (accel->objects_width == 8)
        top_ray_init(&o->tr, ray);
    else
#endif
        obj_ray_init(&o->op, ray);
    o->top[0] = (stack_entry){accel->root, o->tnear};
    o->top_sp = 1;
}

/* The next top-level leaf of slot o's walk, its items into o->item ..
 * o->item_end; 0 when the walk is done.  The merged traversal's order:
 * the nearest child entered next and the others after it by distance
 * (closest hits: dropped when the hit so far is nearer than their entry),
 * 8-wide nodes as objects_intersect_top8 and objects_occluded_top8 walk
 * them.  Without a pause between the nodes: the top level is small and
 * mostly in the caches, and a slot that gave the next slot its turn after
 * each of its nodes, as it does in an object's tree, traced the path
 * tracer's streams through the dragon's 16 instances 15% slower (rtktool
 * bench --only twolevel --api stream, AMD EPYC, either build first). */
static inline __attribute__((always_inline)) int objs_top_leaf(const rtk_accel *accel, objs_slot *o, int anyhit)
{
    while (o->top_sp) {
        const stack_entry e = o->top[--o->top_sp];
        if (!anyhit && e.dist > o->tfar)
            continue;
        if (e.ref & RTK_BVH4_LEAF_BIT) {
            o->item = rtk_leaf_first(e.ref);
            o->item_end = o->item + rtk_leaf_blocks(e.ref);
            return 1;
        }
#if OBJS_TOP8
        if (accel->objects_width == 8) {
            const node_t *n = &BVHN_NODES(accel)[e.ref];
            vnode dist;
            unsigned mask = top_node(n, &o->tr, vn_set1(o->tnear + 0.0f),
                                     anyhit ? vn_set1(o->tfar + 0.0f) : vn_set1(o->tfar), &dist);
            if (!anyhit) {
                o->top_sp = push_children(accel, n, mask, dist, o->top, o->top_sp);
                continue;
            }
            for (; mask; mask &= mask - 1) {
                const int c = __builtin_ctz(mask);
                prefetch_child(accel, n, c);
                o->top[o->top_sp++] = (stack_entry){n->child[c], 0.0f};
            }
            continue;
        }
#endif
        const rtk_bvh4_node *nodes = accel->nodes;
        uint32_t ref[4];
        float dist[4];
        const int nc = node_children(&nodes[e.ref], &o->op, o->tnear, o->tfar, ref, dist);
        for (int c = nc - 1; c >= 0; c--)
            o->top[o->top_sp++] = (stack_entry){ref[c], dist[c]};
    }
    return 0;
}

/* Slot o's walk in item it's tree from its node, with the set-up p (the
 * world's; an instance's or robust tree's, made in o->s.p). */
static inline __attribute__((always_inline)) void objs_walk_begin(objs_slot *o, const rtk_object_item *it,
                                                                  const ray_pre *p)
{
    stream_slot *s = &o->s;
    o->pre = p;
#if !RTK_SIMD_HAS_FMA || RTK_ROBUST
    leaf_ray_init(&s->lr, p);
#endif
    s->best = CLOSEST_HIT_NONE;
    s->tnear_s = o->tnear;
    s->tfar_s = o->tfar;
    s->ntnear = vn_set1(o->tnear + 0.0f);
    s->ntfar = vn_set1(o->tfar + 0.0f);
    s->cur = it->root;
    s->sp = 0;
    o->it = it;
    stream_prefetch_ref(it->accel, it->root);
}

/* Closest hits: slot o's walk through the top level on to the next object
 * tree it walks interleaved (1, o->s set up there); the objects met on the
 * way that are not walked so are handled on the spot, as the merged
 * traversal handles them (objects_item_closest).  0 when the ray is done,
 * its hit written. */
static inline __attribute__((always_inline)) int objs_next_closest(const rtk_accel *accel, objs_slot *o,
                                                                   const rtk_query *q, unsigned qfeat)
{
    rtk_rayhit *rh = o->s.ray;
    objects_walk *w = &o->w;
    for (;;) {
        while (o->item < o->item_end) {
            const rtk_object_item *it = &accel->object_items[o->item++];
            const ray_pre *p = NULL;
            objects_item_closest(accel, it, rh, q, qfeat, o->tnear, &o->tfar, w, &o->s.p, &o->s.m, &p);
            if (p) {
                objs_walk_begin(o, it, p);
                return 1;
            }
        }
        if (!objs_top_leaf(accel, o, 0))
            break;
    }
    if (w->best_leaves)
        objects_hit_write(w->best_leaves, w->best_inst, &w->best, o->tfar, rh);
    return 0;
}

/* Any hits: as objs_next_closest; 0 when the ray is done (ray->tfar
 * -inf where an object on the way occludes it). */
static inline __attribute__((always_inline)) int objs_next_any(const rtk_accel *accel, objs_slot *o,
                                                               const rtk_query *q, unsigned qfeat)
{
    rtk_ray *ray = o->s.ray;
    for (;;) {
        while (o->item < o->item_end) {
            const rtk_object_item *it = &accel->object_items[o->item++];
            const ray_pre *p = NULL;
            if (objects_item_any(accel, it, ray, q, qfeat, &o->w, &o->s.p, &o->s.m, &p)) {
                ray->tfar = -INFINITY;
                return 0;
            }
            if (p) {
                objs_walk_begin(o, it, p);
                return 1;
            }
        }
        if (!objs_top_leaf(accel, o, 1))
            return 0;
    }
}

static inline __attribute__((always_inline)) int objs_next_object(const rtk_accel *accel, objs_slot *o,
                                                                  const rtk_query *q, unsigned qfeat, int closest)
{
    return closest ? objs_next_closest(accel, o, q, qfeat) : objs_next_any(accel, o, q, qfeat);
}

/* Slot o on to the next object tree it walks interleaved (1, o->s set up
 * there): first along its ray's top level when `more` (the walk of an
 * object tree has just ended without occluding the ray), then with the
 * stream's next rays; 0 when the stream has run out.  Rays that finish on
 * the way (no tree of this layout entered interleaved), and every ray of
 * the windows that go one after the other, are done here.  The driver
 * calls it from one place, so that the top level's item step (instances,
 * user geometry, masks) is inlined once per query: called from two, it
 * made the stream entries the largest functions of their files and most
 * of the sanitizer build's time, and not inlined it cost the path tracer
 * through the dragon's instances 9%. */
static inline __attribute__((always_inline)) int objs_advance(const rtk_accel *accel, stream_src *src,
                                                              objs_slot *o, const rtk_query *q, unsigned qfeat,
                                                              int closest, int more)
{
    for (;;) {
        if (more && objs_next_object(accel, o, q, qfeat, closest))
            return 1;
        more = 0;
        while (!more && src->next < src->count) {
            if (src->next >= src->window_end)
                stream_next_window(src);
            void *r = src->rays[src->next++];
            if (src->interleave) {
                objs_top_start(accel, o, r);
                more = 1;
            } else if (closest) {
                OBJS_INTERSECT1(accel, r, q);
            } else {
                OBJS_OCCLUDED1(accel, r, q);
            }
        }
        if (!more)
            return 0;
    }
}

/* The driver (closest a constant in each query): every slot starts with
 * no walk (it NULL) and takes a ray; each active slot steps in turn
 * through its object's tree; a finished object walk hands its hit to the
 * ray and the slot goes on to the ray's next object, or to the next ray. */
static inline __attribute__((always_inline)) void objs_trace(const rtk_accel *accel, void *const *rays,
                                                             uint32_t count, const rtk_query *q, int closest,
                                                             objs_slot *slots)
{
    const unsigned qfeat = query_feat(q);
    objs_slot *active[RTK_STREAM_K];
    int n_active = RTK_STREAM_K;
    for (int k = 0; k < RTK_STREAM_K; k++) {
        slots[k].it = NULL;
        active[k] = &slots[k];
    }
    stream_src src;
    stream_src_init(&src, rays, count);
    stream_resume(&src, q);
    while (n_active > 0) {
        for (int j = 0; j < n_active;) {
            objs_slot *o = active[j];
            int more = 0;
            if (o->it) {
                stream_slot *s = &o->s;
                const rtk_accel *tree = o->it->accel;
                int go;
                if (!(s->cur & RTK_BVH4_LEAF_BIT)) {
                    go = stream_node_step(tree, s, o->pre, !closest);
                } else if (closest) {
                    go = stream_leaf_closest(tree, s, o->pre);
                } else {
                    go = stream_leaf_any(tree, s, o->pre);
                    if (go < 0) /* occluded */
                        ((rtk_ray *)s->ray)->tfar = -INFINITY;
                }
                if (go > 0) {
                    j++;
                    continue;
                }
                if (closest) { /* the object's walk is done: its hit is the ray's so far */
                    if (s->best.lane >= 0) {
                        o->w.best = s->best;
                        o->w.best_leaves = tree;
                        o->w.best_inst = o->it->inst_id;
                    }
                    o->tfar = s->tfar_s;
                }
                more = go == 0;
            }
            if (objs_advance(accel, &src, o, q, qfeat, closest, more))
                j++;
            else
                active[j] = active[--n_active];
        }
    }
    stream_keep_state(&src, q);
}

/* The slots of a call, from the heap (each holds two stacks: several KB);
 * NULL when memory runs out, and the call goes ray by ray.  So does a
 * packet's call (core/query.c hands over a packet's rays as a stream, with
 * no stream state to resume: fewer rays than a window): interleaved, or
 * one after the other behind the slots' allocation, the path tracer's
 * packets of 8 through the dragon's dynamic scene ran 10-13% slower than
 * the merged single-ray traversal, and through its instances no faster
 * (rtktool bench --only twolevel --api packet8 --alt, AMD EPYC, either
 * build first). */
static objs_slot *objs_slots(uint32_t count, const rtk_query *q)
{
    if (count < RTK_STREAM_WINDOW && !(q->flags & RTK_QUERY_FLAG_STREAM_STATE))
        return NULL;
    return aligned_alloc(64, (sizeof(objs_slot) * RTK_STREAM_K + 63) / 64 * 64);
}

/* Both queries' entry (closest a constant in each). */
static inline __attribute__((always_inline)) void objs_stream(const rtk_accel *accel, void *const *rays,
                                                              uint32_t count, const rtk_query *q, int closest)
{
    if (accel->root == RTK_BVH4_EMPTY || !count)
        return;
    objs_slot *slots = objs_slots(count, q);
    if (!slots) {
        for (uint32_t i = 0; i < count; i++) {
            if (closest)
                OBJS_INTERSECT1(accel, rays[i], q);
            else
                OBJS_OCCLUDED1(accel, rays[i], q);
        }
        return;
    }
    objs_trace(accel, rays, count, q, closest, slots);
    free(slots);
}

void OBJS_INTERSECT_STREAM(const rtk_accel *accel, rtk_rayhit *const *rays, uint32_t count, const rtk_query *q)
{
    objs_stream(accel, (void *const *)rays, count, q, 1);
}

void OBJS_OCCLUDED_STREAM(const rtk_accel *accel, rtk_ray *const *rays, uint32_t count, const rtk_query *q)
{
    objs_stream(accel, (void *const *)rays, count, q, 0);
}

#undef OBJS_INTERSECT1
#undef OBJS_OCCLUDED1
#undef OBJS_INTERSECT_STREAM
#undef OBJS_OCCLUDED_STREAM
#undef OBJS_TOP8
#undef OBJS_TOP_STACK
