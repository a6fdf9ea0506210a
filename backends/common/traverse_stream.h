/*
 * Stream traversal of the bvhN.triangle4 layouts, bvh4.triangle4i and the
 * robust ones: many single rays in flight on one thread, interleaved.
 *
 * A single ray's traversal is one chain of dependent loads: each node test
 * waits for its node, which is a cache miss on incoherent rays (on
 * dragon.ply's bounces from random points some 190 ns each on the AMD EPYC
 * development VM, where ../shared/tools/memory_parallelism.c measures
 * 191 ns per dependent miss alone and 11.6 ns per miss with 16 chains in
 * flight).  A stream of rays has no such chain between its rays, so this
 * kernel keeps RTK_STREAM_K of them going at once (the technique known from
 * databases as asynchronous memory access chaining): each slot holds one
 * ray's state (its precomputed ray, stack, current node and closest hit);
 * a step advances one slot by one node test or one leaf, asks for the
 * memory its next step will read (prefetch_child), and the loop moves on to
 * the next slot, so that by the time it comes back the memory has arrived.
 * A slot whose ray is done takes the next ray of the stream.
 *
 * Every step is the single-ray traversal's (traverse_bvhn.h: next_leaf's
 * node step, closest_from_'s and the any-hit loop's leaf step, the same
 * node and triangle tests, the same stack discipline), only interleaved
 * with other rays' steps, so each ray visits the same nodes and leaves in
 * the same order and gets rtk_intersect1's answer bit for bit, ties
 * included.  Rays that need masks, culling or filters (feat_init), and with
 * FMA rays the fused node test cannot take (ray_pre.fma), go through the
 * single-ray entry points, whose traversals for them are their own.
 *
 * Motion blur (traverse_motion.h, RTK_MOTION) interleaves the same way:
 * each slot walks the tree of its ray's time segment (segment_at), with
 * the planes and vertices at the ray's time, as rtk_intersect1 does.
 * Motion blur has no packet kernels, so its coherent groups go ray by
 * ray.
 *
 * Any hits have a third way on avx2's default layouts: rays of one octant
 * walked together by masks (stream_occluded_masks), which the stream's
 * timing windows weigh against the other two (stream_window).
 *
 * A template included after traverse_bvhn.h (or traverse_motion.h's entry
 * points); it defines rtk_bvh<tag>_intersect_stream and
 * rtk_bvh<tag>_occluded_stream (rtk_backend.h: rtk_intersect_stream_fn),
 * and the inline helpers the packet kernels call for packets whose rays
 * scatter.
 */
#include <stdlib.h>
#include <stddef.h>
#include <string.h>

#if !defined(RTK_BVHN)
#error "include traverse_bvhn.h first"
#endif

#define BVHN_INTERSECT_STREAM RTK_SYM(BVHN_NAME(BVHN_TAG, intersect_stream))
#define BVHN_OCCLUDED_STREAM RTK_SYM(BVHN_NAME(BVHN_TAG, occluded_stream))

/* One ray in flight: what its steps read most first. */
typedef struct stream_slot {
    vnode ntnear, ntfar; /* tnear and tfar broadcast for the node tests (-0.0 made +0.0) */
    ray_pre p;
    ray_mem m;
#if !RTK_SIMD_HAS_FMA || RTK_ROBUST
    leaf_ray lr; /* the ray of the unfused and the watertight triangle tests (the fused one reads m) */
#endif
    void *ray; /* the rtk_rayhit or rtk_ray */
#if RTK_MOTION
    const rtk_accel *tree; /* the tree of the ray's time segment */
#endif
    closest_hit best;
    float tnear_s, tfar_s;
    uint32_t cur;
    int sp;
    stack_entry stack[RTK_BVHN_STACK_SIZE(RTK_BVHN)];
} stream_slot;

/* The tree slot s walks: its time segment's with motion blur, else the
 * stream's. */
#if RTK_MOTION
#define STREAM_TREE(accel, s) ((s)->tree)
#else
#define STREAM_TREE(accel, s) (accel)
#endif

/* The memory of a reference popped from the stack, asked for again (it was
 * when it was pushed, but other rays' steps may have pushed it out since). */
static inline __attribute__((always_inline)) void stream_prefetch_ref(const rtk_accel *accel, uint32_t ref)
{
    const char *a;
    if (ref & RTK_BVH4_LEAF_BIT) {
#if RTK_LEAF_INDEXED || RTK_MOTION
        a = (const char *)&accel->trisi[rtk_leaf_first(ref)];
#else
        a = (const char *)&accel->tris[rtk_leaf_first(ref)];
#endif
    } else {
        a = (const char *)&BVHN_NODES(accel)[ref];
    }
    __builtin_prefetch(a);
    __builtin_prefetch(a + 64);
    __builtin_prefetch(a + 128);
    __builtin_prefetch(a + 192);
}

/* Sets up slot s for ray r (its rtk_ray first); 0 when the ray is not for
 * the interleaved traversal (features, or no fused test: the caller sends
 * it through the single-ray entry point). */
static inline __attribute__((always_inline)) int stream_start(const rtk_accel *accel, stream_slot *s, rtk_ray *r)
{
    if (__builtin_expect(ray_feat(accel, r) != 0, 0))
        return 0;
    ray_pre_init(&s->p, &s->m, r, accel);
#if RTK_MOTION
    s->tree = segment_at(accel, r->time, &s->p);
    if (!s->tree) /* (no hit: the single call says so) */
        return 0;
#endif
#if RTK_SIMD_HAS_FMA
    if (__builtin_expect(!s->p.fma, 0))
        return 0;
#endif
#if !RTK_SIMD_HAS_FMA || RTK_ROBUST
    leaf_ray_init(&s->lr, &s->p);
#endif
    s->ray = r;
    s->best = CLOSEST_HIT_NONE;
    s->tnear_s = r->tnear;
    s->tfar_s = r->tfar;
    s->ntnear = vn_set1(r->tnear + 0.0f);
    s->ntfar = vn_set1(r->tfar + 0.0f);
    s->cur = STREAM_TREE(accel, s)->root;
    s->sp = 0;
    return 1;
}

