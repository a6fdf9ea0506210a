/*
 * The leaf tests of the single-ray template (traverse_bvhn.h, which
 * includes this part of itself after the ray, the features and the
 * leaf blocks are defined): four triangles of a block at once against one
 * ray (Moeller-Trumbore, or the watertight test in robust layouts), the
 * hit floor, the nearest lane of a block, and the masks, culling and
 * filters a candidate passes through.  The stream and packet kernels
 * (traverse_stream.h, traverse_packet.h) call the same routines, so a ray
 * gets the same answer by every path.
 */
#if !defined(RTK_BVHN)
#error "a part of traverse_bvhn.h: include that"
#endif

/* Moeller-Trumbore (in Embree's form, geometry/triangle.h) on four
 * triangles at once, the same arithmetic as
 * rtk_triangle_intersect (geometry/triangle.h) lane by lane.  Returns the
 * mask of lanes hit within [tnear, tfar]; U, V, T and |det| per lane. */
typedef struct tri4_hit {
    vfloat4 U, V, T, absdet;
} tri4_hit;

#if RTK_ROBUST
/* The lanes of watertight4 whose float edge functions came out exactly
 * zero (or |det| below FLT_MIN), decided again in double: rare, so out of
 * the loops. */
static __attribute__((noinline, cold)) unsigned watertight_lanes(unsigned mask, unsigned zeros, const vfloat4 *xs,
                                                                 const vfloat4 *ys, const vfloat4 *zs, vfloat4 tnear,
                                                                 vfloat4 tfar, tri4_hit *h)
{
    _Alignas(16) float lx[3][4], ly[3][4], lz[3][4], hu[4], hv[4], ht[4], hd[4], tn[4], tf[4];
    for (int k = 0; k < 3; k++) {
        vf4_store(lx[k], xs[k]);
        vf4_store(ly[k], ys[k]);
        vf4_store(lz[k], zs[k]);
    }
    vf4_store(hu, h->U), vf4_store(hv, h->V), vf4_store(ht, h->T), vf4_store(hd, h->absdet);
    vf4_store(tn, tnear), vf4_store(tf, tfar);
    for (; zeros; zeros &= zeros - 1) {
        const int i = __builtin_ctz(zeros);
        const float a2[2] = {lx[0][i], ly[0][i]}, b2[2] = {lx[1][i], ly[1][i]}, c2[2] = {lx[2][i], ly[2][i]};
        const float z[3] = {lz[0][i], lz[1][i], lz[2][i]};
        rtk_tri_hit hit;
        mask &= ~(1u << i);
        if (!rtk_watertight_double(a2, b2, c2, z, tn[i], tf[i], &hit))
            continue;
        mask |= 1u << i;
        hu[i] = hit.u;
        hv[i] = hit.v;
        ht[i] = hit.t;
        hd[i] = 1.0f;
    }
    h->U = vf4_load(hu);
    h->V = vf4_load(hv);
    h->T = vf4_load(ht);
    h->absdet = vf4_load(hd);
    return mask;
}

/* The watertight test (rtk_triangle_intersect_watertight) on four
 * triangles at once, lane by lane the same arithmetic; a lane where an edge
 * function comes out exactly zero, or |det| below FLT_MIN, is decided again
 * alone in double precision (rare: a ray exactly through an edge or vertex,
 * a triangle seen edge-on, or one so small that its products underflow).
 * U and V are the weights of v1 and v2 times |det|, T the distance times
 * |det|; a lane decided in double gets |det| = 1.  The permuted axes kx,
 * ky, kz are constants here (triangle4_intersect picks one of three
 * copies), so each block's nine loads are at fixed offsets: with the axes
 * as variables the kernel recomputed and spilled nine addresses at every
 * leaf. */
static inline __attribute__((always_inline)) unsigned watertight4(const float *f, const leaf_ray *l, int kx, int ky,
                                                                  int kz, vfloat4 tnear, vfloat4 tfar, tri4_hit *h)
{
    /* vertex k's coordinate along axis j: f[12 * k + 4 * j] */
    const vfloat4 ox = LR_SET1(l->wo[0]), oy = LR_SET1(l->wo[1]), oz = LR_SET1(l->wo[2]);
    const vfloat4 sx = LR_SET1(l->s[0]), sy = LR_SET1(l->s[1]);
    const vfloat4 az = vf4_sub(vf4_load(f + 4 * kz), oz);
    const vfloat4 bz = vf4_sub(vf4_load(f + 12 + 4 * kz), oz);
    const vfloat4 cz = vf4_sub(vf4_load(f + 24 + 4 * kz), oz);
    const vfloat4 ax = vf4_sub(vf4_sub(vf4_load(f + 4 * kx), ox), vf4_mul(sx, az));
    const vfloat4 ay = vf4_sub(vf4_sub(vf4_load(f + 4 * ky), oy), vf4_mul(sy, az));
    const vfloat4 bx = vf4_sub(vf4_sub(vf4_load(f + 12 + 4 * kx), ox), vf4_mul(sx, bz));
    const vfloat4 by = vf4_sub(vf4_sub(vf4_load(f + 12 + 4 * ky), oy), vf4_mul(sy, bz));
    const vfloat4 cx = vf4_sub(vf4_sub(vf4_load(f + 24 + 4 * kx), ox), vf4_mul(sx, cz));
    const vfloat4 cy = vf4_sub(vf4_sub(vf4_load(f + 24 + 4 * ky), oy), vf4_mul(sy, cz));
    const vfloat4 U = vf4_sub(vf4_mul(cx, by), vf4_mul(cy, bx));
    const vfloat4 V = vf4_sub(vf4_mul(ax, cy), vf4_mul(ay, cx));
    const vfloat4 W = vf4_sub(vf4_mul(bx, ay), vf4_mul(by, ax));
    const vfloat4 zero = vf4_set1(0.0f);
    const vfloat4 det = vf4_add(vf4_add(U, V), W);
    const vfloat4 absdet = vf4_abs(det);
    const vfloat4 sz = LR_SET1(l->s[2]);
    const vfloat4 szaz = vf4_mul(sz, az), szbz = vf4_mul(sz, bz), szcz = vf4_mul(sz, cz);
    const vfloat4 T = vf4_xor_sign(vf4_add(vf4_add(vf4_mul(U, szaz), vf4_mul(V, szbz)), vf4_mul(W, szcz)), det);
    vbool4 ok = vf4_ge(absdet, vf4_set1(FLT_MIN));
    ok = vb4_and(ok, vf4_ge(T, vf4_mul(tnear, absdet)));
    ok = vb4_and(ok, vf4_le(T, vf4_mul(tfar, absdet)));
    /* inside: U, V and W of one sign, their sign bits agreeing (a lane
     * with a zero among them is decided below) */
    unsigned mask = (unsigned)vb4_mask(ok) & ~(unsigned)vf4_signs(vf4_or(vf4_xor(U, V), vf4_xor(U, W)));
    /* a zero among U, V, W makes the product zero (so does one that
     * underflows, which the exact test below then decides too; an empty
     * lane's NaN never does) */
    const unsigned zeros = (unsigned)vb4_mask(
        vb4_or(vf4_eq(vf4_mul(vf4_mul(U, V), W), zero), vf4_lt(absdet, vf4_set1(FLT_MIN))));
    h->U = vf4_xor_sign(V, det);
    h->V = vf4_xor_sign(W, det);
    h->T = T;
    h->absdet = absdet;
    if (__builtin_expect(zeros != 0, 0)) {
        const vfloat4 xs[3] = {ax, bx, cx}, ys[3] = {ay, by, cy}, zs[3] = {szaz, szbz, szcz};
        mask = watertight_lanes(mask, zeros, xs, ys, zs, tnear, tfar, h);
    }
    return mask;
}