static inline const leaf_ray *stream_leaf_ray(const stream_slot *s)
{
#if RTK_SIMD_HAS_FMA && !RTK_ROBUST
    (void)s;
    return NULL;
#else
    return &s->lr;
#endif
}

/* One node step of next_leaf (anyhit as there) for slot s at inner node
 * s->cur, with the ray's set-up p (the slot's own s->p here; a two-level
 * walk's may be shared by the objects it enters, traverse_objects_stream.h);
 * 0 when the ray is done (nothing hit and the stack ran out). */
static inline __attribute__((always_inline)) int stream_node_step(const rtk_accel *accel, stream_slot *s,
                                                                  const ray_pre *p, int anyhit)
{
    accel = STREAM_TREE(accel, s);
    const node_t *n = &BVHN_NODES(accel)[s->cur];
    const uint32_t *child = n->child;
    vnode dists;
    unsigned mask = node_intersect(n, p, s->ntnear, s->ntfar, &dists, BVHN_FUSED);
    if (mask && !(mask & (mask - 1))) { /* one child */
        const int i = __builtin_ctz(mask);
        s->cur = child[i];
        prefetch_child(accel, n, i);
        return 1;
    }
    if (mask && anyhit) { /* as next_leaf: the last child first, the others pushed */
        const int last = 31 - __builtin_clz(mask);
        s->cur = child[last];
        prefetch_child(accel, n, last);
        int sp = s->sp;
        for (mask ^= 1u << last; mask; mask &= mask - 1) {
            const int i = __builtin_ctz(mask);
            s->stack[sp++] = (stack_entry){child[i], 0.0f};
            prefetch_child(accel, n, i);
        }
        s->sp = sp;
        return 1;
    }
    if (mask) {
        _Alignas(32) float dist[RTK_BVHN];
        vn_store(dist, dists);
        const int i0 = __builtin_ctz(mask);
        mask &= mask - 1;
        const int i1 = __builtin_ctz(mask);
        mask &= mask - 1;
        if (!mask) { /* two children: the far one pushed, the near one next */
            const int near = dist[i1] < dist[i0] ? i1 : i0, far = i0 + i1 - near;
            prefetch_child(accel, n, far);
            prefetch_child(accel, n, near);
            s->stack[s->sp++] = (stack_entry){child[far], dist[far]};
            s->cur = child[near];
            return 1;
        }
        s->sp = push_children(accel, n, (1u << i0) | (1u << i1) | mask, dists, s->stack, s->sp);
    }
    if (!pop_in_range(s->stack, &s->sp, s->tfar_s, &s->cur))
        return 0;
    stream_prefetch_ref(accel, s->cur);
    return 1;
}

/* The closest-hit query's leaf step (closest_from_'s leaf loop) for slot s
 * at leaf s->cur, then the pop; 0 when the ray is done.  (With motion blur
 * LEAF_BLOCK interpolates to p's time.) */
static inline __attribute__((always_inline)) int stream_leaf_closest(const rtk_accel *accel, stream_slot *s,
                                                                     const ray_pre *p)
{
    accel = STREAM_TREE(accel, s);
    const vfloat4 tnear = vf4_set1(s->tnear_s + 0.0f);
    float tfar_s = s->tfar_s;
    vfloat4 tfar = vf4_set1(tfar_s + 0.0f);
    const uint32_t first = rtk_leaf_first(s->cur), end = first + rtk_leaf_blocks(s->cur);
    for (uint32_t block = first; block < end; block++) {
        block_t scratch;
        const block_t *t = LEAF_BLOCK(accel, block, &scratch);
        tri4_hit h;
        unsigned mask = triangle4_intersect(t, p, stream_leaf_ray(s), tnear, tfar, &h);
        float t_lane;
        int lane;
        if (!mask || (lane = block_nearest(t, p, &h, mask, s->tnear_s, tfar_s, &t_lane, &s->best.u, &s->best.v)) < 0)
            continue;
        s->best.leaf = block;
        s->best.lane = lane;
        tfar_s = t_lane;
        tfar = vf4_set1(tfar_s + 0.0f);
    }
    if (tfar_s != s->tfar_s) {
        s->tfar_s = tfar_s;
        s->ntfar = vn_set1(tfar_s + 0.0f);
    }
    if (!pop_in_range(s->stack, &s->sp, tfar_s, &s->cur))
        return 0;
    stream_prefetch_ref(accel, s->cur);
    return 1;
}

/* The any-hit query's leaf step: -1 on a hit, 0 when the ray is done
 * without one, 1 to go on. */
static inline __attribute__((always_inline)) int stream_leaf_any(const rtk_accel *accel, stream_slot *s,
                                                                 const ray_pre *p)
{
    accel = STREAM_TREE(accel, s);
    const vfloat4 tnear = vf4_set1(s->tnear_s + 0.0f), tfar = vf4_set1(s->tfar_s + 0.0f);
    const uint32_t first = rtk_leaf_first(s->cur), end = first + rtk_leaf_blocks(s->cur);
    for (uint32_t block = first; block < end; block++) {
        tri4_hit h;
        block_t scratch;
        const block_t *t = LEAF_BLOCK(accel, block, &scratch);
        if (triangle4_intersect(t, p, stream_leaf_ray(s), tnear, tfar, &h))
            return -1;
    }
    if (!pop_in_range(s->stack, &s->sp, s->tfar_s, &s->cur))
        return 0;
    stream_prefetch_ref(accel, s->cur);
    return 1;
}