static inline __attribute__((always_inline)) unsigned triangle4_intersect(const block_t *t, const ray_pre *p,
                                                                          const leaf_ray *l, vfloat4 tnear,
                                                                          vfloat4 tfar, tri4_hit *h)
{
    (void)p; /* (the watertight test takes the ray from l) */
    const float *f = (const float *)t;
    switch (l->kz) {
    case 0:
        return watertight4(f, l, 1, 2, 0, tnear, tfar, h);
    case 1:
        return watertight4(f, l, 2, 0, 1, tnear, tfar, h);
    default:
        return watertight4(f, l, 0, 1, 2, tnear, tfar, h);
    }
}
#else
static inline unsigned triangle4_intersect(const block_t *t, const ray_pre *p, const leaf_ray *l, vfloat4 tnear,
                                           vfloat4 tfar, tri4_hit *h)
{
    const vfloat4 e1x = vf4_load(t->e1x), e1y = vf4_load(t->e1y), e1z = vf4_load(t->e1z);
    const vfloat4 e2x = vf4_load(t->e2x), e2y = vf4_load(t->e2y), e2z = vf4_load(t->e2z);
    (void)p;
#if RTK_SIMD_HAS_FMA
    /* the ray from memory at every block (see ray_mem) */
    (void)l;
    const vfloat4 dx = vf4_set1_at(&p->m->d[0]), dy = vf4_set1_at(&p->m->d[1]), dz = vf4_set1_at(&p->m->d[2]);
    const vfloat4 ox = vf4_set1_at(&p->m->o[0]), oy = vf4_set1_at(&p->m->o[1]), oz = vf4_set1_at(&p->m->o[2]);
#else
    const vfloat4 dx = l->dir[0], dy = l->dir[1], dz = l->dir[2];
    const vfloat4 ox = l->org[0], oy = l->org[1], oz = l->org[2];
#endif
    /* n = cross(e1, e2), c = v0 - o: det and T first, so that n is done
     * with before r = cross(c, d) is made (fewer registers live) */
    const vfloat4 nx = vf4_sub(vf4_mul(e1y, e2z), vf4_mul(e1z, e2y));
    const vfloat4 ny = vf4_sub(vf4_mul(e1z, e2x), vf4_mul(e1x, e2z));
    const vfloat4 nz = vf4_sub(vf4_mul(e1x, e2y), vf4_mul(e1y, e2x));
    const vfloat4 det = vf4_add(vf4_add(vf4_mul(nx, dx), vf4_mul(ny, dy)), vf4_mul(nz, dz));
    const vfloat4 absdet = vf4_abs(det);
    const vfloat4 cx = vf4_sub(vf4_load(t->v0x), ox);
    const vfloat4 cy = vf4_sub(vf4_load(t->v0y), oy);
    const vfloat4 cz = vf4_sub(vf4_load(t->v0z), oz);
    const vfloat4 T = vf4_xor_sign(vf4_add(vf4_add(vf4_mul(nx, cx), vf4_mul(ny, cy)), vf4_mul(nz, cz)), det);
    const vfloat4 rx = vf4_sub(vf4_mul(cy, dz), vf4_mul(cz, dy));
    const vfloat4 ry = vf4_sub(vf4_mul(cz, dx), vf4_mul(cx, dz));
    const vfloat4 rz = vf4_sub(vf4_mul(cx, dy), vf4_mul(cy, dx));
    const vfloat4 U = vf4_xor_sign(vf4_add(vf4_add(vf4_mul(rx, e2x), vf4_mul(ry, e2y)), vf4_mul(rz, e2z)), det);
    const vfloat4 V = vf4_xor_sign(vf4_add(vf4_add(vf4_mul(rx, e1x), vf4_mul(ry, e1y)), vf4_mul(rz, e1z)),
                                   vf4_xor(det, vf4_set1(-0.0f)));
    const vfloat4 zero = vf4_set1(0.0f);
    vbool4 ok = vb4_and(vf4_ge(U, zero), vf4_ge(V, zero));
    ok = vb4_and(ok, vf4_le(vf4_add(U, V), absdet));
    ok = vb4_and(ok, vf4_ge(absdet, vf4_set1(FLT_MIN))); /* 1 / absdet finite (geometry/triangle.h) */
    ok = vb4_and(ok, vf4_ge(T, vf4_mul(tnear, absdet)));
    ok = vb4_and(ok, vf4_le(T, vf4_mul(tfar, absdet)));
    h->U = U;
    h->V = V;
    h->T = T;
    h->absdet = absdet;
    return (unsigned)vb4_mask(ok);
}
#endif