#if !RTK_MOTION
/* Any hits by masks: up to RTK_MASK_RAYS rays of one direction octant
 * walked through the tree together, as Embree 3's incoherent streams are
 * (rtcOccluded1M sorts a stream into octants and walks up to 32 rays of one
 * at a time; 64 measured 2-5% faster here, docs/benchmarks/streams.md).
 * The rays are set up eight at a time in vectors.  A stack entry is a node
 * and the mask of the rays that entered it; at a node its planes are loaded
 * once and each ray of the mask is tested against its children with the
 * single-ray kernel's fused test (the same constants, read from arrays by
 * ray), the children's ray masks gathered in two vectors (rays 0-31 and
 * 32-63); at a leaf each ray of the mask takes the
 * single-ray triangle test, and a ray that hits leaves every mask.  Every
 * ray enters exactly the boxes it enters alone, so it reaches the same
 * leaves and gets rtk_occluded1's answer (whatever the order: any hit).
 * One node read serves every ray that reaches it, which pays where the
 * rays share the tree's upper nodes and those are in the caches (rays from
 * scattered points along one direction: San Miguel's sun rays, the
 * procedural mesh's shadow rays, docs/benchmarks/streams.md); where each
 * ray waits on memory of its own, interleaving pays more, and the stream's
 * timing windows choose (stream_window).  Only the fused test of the
 * default layouts on 8-wide trees (avx2) has it. */
#define RTK_MASK_RAYS 64
#if RTK_SIMD_HAS_FMA && !RTK_ROBUST && RTK_BVHN == 8
#define RTK_MASK_FAST 1
#endif

#ifdef RTK_MASK_FAST
typedef uint64_t mask_t;
static __attribute__((noinline)) void stream_occluded_masks(const rtk_accel *accel, rtk_ray *const *rays, uint32_t n,
                                                           const rtk_query *q)
{
    _Alignas(64) float inv[3][RTK_MASK_RAYS], cn[3][RTK_MASK_RAYS], cf[3][RTK_MASK_RAYS], tn[RTK_MASK_RAYS],
        tf[RTK_MASK_RAYS], bits[32];
    _Alignas(64) ray_mem rm[RTK_MASK_RAYS];
    size_t near_off[3], far_off[3];
    mask_t active = 0;
    for (uint32_t i = 0; i < 32; i++) {
        const uint32_t b = 1u << i;
        memcpy(&bits[i], &b, 4);
    }
    /* the rays set up eight at a time, in vectors by component:
     * ray_pre_init_v's arithmetic lane by lane, so each ray gets the
     * single-ray kernel's reciprocals and c values to the bit */
    for (uint32_t i0 = 0; i0 < n; i0 += 8) {
        vfloat4 o[8], d[8];
        for (int c = 0; c < 8; c++) {
            const rtk_ray *r = rays[i0 + c < n ? i0 + c : i0];
            o[c] = vf4_loadu(&r->org_x);
            d[c] = vf4_loadu(&r->dir_x);
            vf4_store(rm[i0 + c].o, o[c]); /* (the fused triangle test reads o and d) */
            vf4_store(rm[i0 + c].d, d[c]);
        }
        vf4_transpose(&o[0], &o[1], &o[2], &o[3]);
        vf4_transpose(&o[4], &o[5], &o[6], &o[7]);
        vf4_transpose(&d[0], &d[1], &d[2], &d[3]);
        vf4_transpose(&d[4], &d[5], &d[6], &d[7]);
        const vfloat8 tiny = vf8_set1(RTK_ZERO_DIR), ulp4 = vf8_set1(0x1p-22f), min_normal = vf8_set1(0x1p-126f);
        unsigned in_range = 0xff;
        for (int k = 0; k < 3; k++) {
            const vfloat8 ok = vf8_from4(o[k], o[4 + k]), dk = vf8_from4(d[k], d[4 + k]);
            const vfloat8 ik = vf8_div(vf8_set1(1.0f), vf8_select(vf8_lt(vf8_abs(dk), tiny), vf8_xor_sign(tiny, dk), dk));
            const vfloat8 c = vf8_mul(ok, ik), e = vf8_add(vf8_mul(vf8_abs(c), ulp4), min_normal);
            vf8_store(&inv[k][i0], ik);
            vf8_store(&cn[k][i0], vf8_add(c, e));
            vf8_store(&cf[k][i0], vf8_sub(c, e));
            in_range &= (unsigned)vb8_mask(vf8_le(vf8_abs(c), vf8_set1(0x1p126f)));
            /* (and a zero direction component: the subtract-then-multiply
             * test, stream_zero_dir; by the fused one here avx2 missed
             * test_rays' rays along a grid's edge x = 0) */
            in_range &= ~(unsigned)vb8_mask(vf8_lt(vf8_abs(dk), tiny));
        }
        vf8_store(&tn[i0], vf8_add(vf8_from4(o[3], o[7]), vf8_set1(0.0f)));
        const uint32_t m = n - i0 < 8 ? n - i0 : 8;
        for (uint32_t c = 0; c < m; c++) {
            rtk_ray *r = rays[i0 + c];
            /* features, or not for the fused test (ray_pre.fma): the
             * single-ray kernel's own ways */
            if (ray_feat(accel, r) != 0 || !(in_range >> c & 1)) {
                BVHN_OCCLUDED1(accel, r, q);
                continue;
            }
            tf[i0 + c] = r->tfar + 0.0f;
            active |= (mask_t)1 << (i0 + c);
        }
    }
    /* the planes by the direction's sign bits, as ray_pre_init_v picks
     * them (one octant: the rays came binned by them) */
    const unsigned neg = (unsigned)vf4_signs(vf4_loadu(&rays[0]->dir_x)) & 7;
    for (int k = 0; k < 3; k++) {
        near_off[k] = plane_offsets[neg][0][k];
        far_off[k] = plane_offsets[neg][1][k];
    }
    if (!active)
        return;
    ray_pre shell; /* (the fused triangle test reads only its ray_mem) */
    typedef struct {
        mask_t mask;
        uint32_t ref;
    } mask_entry;
    mask_entry stack[RTK_BVHN_STACK_SIZE(RTK_BVHN)];
    int sp = 0;
    stack[sp++] = (mask_entry){active, accel->root};
    while (sp > 0) {
        sp--;
        uint32_t cur = stack[sp].ref;
        mask_t mask = stack[sp].mask & active;
        if (!mask)
            continue;
        while (!(cur & RTK_BVH4_LEAF_BIT)) {
            const node_t *nd = &BVHN_NODES(accel)[cur];
            const vnode nx = plane(nd, near_off[0]), ny = plane(nd, near_off[1]), nz = plane(nd, near_off[2]);
            const vnode fx = plane(nd, far_off[0]), fy = plane(nd, far_off[1]), fz = plane(nd, far_off[2]);
            /* the children's ray masks, rays 0-31 and 32-63 */
            vnode acc[2] = {vn_set1(0.0f), vn_set1(0.0f)};
            for (int half = 0; half < 2; half++)
                for (uint32_t mm = (uint32_t)(mask >> 32 * half); mm; mm &= mm - 1) {
                    const int b = __builtin_ctz(mm), r = b + 32 * half;
                    const vnode ix = vn_set1_at(&inv[0][r]), iy = vn_set1_at(&inv[1][r]), iz = vn_set1_at(&inv[2][r]);
                    const vnode t0x = vn_msub(nx, ix, vn_set1_at(&cn[0][r]));
                    const vnode t0y = vn_msub(ny, iy, vn_set1_at(&cn[1][r]));
                    const vnode t0z = vn_msub(nz, iz, vn_set1_at(&cn[2][r]));
                    const vnode t1x = vn_msub(fx, ix, vn_set1_at(&cf[0][r]));
                    const vnode t1y = vn_msub(fy, iy, vn_set1_at(&cf[1][r]));
                    const vnode t1z = vn_msub(fz, iz, vn_set1_at(&cf[2][r]));
                    const vnode tmin = vn_maxi(vn_maxi(t0x, t0y), vn_maxi(t0z, vn_set1_at(&tn[r])));
                    const vnode tmax = vn_mini(vn_mini(t1x, t1y), vn_mini(t1z, vn_set1_at(&tf[r])));
                    const vbool8 hit = vn_gti(vn_add_ulps(tmax, RTK_FUSED_FAR_ULPS * RTK_FAR_ULPS + 1), tmin);
                    acc[half] = vb8_or(acc[half], vb8_and(hit, vn_set1_at(&bits[b])));
                }
            _Alignas(32) uint32_t cm[2][8];
            vn_store((float *)cm[0], acc[0]);
            vn_store((float *)cm[1], acc[1]);
            /* the children some ray entered: lanes not zero, as integers
             * (bit 31 is the sign; a float comparison would take the
             * lanes for denormals, zero under DAZ) */
            const vnode both = vb8_or(acc[0], acc[1]);
            unsigned any = (unsigned)(vn_mask(vn_gti(both, vn_set1(0.0f))) | vn_mask(both));
            if (!any)
                goto next;
            const int c0 = 31 - __builtin_clz(any);
            any ^= 1u << c0;
            for (; any; any &= any - 1) {
                const int c = __builtin_ctz(any);
                stack[sp++] = (mask_entry){cm[0][c] | (mask_t)cm[1][c] << 32, nd->child[c]};
                prefetch_child(accel, nd, c);
            }
            prefetch_child(accel, nd, c0);
            cur = nd->child[c0];
            mask = cm[0][c0] | (mask_t)cm[1][c0] << 32;
        }
        {
            const uint32_t first = rtk_leaf_first(cur), end = first + rtk_leaf_blocks(cur);
            for (mask_t mm = mask; mm; mm &= mm - 1) {
                const int r = __builtin_ctzll(mm);
                shell.m = &rm[r];
                const vfloat4 tnear = vf4_set1(tn[r]), tfar = vf4_set1(tf[r]);
                for (uint32_t block = first; block < end; block++) {
                    tri4_hit h;
                    block_t scratch;
                    const block_t *t = LEAF_BLOCK(accel, block, &scratch);
                    if (triangle4_intersect(t, &shell, NULL, tnear, tfar, &h)) {
                        active &= ~((mask_t)1 << r);
                        rays[r]->tfar = -INFINITY;
                        break;
                    }
                }
            }
            if (!active)
                return;
        }
    next:;
    }
}
#endif
#endif