/* The hit floor.  A hit's distance is T / |det| rounded; where the ray
 * grazes the triangle's plane (|det| tiny: a needle, or a ray nearly in the
 * plane) it can come out far nearer than any point of the triangle, a
 * point outside the triangle's box and its leaf's.  Which such hit a ray
 * gets would then depend on the order of the boxes it visits (the leaf is
 * tested only if no hit beyond that distance has pruned it first), so the
 * packet and stream kernels, which visit in other orders, could not give
 * rtk_intersect1's answer (conformance: the stream gave 0x1.fffa58p-1
 * where the single call gave 0x1.ffff7ep-1 on the sphere and soup; a
 * ray along a pole triangle of a ball got t = 32768 from 54000 units
 * away).  So every closest-hit kernel raises a hit's distance to where the
 * ray enters the triangle's bounding box, less 2^-20 of it: a hit that
 * is not that far off keeps its distance to the bit (a well-conditioned
 * hit is a few ulps from the true one, which lies in the box), one that is
 * comes out at the box, nearer the truth; and then a hit never lies
 * nearer than its leaf's entry distance by more than the near-tie band of
 * the packet kernels (PK_TIE_REL, 2^-16), so the nearest one does not
 * depend on the order of the visits.  A hit whose floor lies beyond tfar
 * is no hit.  The floor is computed with the exact reciprocal of the
 * direction and the vertices as the triangle tests see them, by
 * operations no compiler contracts (subtract, then multiply), the same in
 * the single-ray, stream and packet kernels (PK_(hit_floor)). */
#if RTK_ROBUST
static inline void block_axis(const block_t *t, int k, vfloat4 *a, vfloat4 *b, vfloat4 *c)
{
    const float *f = (const float *)t; /* vertex v's coordinate along axis k: f[12 * v + 4 * k] */
    *a = vf4_load(f + 4 * k);
    *b = vf4_load(f + 12 + 4 * k);
    *c = vf4_load(f + 24 + 4 * k);
}
#else
static inline void block_axis(const block_t *t, int k, vfloat4 *a, vfloat4 *b, vfloat4 *c)
{
    const float *v0 = k == 0 ? t->v0x : k == 1 ? t->v0y : t->v0z;
    const float *e1 = k == 0 ? t->e1x : k == 1 ? t->e1y : t->e1z;
    const float *e2 = k == 0 ? t->e2x : k == 1 ? t->e2y : t->e2z;
    *a = vf4_load(v0);
    *b = vf4_add(*a, vf4_load(e1));
    *c = vf4_add(*a, vf4_load(e2));
}
#endif

/* Lane j's three coordinates along axis k, as block_axis has them. */
static inline void lane_axis(const block_t *t, int j, int k, float *a, float *b, float *c)
{
#if RTK_ROBUST
    const float *f = (const float *)t;
    *a = f[4 * k + j];
    *b = f[12 + 4 * k + j];
    *c = f[24 + 4 * k + j];
#else
    const float *v0 = k == 0 ? t->v0x : k == 1 ? t->v0y : t->v0z;
    const float *e1 = k == 0 ? t->e1x : k == 1 ? t->e1y : t->e1z;
    const float *e2 = k == 0 ? t->e2x : k == 1 ? t->e2y : t->e2z;
    *a = v0[j];
    *b = *a + e1[j];
    *c = *a + e2[j];
#endif
}

/* (see block_hit_floor) */
#define RTK_FLOOR_PAD 0x1p-22f

/* Lane j's lowest and highest coordinate along axis k, as minps / maxps
 * give them over block_axis's three (spelled as their comparisons). */
static inline void lane_axis_bounds(const block_t *t, int j, int k, float *lo, float *hi)
{
    float a, b, c;
    lane_axis(t, j, k, &a, &b, &c);
    const float ab_lo = a < b ? a : b, ab_hi = a > b ? a : b;
    *lo = ab_lo < c ? ab_lo : c;
    *hi = ab_hi > c ? ab_hi : c;
}

/* The same, each moved out by block_hit_floor's pad. */
static inline void lane_axis_range(const block_t *t, int j, int k, float *lo, float *hi)
{
    float l, h;
    lane_axis_bounds(t, j, k, &l, &h);
    const float al = fabsf(l), ah = fabsf(h);
    const float pad = (al > ah ? al : ah) * RTK_FLOOR_PAD;
    *lo = l - pad;
    *hi = h + pad;
}

/* The floors of a block's four triangles for ray p (see above).  The box
 * is widened by 2^-22 of its largest coordinate magnitude on each axis:
 * v0 + e1 and v0 + e2 can round an ulp of that magnitude away from the
 * vertices themselves, and a ray through such a vertex along a zero
 * direction component (reciprocal 1e18) then found the box an ulp
 * outside it and got a floor of an ulp times 1e18: t = 3.7e9 for a hit at
 * 0.3 (test_rays, axis_rays_through_vertices). */