/* Where the interleaved traversal takes its rays from: the stream, in
 * groups of RTK_STREAM_GROUP consecutive rays.  A group whose rays are
 * coherent (stream_coherent) is traced on the spot, the way such rays go
 * fastest: as a packet (RTK_STREAM_PACKET: the packet kernels of that
 * width), any hit through the usual kernel (whose any-hit answers are the
 * single-ray kernel's), closest hit through its exact form, which hands
 * back the rays whose answer the packet's order of tests may have changed
 * (two triangles tied within rounding) to be traced alone.  So are the
 * rays the interleaved traversal does not take (stream_start).  The others go into its slots one at a time. */
#define RTK_STREAM_GROUP 8
/* Whether the rays that are not coherent go faster interleaved or one
 * after the other depends on how often their memory is in the caches
 * (long incoherent rays through a large tree: interleaved, measured 1.9x
 * on dragon.ply; rays that mostly test the top of the tree and leave, as
 * San Miguel's bounces do: one after the other, interleaved 0.74x), which
 * the kernel cannot tell from the rays.  So it measures: the stream is
 * taken in windows of RTK_STREAM_WINDOW rays, one window each way (after
 * one that fills the slots), and the faster way takes the next
 * RTK_STREAM_EXPLOIT windows, then both are measured again; each time the
 * same way wins again it keeps the stream twice as long (up to
 * RTK_STREAM_EXPLOIT_MAX windows), since measuring the slower way costs.
 * Any hits on avx2's default layouts have a third way, measured after the
 * other two: by masks (stream_occluded_masks), the rays gathered into bins
 * by octant, coherent groups included; the bins are traced when full, at
 * the end of a measured window and before the way changes, so that
 * windows the masks keep fill whole bins.  Every way gives every ray the
 * same answer. */