static inline __attribute__((always_inline)) vfloat4 block_hit_floor(const block_t *t, const ray_pre *p)
{
    vfloat4 entry = vf4_set1(0.0f);
    for (int k = 0; k < 3; k++) {
        vfloat4 a, b, c;
        block_axis(t, k, &a, &b, &c);
        const vfloat4 lo = vf4_min(vf4_min(a, b), c), hi = vf4_max(vf4_max(a, b), c);
        const vfloat4 pad = vf4_mul(vf4_max(vf4_abs(lo), vf4_abs(hi)), vf4_set1(RTK_FLOOR_PAD));
        const vfloat4 near = p->rs[k] < 0.0f ? vf4_add(hi, pad) : vf4_sub(lo, pad);
        const vfloat4 tk = vf4_mul(vf4_sub(near, vf4_set1(p->os[k])), vf4_set1(p->rs[k]));
        entry = k ? vf4_max(entry, tk) : tk;
    }
    entry = vf4_add(entry, vf4_set1(0.0f)); /* (-0.0 -> +0.0) */
    return vf4_sub(entry, vf4_mul(vf4_abs(entry), vf4_set1(0x1p-20f)));
}

/* An upper bound on each lane's floor: block_hit_floor's operations one
 * by one (the product by 2^-20 is exact, so a fused multiply-subtract
 * rounds the same) on the box without its pad, which can only raise each
 * step.  A distance at or above it is at or above the floor, and
 * block_nearest needs the floor itself only below it (rare): the pad's
 * operations stay off the usual path, where they cost primary packets and
 * streams about 2%.  In vectors, beside the triangle test, rather than
 * for the nearest lane once it is known: that lane's scalar steps lay on
 * the way from the test to the next node, and San Miguel's primary rays
 * (several blocks with a hit a ray) ran 8-12% faster without them
 * (docs/benchmarks/streams.md, "the hit floor's bound in vectors"). */
static inline __attribute__((always_inline)) vfloat4 block_hit_floor_bound(const block_t *t, const ray_pre *p)
{
    vfloat4 entry = vf4_set1(0.0f);
    for (int k = 0; k < 3; k++) {
        vfloat4 a, b, c;
        block_axis(t, k, &a, &b, &c);
        const vfloat4 near = p->rs[k] < 0.0f ? vf4_max(vf4_max(a, b), c) : vf4_min(vf4_min(a, b), c);
        const vfloat4 tk = vf4_mul(vf4_sub(near, vf4_set1(p->os[k])), vf4_set1(p->rs[k]));
        entry = k ? vf4_max(entry, tk) : tk;
    }
    entry = vf4_add(entry, vf4_set1(0.0f)); /* (-0.0 -> +0.0) */
    return vf4_sub(entry, vf4_mul(vf4_abs(entry), vf4_set1(0x1p-20f)));
}

/* The lanes of mask whose floor fl[] does not lie beyond tfar. */
static inline unsigned floors_within(const float *fl, unsigned mask, float tfar_s)
{
    for (unsigned m = mask; m; m &= m - 1)
        if (fl[__builtin_ctz(m)] > tfar_s)
            mask &= ~(1u << __builtin_ctz(m));
    return mask;
}

/* The nearest of the lanes of mask, each lane's distance T / |det| (T[i]
 * * rcp[i]) raised to its floor fl[i], the first of equals: the lane
 * (-1 when mask is empty) and its distance in *t_out. */
static inline int floored_nearest(const float *T, const float *rcp, const float *fl, unsigned mask, float *t_out)
{
    int lane = -1;
    float t_lane = 0.0f;
    for (; mask; mask &= mask - 1) {
        const int i = __builtin_ctz(mask);
        float ti = T[i] * rcp[i];
        ti = ti < fl[i] ? fl[i] : ti;
        if (lane < 0 || ti < t_lane) {
            lane = i;
            t_lane = ti;
        }
    }
    *t_out = t_lane;
    return lane;
}