#define RTK_STREAM_WINDOW 128
#define RTK_STREAM_EXPLOIT 16
#define RTK_STREAM_EXPLOIT_MAX 256
/* The masks win a choice when their measured window cost less than
 * RTK_STREAM_MASK_EDGE times the better of the other two ways' (in
 * quarters: 5/4).  A measured masks window reads dearer than the windows
 * the masks then keep: it ends by tracing every bin however few rays it
 * holds, where kept windows leave them to fill.  At 4/4 the masks kept
 * about 55% of the dragon's shadow stream's windows; at 5/4 the any
 * hit streams ran 1-6% faster on the shadow sets of San Miguel, the dragon
 * and procedural:4M beside it (either build first), and 6/4 gained on the
 * dragon what it lost on San Miguel (docs/benchmarks/streams.md); the
 * masks forced on every window (no choice) run the sun sets of
 * the dragon and procedural:4M at 0.4x of the interleaved way, which any
 * edge below 2x still finds. */
#define RTK_STREAM_MASK_EDGE 5
typedef struct stream_src {
    void *const *rays;
    uint32_t count, next, group_end;
    uint32_t window_start, window_end; /* the window in progress */
    int interleave;      /* the window's way: 1 interleaved, 0 one after the other */
    int step; /* -1: not begun, 0: filling, 1: measuring one by one, 2: measuring interleaved,
               * 4: measuring by masks, 3: exploiting */
    uint32_t left;       /* windows left to exploit */
    uint32_t span;       /* windows the last choice was given */
    uint64_t t0;         /* rtk_cycles() at the window's start */
    uint64_t cost_single; /* cycles of the measured one-by-one window, per ray */
    uint64_t cost_inter;  /* and of the interleaved one */
    int won;              /* the last choice: 0 one by one, 1 interleaved, 2 by masks */
#ifdef RTK_MASK_FAST
    int can_mask;         /* any hits: the masks are a third way */
    int masks;            /* the window's way is by masks (interleave 0) */
    uint32_t bin_n[8];    /* rays waiting per direction octant */
    rtk_ray *bin[8][RTK_MASK_RAYS]; /* (last: left unset by stream_src_init) */
#endif
} stream_src;

/* A stream of count rays begins.  Every field is zeroed but the bins' 4 KB
 * of pointers, which only bin_n's counts make readable: a packet's 8 rays
 * come through here too, and an initializer zeroed the whole struct, a
 * 4 KB memset per call. */
#ifdef RTK_MASK_FAST
_Static_assert(offsetof(stream_src, bin) + sizeof(((stream_src *)0)->bin) == sizeof(stream_src),
               "the bins end stream_src: a field after them would be left unset by stream_src_init");
#endif
static inline void stream_src_init(stream_src *src, void *const *rays, uint32_t count)
{
#ifdef RTK_MASK_FAST
    memset(src, 0, offsetof(stream_src, bin));
#else
    memset(src, 0, sizeof *src);
#endif
    src->rays = rays;
    src->count = count;
    src->step = -1;
    src->interleave = 1;
    src->t0 = rtk_cycles();
}

/* The way numbered w (0 one by one, 1 interleaved, 2 by masks) for the
 * next window. */
static inline void stream_way(stream_src *src, int w)
{
    src->interleave = w == 1;
#ifdef RTK_MASK_FAST
    src->masks = w == 2;
#endif
}

/* At a window's end: what the window cost, and the way of the next one. */
static inline void stream_window(stream_src *src, uint32_t rays)
{
    const uint64_t t = rtk_cycles();
    const uint64_t per_ray = (t - src->t0) / (rays ? rays : 1);
    src->t0 = t;
    int choose = 0;
    switch (src->step) {
    case -1: /* the first window fills the slots */
        src->step = 0;
        stream_way(src, 1);
        break;
    case 0: /* filled: measure one by one */
        src->step = 1;
        stream_way(src, 0);
        break;
    case 1:
        src->cost_single = per_ray;
        src->step = 2;
        stream_way(src, 1);
        break;
    case 2:
        src->cost_inter = per_ray;
#ifdef RTK_MASK_FAST
        if (src->can_mask) {
            src->step = 4;
            stream_way(src, 2);
            break;
        }
#endif
        choose = 1;
        break;
    case 4:
        choose = 1;
        break;
    default:
        if (--src->left == 0) {
            src->step = 1;
            stream_way(src, 0);
        }
        break;
    }
    if (choose) {
        int w = src->cost_inter <= src->cost_single ? 1 : 0;
        if (src->step == 4 && per_ray * 4 < (w ? src->cost_inter : src->cost_single) * RTK_STREAM_MASK_EDGE)
            w = 2;
        src->span = src->span && w == src->won ? 2 * src->span : RTK_STREAM_EXPLOIT;
        src->span = src->span < RTK_STREAM_EXPLOIT_MAX ? src->span : RTK_STREAM_EXPLOIT_MAX;
        src->won = w;
        stream_way(src, w);
        src->left = src->span;
        src->step = 3;
    }
}

/* The window in progress ended at src->next: measured, and the next one
 * begun there (RTK_STREAM_WINDOW rays, or the rest of the stream). */
static inline void stream_next_window(stream_src *src)
{
    stream_window(src, src->next - src->window_start);
    src->window_start = src->next;
    src->window_end = src->count - src->next < RTK_STREAM_WINDOW ? src->count : src->next + RTK_STREAM_WINDOW;
}

/* What a stream call leaves for the next stream call on the same tree, in
 * the query's stream state (rtk_query.stream_state, which the core keeps
 * per thread and tree, core/stream.c): the way being kept, how many
 * windows more, and how long the last choice was given (the doubling of
 * RTK_STREAM_EXPLOIT goes on across calls).  A call that ends while
 * measuring leaves step 0, and the next measures afresh; a state the
 * kernel cannot resume (another layout's, after the core found a new tree
 * at a freed one's address) is measured afresh as well. */