/* The nearest of a block's lanes hit within [tnear, tfar] (mask, from
 * triangle4_intersect), each distance raised to its floor: the lane, or -1
 * when every floor lies beyond tfar; its distance clamped to [tnear, tfar]
 * (the product may round past an end of the interval the unscaled test
 * accepted; ties go to the interval's end, so -0.0 becomes tnear's +0.0,
 * as max/min do in the packet kernels) in *t_out, and u, v.  The floors
 * only raise distances, so when the nearest lane as rounded lies at or
 * above its own floor (nearly always) it is the answer, the first of
 * equals as below, and the other lanes' floors are not needed. */
static inline __attribute__((always_inline)) int block_nearest(const block_t *t, const ray_pre *p, const tri4_hit *h,
                                                               unsigned mask, float tnear_s, float tfar_s,
                                                               float *t_out, float *u_out, float *v_out)
{
    /* the reciprocals of |det| in one division for the four lanes (the
     * same quotients) */
    _Alignas(16) float T[4], rcp[4], fb[4];
    vf4_store(T, h->T);
    vf4_store(rcp, vf4_div(vf4_set1(1.0f), h->absdet));
    vf4_store(fb, block_hit_floor_bound(t, p));
    int lane = -1;
    float t_lane = 0.0f;
    for (unsigned m = mask; m; m &= m - 1) {
        const int i = __builtin_ctz(m);
        const float ti = T[i] * rcp[i];
        if (lane < 0 || ti < t_lane) {
            lane = i;
            t_lane = ti;
        }
    }
    const float fl_lane = fb[lane];
    if (__builtin_expect(!(t_lane >= fl_lane && fl_lane <= tfar_s), 0)) {
        _Alignas(16) float fl[4];
        vf4_store(fl, block_hit_floor(t, p));
        lane = floored_nearest(T, rcp, fl, floors_within(fl, mask, tfar_s), &t_lane);
        if (lane < 0)
            return -1;
    }
    *t_out = t_lane <= tnear_s ? tnear_s : (t_lane >= tfar_s ? tfar_s : t_lane);
    _Alignas(16) float U[4], V[4];
    vf4_store(U, h->U);
    vf4_store(V, h->V);
    *u_out = U[lane] * rcp[lane];
    *v_out = V[lane] * rcp[lane];
    return lane;
}

#if RTK_ROBUST
/* v0 and the edges as the triangle4 builder computes them, so the normal
 * is the default layouts' to the bit */
static inline void lane_triangle(const block_t *t, int lane, float v0[3], float e1[3], float e2[3])
{
    v0[0] = t->v0x[lane];
    v0[1] = t->v0y[lane];
    v0[2] = t->v0z[lane];
    e1[0] = t->v1x[lane] - v0[0];
    e1[1] = t->v1y[lane] - v0[1];
    e1[2] = t->v1z[lane] - v0[2];
    e2[0] = t->v2x[lane] - v0[0];
    e2[1] = t->v2y[lane] - v0[1];
    e2[2] = t->v2z[lane] - v0[2];
}
#else
static inline void lane_triangle(const block_t *t, int lane, float v0[3], float e1[3], float e2[3])
{
    v0[0] = t->v0x[lane];
    v0[1] = t->v0y[lane];
    v0[2] = t->v0z[lane];
    e1[0] = t->e1x[lane];
    e1[1] = t->e1y[lane];
    e1[2] = t->e1z[lane];
    e2[0] = t->e2x[lane];
    e2[1] = t->e2y[lane];
    e2[2] = t->e2z[lane];
}
#endif

/* Whether a candidate hit counts (rtk.h: masks, culling, filters): lane
 * `lane` of block t at distance tt with barycentrics u, v, for a ray whose
 * closest hit so far is at tfar; occluded selects the filter. */