typedef struct stream_keep {
    int32_t step; /* 3: keep the way `won` for `left` windows more; 0: begin afresh */
    int32_t won;
    uint32_t left, span;
} stream_keep;
_Static_assert(sizeof(stream_keep) <= RTK_STREAM_STATE_SIZE, "the query's stream state holds a stream_keep");

/* At a call's start: the way the stream's previous call was keeping. */
static inline void stream_resume(stream_src *src, const rtk_query *q)
{
    if (!(q->flags & RTK_QUERY_FLAG_STREAM_STATE))
        return;
    const stream_keep *k = q->stream_state;
    src->span = k->span < RTK_STREAM_EXPLOIT_MAX ? k->span : RTK_STREAM_EXPLOIT_MAX;
    src->won = k->won;
    if (k->step != 3 || !k->left || k->won < 0 || k->won > 2)
        return;
#ifdef RTK_MASK_FAST
    if (k->won == 2 && !src->can_mask)
        return;
#else
    if (k->won == 2)
        return;
#endif
    src->step = 3;
    src->left = k->left;
    stream_way(src, k->won);
    /* (the first window begins now: no window of filling) */
    src->window_end = src->count < RTK_STREAM_WINDOW ? src->count : RTK_STREAM_WINDOW;
}

/* At a call's end: what the next call of the stream resumes. */
static inline void stream_keep_state(const stream_src *src, const rtk_query *q)
{
    if (!(q->flags & RTK_QUERY_FLAG_STREAM_STATE))
        return;
    stream_keep *k = q->stream_state;
    *k = (stream_keep){.step = src->step == 3 ? 3 : 0, .won = src->won, .left = src->left, .span = src->span};
}

#ifdef RTK_MASK_FAST
#define STREAM_MASKS(src) ((src)->masks)

/* The rays waiting in octant o's bin, traced by masks. */
static inline void stream_walk_bin(const rtk_accel *accel, stream_src *src, int o, const rtk_query *q)
{
    stream_occluded_masks(accel, src->bin[o], src->bin_n[o], q);
    src->bin_n[o] = 0;
}

/* The rays waiting in every octant's bin. */
static inline void stream_flush_bins(const rtk_accel *accel, stream_src *src, const rtk_query *q)
{
    for (int o = 0; o < 8; o++)
        if (src->bin_n[o])
            stream_walk_bin(accel, src, o, q);
}
#else
#define STREAM_MASKS(src) 0
#endif

static inline unsigned stream_zero_dir(const rtk_ray *r)
{
#if RTK_SIMD_HAS_FMA
    /* A zero direction component takes the single-ray kernel's
     * subtract-then-multiply test (ray_pre_init), not a packet's fused
     * one: a group with such a ray is not coherent, and the packet
     * kernels' stream of such rays (PK_(scattered)) does not come back to
     * them. */
    return fabsf(r->dir_x) < RTK_ZERO_DIR || fabsf(r->dir_y) < RTK_ZERO_DIR || fabsf(r->dir_z) < RTK_ZERO_DIR;
#else
    (void)r;
    return 0;
#endif
}

/* Whether rays[0 .. n) are coherent: none needs the features, their
 * direction signs agree on every axis, and their origins lie within a
 * sixteenth of the tree's largest side of each other (as PK_(scattered)
 * measures them): camera rays, and shadow rays to one light from
 * neighbouring hits.  Such rays share most of their nodes, which are then
 * in the caches, and there interleaving only costs. */
static inline int stream_coherent(const rtk_accel *accel, void *const *rays, uint32_t n)
{
    const rtk_ray *r0 = rays[0];
    const unsigned s0 = (r0->dir_x < 0.0f) | (r0->dir_y < 0.0f) << 1 | (r0->dir_z < 0.0f) << 2;
    float lo[3] = {r0->org_x, r0->org_y, r0->org_z}, hi[3] = {r0->org_x, r0->org_y, r0->org_z};
    unsigned feat = ray_feat(accel, r0) | stream_zero_dir(r0);
    for (uint32_t i = 1; i < n; i++) {
        const rtk_ray *r = rays[i];
        const unsigned si = (r->dir_x < 0.0f) | (r->dir_y < 0.0f) << 1 | (r->dir_z < 0.0f) << 2;
        if (si != s0)
            return 0;
        feat |= ray_feat(accel, r) | stream_zero_dir(r);
        const float o[3] = {r->org_x, r->org_y, r->org_z};
        for (int k = 0; k < 3; k++) {
            lo[k] = o[k] < lo[k] ? o[k] : lo[k];
            hi[k] = o[k] > hi[k] ? o[k] : hi[k];
        }
    }
    const float limit = accel->extent * (1.0f / 16.0f);
    return !feat && hi[0] - lo[0] <= limit && hi[1] - lo[1] <= limit && hi[2] - lo[2] <= limit;
}

/* The packet kernels the coherent groups' any hits go through: 8 wide
 * where the SIMD layer has 8-wide vectors, 4 with SSE4.1, none in the
 * scalar backend (which has no packet kernels: its groups go ray by ray). */
#if RTK_MOTION
/* (none) */
#elif defined(RTK_SIMD_HAS_8)
#define RTK_STREAM_PACKET 8
#elif defined(__SSE4_1__)
#define RTK_STREAM_PACKET 4
#endif
#ifdef RTK_STREAM_PACKET
#define STREAM_PK_NAME_(n, k) rtk_bvh##n##_occluded##k
#define STREAM_PK_NAME(n, k) STREAM_PK_NAME_(n, k)
#define STREAM_OCCLUDED_PACKET RTK_SYM(STREAM_PK_NAME(BVHN_TAG, RTK_STREAM_PACKET))
/* The rays' first 12 words (their rtk_ray) into the rows of a packet of
 * RTK_STREAM_PACKET rays at w: four words of four rays at a time,
 * transposed (lane stores would stall the kernel's row loads on store
 * forwarding). */