static __attribute__((noinline)) int accept_lane(const block_t *t, int lane, const feat_ctx *p, float tt, float u,
                                                 float v, float tfar, int occluded)
{
    const rtk_ray *r = p->ray;
    const rtk_geometry_attrs *a = p->attrs ? &p->attrs[t->geom[lane]] : NULL;
    /* the mask first: it needs neither the normal nor the ray's copy */
    if (a && !(a->mask & r->mask))
        return 0;
    const rtk_filter_fn filter = !a ? NULL : occluded ? a->occluded_filter : a->intersect_filter;
    const rtk_filter_fn qfilter = p->feat & RTK_FEAT_QUERY_FILTER ? p->q->filter : NULL;
    if (!filter && !qfilter && !(p->feat & RTK_FEAT_CULL))
        return 1;
    float v0[3], e1[3], e2[3], ng[3];
    lane_triangle(t, lane, v0, e1, e2);
    rtk_triangle_normal(e1, e2, ng);
    if (p->feat & RTK_FEAT_CULL) {
        /* in double, where the products of floats are exact: the same sign
         * in every backend, FMA or not */
        const double dn = (double)r->dir_x * ng[0] + (double)r->dir_y * ng[1] + (double)r->dir_z * ng[2];
        if (((r->flags & RTK_RAY_FLAG_CULL_BACK) && dn > 0.0f) || ((r->flags & RTK_RAY_FLAG_CULL_FRONT) && dn < 0.0f))
            return 0;
    }
    if (!filter && !qfilter)
        return 1;
    rtk_ray ray = *r;
    ray.tfar = tfar;
    rtk_hit hit = {.Ng_x = ng[0], .Ng_y = ng[1], .Ng_z = ng[2], .u = u, .v = v, .primID = t->prim[lane],
                   .geomID = t->geom[lane], .instID = p->q->inst_id};
    if (p->attrs)
        rtk_quad_hit(p->attrs, hit.geomID, &hit.primID, &hit.u, &hit.v);
    const rtk_filter_args args = {.geometry_user = a ? a->user : NULL, .context = p->q->context, .ray = &ray,
                                  .hit = &hit, .t = tt};
    if (filter && !filter(&args))
        return 0;
    return !qfilter || qfilter(&args) != 0;
}

/* The closest-hit query's candidates of one block (mask, the lanes hit
 * within [tnear, tfar]) through accept_lane, nearest first: the mask of
 * the nearest accepted, or 0. */
static __attribute__((noinline)) unsigned accept_closest(const block_t *t, const feat_ctx *p, const tri4_hit *h,
                                                         vfloat4 floor, unsigned mask, float tnear_s, float tfar_s)
{
    _Alignas(16) float T[4], rcp[4], U[4], V[4], fl[4];
    vf4_store(T, h->T);
    vf4_store(rcp, vf4_div(vf4_set1(1.0f), h->absdet));
    vf4_store(U, h->U);
    vf4_store(V, h->V);
    vf4_store(fl, floor);
    mask = floors_within(fl, mask, tfar_s);
    while (mask) {
        float tl;
        const int lane = floored_nearest(T, rcp, fl, mask, &tl);
        tl = tl <= tnear_s ? tnear_s : (tl >= tfar_s ? tfar_s : tl); /* as closest_from_ clamps */
        if (accept_lane(t, lane, p, tl, U[lane] * rcp[lane], V[lane] * rcp[lane], tfar_s, 0))
            return 1u << lane;
        mask &= ~(1u << lane);
    }
    return 0;
}

/* The any-hit query's: 1 when one is accepted. */
static __attribute__((noinline)) int accept_any(const block_t *t, const feat_ctx *p, const tri4_hit *h, unsigned mask,
                                                float tnear_s, float tfar_s)
{
    _Alignas(16) float T[4], rcp[4], U[4], V[4];
    vf4_store(T, h->T);
    vf4_store(rcp, vf4_div(vf4_set1(1.0f), h->absdet));
    vf4_store(U, h->U);
    vf4_store(V, h->V);
    for (; mask; mask &= mask - 1) {
        const int i = __builtin_ctz(mask);
        float ti = T[i] * rcp[i];
        ti = ti <= tnear_s ? tnear_s : (ti >= tfar_s ? tfar_s : ti);
        if (accept_lane(t, i, p, ti, U[i] * rcp[i], V[i] * rcp[i], tfar_s, 1))
            return 1;
    }
    return 0;
}

/* The lanes of `mask` whose geometry's mask shares a bit with the ray's:
 * a ray without culling in a tree with masks but no filters, whose
 * candidates need no call (a call in the loop makes the compiler keep the
 * ray's vectors in memory).  Whether a candidate passes does not depend on
 * its distance, so the closest hit is the nearest lane left. */
static inline unsigned mask_lanes(const block_t *t, unsigned mask, const feat_ctx *f)
{
    const uint32_t rmask = f->ray->mask;
    unsigned keep = 0;
    for (unsigned m = mask; m; m &= m - 1) {
        const int i = __builtin_ctz(m);
        keep |= (f->attrs[t->geom[i]].mask & rmask) ? 1u << i : 0u;
    }
    return keep;
}