static inline void stream_gather(void *const *rays, float *w)
{
    enum { K = RTK_STREAM_PACKET };
    for (int b = 0; b < 3; b++) {
        vfloat4 x[K];
        for (int i = 0; i < K; i += 4) {
            for (int c = 0; c < 4; c++)
                x[i + c] = vf4_loadu((const float *)rays[i + c] + 4 * b);
            vf4_transpose(&x[i], &x[i + 1], &x[i + 2], &x[i + 3]);
        }
        for (int c = 0; c < 4; c++)
#if RTK_STREAM_PACKET == 8
            vf8_store(w + (4 * b + c) * K, vf8_from4(x[c], x[4 + c]));
#else
            vf4_store(w + (4 * b + c) * K, x[c]);
#endif
    }
}

static _Alignas(64) const int32_t stream_all[8] = {-1, -1, -1, -1, -1, -1, -1, -1};

/* A coherent group's any hits as one packet (rays: RTK_STREAM_PACKET of them). */
static void stream_occluded_group(const rtk_accel *accel, void *const *rays, const rtk_query *q)
{
    _Alignas(64) rtk_ray8 pk; /* (rtk_ray4's fields are a prefix of each row) */
    float *f = (float *)&pk;
    stream_gather(rays, f);
    STREAM_OCCLUDED_PACKET(accel, stream_all, &pk, q);
    for (int i = 0; i < RTK_STREAM_PACKET; i++)
        if (f[8 * RTK_STREAM_PACKET + i] == -INFINITY)
            ((rtk_ray *)rays[i])->tfar = -INFINITY;
}

#define STREAM_EXACT_NAME_(n, k) rtk_bvh##n##_intersect##k##_exact
#define STREAM_EXACT_NAME(n, k) STREAM_EXACT_NAME_(n, k)
#define STREAM_INTERSECT_PACKET RTK_SYM(STREAM_EXACT_NAME(BVHN_TAG, RTK_STREAM_PACKET))
/* A coherent group's closest hits as one packet, through the packet
 * kernel's exact form: the rays where the packet's order of tests may
 * have picked another of two triangles tied within rounding (rare: a ray
 * through a shared edge) it leaves alone, and they are traced here alone,
 * so every ray gets rtk_intersect1's answer. */
static void stream_intersect_group(const rtk_accel *accel, void *const *rays, const rtk_query *q)
{
    enum { K = RTK_STREAM_PACKET, HIT = sizeof(rtk_ray) / 4 };
    _Alignas(64) rtk_rayhit8 pk; /* (rtk_rayhit4's rows are a prefix of each: K words a row) */
    float *w = (float *)&pk;
    stream_gather(rays, w);
    /* the hit rows defined (the kernel blends them), geomID invalid (by
     * rows, as the rays) */
    const size_t geom_row = offsetof(rtk_rayhit, hit.geomID) / 4;
    const uint32_t invalid_bits = RTK_INVALID_GEOMETRY_ID;
    float invalid;
    memcpy(&invalid, &invalid_bits, sizeof invalid);
    for (size_t k = HIT; k < HIT + 8; k++)
        for (int i = 0; i < K; i += 4)
            vf4_store(w + k * K + i, vf4_set1(k == geom_row ? invalid : 0.0f));
    const uint32_t *geom = (const uint32_t *)(w + geom_row * K);
    const unsigned alone = STREAM_INTERSECT_PACKET(accel, stream_all, &pk, q);
    /* the hits back: the 8 hit words of four rays at a time, transposed */
    for (int i = 0; i < K; i += 4) {
        vfloat4 a[4], b[4];
        for (int c = 0; c < 4; c++) {
            a[c] = vf4_load(w + (HIT + c) * K + i);
            b[c] = vf4_load(w + (HIT + 4 + c) * K + i);
        }
        vf4_transpose(&a[0], &a[1], &a[2], &a[3]);
        vf4_transpose(&b[0], &b[1], &b[2], &b[3]);
        for (int c = 0; c < 4; c++) {
            float *out = (float *)rays[i + c];
            if (alone >> (i + c) & 1)
                BVHN_INTERSECT1(accel, (rtk_rayhit *)out, q);
            else if (geom[i + c] != RTK_INVALID_GEOMETRY_ID) {
                out[offsetof(rtk_ray, tfar) / 4] = w[offsetof(rtk_ray, tfar) / 4 * K + i + c];
                vf4_storeu(out + HIT, a[c]);
                vf4_storeu(out + HIT + 4, b[c]);
            }
        }
    }
}
#endif

/* A coherent group of n = RTK_STREAM_GROUP rays (stream_coherent),
 * traced on the spot: as packets where there are packet kernels, else ray
 * by ray.  (Out of line: one call per eight rays; inlined into the packet
 * kernels, whose lists hold four, GCC warns of reads it cannot see are
 * never reached.) */
static __attribute__((noinline)) void stream_group(const rtk_accel *accel, void *const *g, uint32_t n,
                                                  const rtk_query *q, int closest)
{
#ifdef RTK_STREAM_PACKET
    if (!closest) /* (RTK_STREAM_GROUP is a multiple of RTK_STREAM_PACKET) */
        for (uint32_t k = 0; k < n; k += RTK_STREAM_PACKET)
            stream_occluded_group(accel, g + k, q);
    else
        for (uint32_t k = 0; k < n; k += RTK_STREAM_PACKET)
            stream_intersect_group(accel, g + k, q);
#else
    for (uint32_t i = 0; i < n; i++) {
        if (closest)
            BVHN_INTERSECT1(accel, g[i], q);
        else
            BVHN_OCCLUDED1(accel, g[i], q);
    }
#endif
}

/* The next ray for the interleaved traversal, set up in slot s; 0 when the
 * stream has run out.  Coherent groups and the rays the slots do not take
 * are traced here on the way. */
static inline __attribute__((always_inline)) int stream_next(const rtk_accel *accel, stream_src *src, stream_slot *s,
                                                             const rtk_query *q, int closest)
{
    while (src->next < src->count) {
        if (src->next >= src->window_end) {
#ifdef RTK_MASK_FAST
            /* the bins traced at the end of a measured window (its cost
             * includes them) and before the way changes; between windows
             * that keep the masks they keep filling */
            if (src->masks && (src->step != 3 || src->left == 1))
                stream_flush_bins(accel, src, q);
#endif
            stream_next_window(src);
        }
        if (src->next == src->group_end) {
            const uint32_t n = src->count - src->next < RTK_STREAM_GROUP ? src->count - src->next : RTK_STREAM_GROUP;
            void *const *g = src->rays + src->next;
            src->group_end = src->next + n;
            if (n == RTK_STREAM_GROUP && !STREAM_MASKS(src) && stream_coherent(accel, g, n)) {
                stream_group(accel, g, n, q, closest);
                src->next = src->group_end;
                continue;
            }
        }
        void *r = src->rays[src->next++];
        if (src->interleave && stream_start(accel, s, r))
            return 1;
#ifdef RTK_MASK_FAST
        if (src->masks) { /* (any hits only) */
            /* the octant by the sign bits, as ray_pre_init picks the
             * planes (-0.0 counts as negative there) */
            const unsigned o = (unsigned)vf4_signs(vf4_loadu(&((const rtk_ray *)r)->dir_x)) & 7;
            src->bin[o][src->bin_n[o]++] = r;
            if (src->bin_n[o] == RTK_MASK_RAYS)
                stream_walk_bin(accel, src, (int)o, q);
            continue;
        }
#endif
        if (closest)
            BVHN_INTERSECT1(accel, r, q);
        else
            BVHN_OCCLUDED1(accel, r, q);
    }
#ifdef RTK_MASK_FAST
    stream_flush_bins(accel, src, q);
#endif
    return 0;
}

/* The stream driver both queries share (closest a constant in each):
 * slots fill from the stream, each active slot steps in turn, a finished
 * ray's answer is written and its slot takes the next ray. */
static inline __attribute__((always_inline)) void stream_trace(const rtk_accel *accel, void *const *rays,
                                                               uint32_t count, const rtk_query *q, int closest,
                                                               stream_slot *slots, int nslots)
{
    stream_slot *active[RTK_STREAM_K];
    int n_active = 0;
    stream_src src;
    stream_src_init(&src, rays, count);
#ifdef RTK_MASK_FAST
    src.can_mask = !closest;
#endif
    stream_resume(&src, q);
    for (int k = 0; k < nslots && stream_next(accel, &src, &slots[k], q, closest); k++)
        active[n_active++] = &slots[k];
    while (n_active > 0) {
        for (int j = 0; j < n_active;) {
            stream_slot *s = active[j];
            int go;
            if (!(s->cur & RTK_BVH4_LEAF_BIT)) {
                go = stream_node_step(accel, s, &s->p, !closest);
            } else if (closest) {
                go = stream_leaf_closest(accel, s, &s->p);
            } else {
                go = stream_leaf_any(accel, s, &s->p);
                if (go < 0) {
                    ((rtk_ray *)s->ray)->tfar = -INFINITY;
                    go = 0;
                }
            }
            if (go) {
                j++;
                continue;
            }
            if (closest)
                closest_hit_write(STREAM_TREE(accel, s), accel, &s->best, &s->p, s->tfar_s, s->ray);
            if (stream_next(accel, &src, s, q, closest))
                j++;
            else
                active[j] = active[--n_active];
        }
    }
    stream_keep_state(&src, q);
}

/* The slots of a stream call, from the heap: RTK_STREAM_K of them are
 * 4-9 KB each (their stacks), more than a task system's small thread
 * stacks should give one frame.  NULL when memory runs out: the call then
 * traces ray by ray. */
static stream_slot *stream_slots(void)
{
    return aligned_alloc(64, (sizeof(stream_slot) * RTK_STREAM_K + 63) / 64 * 64);
}

/* A stream of one coherent group (a packet of a layout without packet
 * kernels, which the core hands over as a stream): traced as the group it
 * is, without the slots' allocation. */
static inline int stream_one_group(const rtk_accel *accel, void *const *rays, uint32_t count, const rtk_query *q,
                                   int closest)
{
    if (count != RTK_STREAM_GROUP || !stream_coherent(accel, rays, count))
        return 0;
    stream_group(accel, rays, count, q, closest);
    return 1;
}

void BVHN_INTERSECT_STREAM(const rtk_accel *accel, rtk_rayhit *const *rays, uint32_t count, const rtk_query *q)
{
    if (accel->root == RTK_BVH4_EMPTY || !count || stream_one_group(accel, (void *const *)rays, count, q, 1))
        return;
    stream_slot *slots = stream_slots();
    if (__builtin_expect(!slots, 0)) {
        for (uint32_t i = 0; i < count; i++)
            BVHN_INTERSECT1(accel, rays[i], q);
        return;
    }
    stream_trace(accel, (void *const *)rays, count, q, 1, slots, RTK_STREAM_K);
    free(slots);
}

void BVHN_OCCLUDED_STREAM(const rtk_accel *accel, rtk_ray *const *rays, uint32_t count, const rtk_query *q)
{
    if (accel->root == RTK_BVH4_EMPTY || !count || stream_one_group(accel, (void *const *)rays, count, q, 0))
        return;
    stream_slot *slots = stream_slots();
    if (__builtin_expect(!slots, 0)) {
        for (uint32_t i = 0; i < count; i++)
            BVHN_OCCLUDED1(accel, rays[i], q);
        return;
    }
    stream_trace(accel, (void *const *)rays, count, q, 0, slots, RTK_STREAM_K);
    free(slots);
}
