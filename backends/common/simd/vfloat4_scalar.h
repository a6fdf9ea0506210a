/* The width-1 version of the SIMD layer, for the scalar backend: the same
 * 4-lane types and functions as vfloat4_sse41.h, executed one lane at a time
 * with scalar float and int operations, in plain C.  The scalar backend is
 * compiled with the vectorizers off (backends/scalar/CMakeLists.txt), so what
 * it measures is the kernels without SIMD; it runs wherever C does.  Same
 * semantics as the other headers (simd.h), including the SSE rules for NaN in
 * min/max. */
#ifndef RTK_VFLOAT4_SCALAR_H
#define RTK_VFLOAT4_SCALAR_H

typedef struct { float f[4]; } vfloat4;
typedef struct { int32_t i[4]; } vint4;
typedef vint4 vbool4; /* lanes are 0 or -1 */

#define RTK_INLINE static inline __attribute__((always_inline))

/* r.<field>[k] = expr for k = 0..3; expr may use k */
#define RTK_S4(field, expr)                                                    \
    do {                                                                       \
        for (int k = 0; k < 4; k++)                                            \
            r.field[k] = (expr);                                               \
    } while (0)
#define RTK_S4_F(expr) vfloat4 r; RTK_S4(f, expr); return r
#define RTK_S4_I(expr) vint4 r; RTK_S4(i, expr); return r

RTK_INLINE int32_t rtk_s_bits(float a) { int32_t b; memcpy(&b, &a, sizeof b); return b; }
RTK_INLINE float rtk_s_float(int32_t b) { float a; memcpy(&a, &b, sizeof a); return a; }
RTK_INLINE float rtk_s_min(float a, float b) { return a < b ? a : b; } /* minss: b unless a < b */
RTK_INLINE float rtk_s_max(float a, float b) { return a > b ? a : b; }

/* ---- vfloat4 ---------------------------------------------------------- */
RTK_INLINE vfloat4 vf4_load(const float *p) { vfloat4 r; memcpy(r.f, p, sizeof r); return r; }
RTK_INLINE vfloat4 vf4_loadu(const float *p) { vfloat4 r; memcpy(r.f, p, sizeof r); return r; }
RTK_INLINE void vf4_store(float *p, vfloat4 a) { memcpy(p, a.f, sizeof a); }
RTK_INLINE void vf4_storeu(float *p, vfloat4 a) { memcpy(p, a.f, sizeof a); }
RTK_INLINE vfloat4 vf4_set1(float a) { return (vfloat4){{a, a, a, a}}; }
RTK_INLINE vfloat4 vf4_set(float a, float b, float c, float d) { return (vfloat4){{a, b, c, d}}; }
RTK_INLINE vfloat4 vf4_add(vfloat4 a, vfloat4 b) { RTK_S4_F(a.f[k] + b.f[k]); }
RTK_INLINE vfloat4 vf4_sub(vfloat4 a, vfloat4 b) { RTK_S4_F(a.f[k] - b.f[k]); }
RTK_INLINE vfloat4 vf4_mul(vfloat4 a, vfloat4 b) { RTK_S4_F(a.f[k] * b.f[k]); }
RTK_INLINE vfloat4 vf4_div(vfloat4 a, vfloat4 b) { RTK_S4_F(a.f[k] / b.f[k]); }
RTK_INLINE vfloat4 vf4_sqrt(vfloat4 a) { RTK_S4_F(__builtin_sqrtf(a.f[k])); }
RTK_INLINE vfloat4 vf4_min(vfloat4 a, vfloat4 b) { RTK_S4_F(rtk_s_min(a.f[k], b.f[k])); }
RTK_INLINE vfloat4 vf4_max(vfloat4 a, vfloat4 b) { RTK_S4_F(rtk_s_max(a.f[k], b.f[k])); }
/* max / min / a > b of the lanes' bits as signed integers (see simd.h) */
RTK_INLINE vbool4 vf4_gti(vfloat4 a, vfloat4 b) { RTK_S4_I(-(rtk_s_bits(a.f[k]) > rtk_s_bits(b.f[k]))); }
RTK_INLINE vfloat4 vf4_maxi(vfloat4 a, vfloat4 b)
{
    RTK_S4_F(rtk_s_bits(a.f[k]) > rtk_s_bits(b.f[k]) ? a.f[k] : b.f[k]);
}
RTK_INLINE vfloat4 vf4_mini(vfloat4 a, vfloat4 b)
{
    RTK_S4_F(rtk_s_bits(a.f[k]) > rtk_s_bits(b.f[k]) ? b.f[k] : a.f[k]);
}
RTK_INLINE vfloat4 vf4_add_ulps(vfloat4 a, int n)
{
    vfloat4 r;
    for (int k = 0; k < 4; k++) {
        const int32_t b = (int32_t)((uint32_t)rtk_s_bits(a.f[k]) + (uint32_t)n);
        memcpy(&r.f[k], &b, sizeof b);
    }
    return r;
}
/* two roundings: the scalar backend has no FMA (RTK_SIMD_HAS_FMA is unset) */
RTK_INLINE vfloat4 vf4_madd(vfloat4 a, vfloat4 b, vfloat4 c) { RTK_S4_F(a.f[k] * b.f[k] + c.f[k]); }
RTK_INLINE vfloat4 vf4_msub(vfloat4 a, vfloat4 b, vfloat4 c) { RTK_S4_F(a.f[k] * b.f[k] - c.f[k]); }
RTK_INLINE vbool4 vf4_lt(vfloat4 a, vfloat4 b) { RTK_S4_I(-(a.f[k] < b.f[k])); }
RTK_INLINE vbool4 vf4_le(vfloat4 a, vfloat4 b) { RTK_S4_I(-(a.f[k] <= b.f[k])); }
RTK_INLINE vbool4 vf4_gt(vfloat4 a, vfloat4 b) { RTK_S4_I(-(a.f[k] > b.f[k])); }
RTK_INLINE vbool4 vf4_ge(vfloat4 a, vfloat4 b) { RTK_S4_I(-(a.f[k] >= b.f[k])); }
RTK_INLINE vbool4 vf4_eq(vfloat4 a, vfloat4 b) { RTK_S4_I(-(a.f[k] == b.f[k])); }
RTK_INLINE vfloat4 vf4_select(vbool4 m, vfloat4 a, vfloat4 b) { RTK_S4_F(m.i[k] ? a.f[k] : b.f[k]); }
RTK_INLINE vfloat4 vf4_keep(vbool4 m, vfloat4 a) { RTK_S4_F(m.i[k] ? a.f[k] : 0.0f); }
RTK_INLINE vfloat4 vf4_clear3(vfloat4 a) { RTK_S4_F(k < 3 ? a.f[k] : 0.0f); }
RTK_INLINE vfloat4 vf4_abs(vfloat4 a) { RTK_S4_F(rtk_s_float(rtk_s_bits(a.f[k]) & INT32_MAX)); }
RTK_INLINE vfloat4 vf4_yzx(vfloat4 a) { return (vfloat4){{a.f[1], a.f[2], a.f[0], a.f[3]}}; }
RTK_INLINE vfloat4 vf4_zxy(vfloat4 a) { return (vfloat4){{a.f[2], a.f[0], a.f[1], a.f[3]}}; }
RTK_INLINE vfloat4 vf4_xor_sign(vfloat4 a, vfloat4 s)
{
    RTK_S4_F(rtk_s_float(rtk_s_bits(a.f[k]) ^ (rtk_s_bits(s.f[k]) & INT32_MIN)));
}
/* the bits of a and b: xor, or */
RTK_INLINE vfloat4 vf4_xor(vfloat4 a, vfloat4 b) { RTK_S4_F(rtk_s_float(rtk_s_bits(a.f[k]) ^ rtk_s_bits(b.f[k]))); }
RTK_INLINE vfloat4 vf4_or(vfloat4 a, vfloat4 b) { RTK_S4_F(rtk_s_float(rtk_s_bits(a.f[k]) | rtk_s_bits(b.f[k]))); }
/* bit k = lane k's sign bit (-0.0 and negative NaNs included) */
RTK_INLINE int vf4_signs(vfloat4 a)
{
    int m = 0;
    for (int k = 0; k < 4; k++)
        m |= (int)((uint32_t)rtk_s_bits(a.f[k]) >> 31) << k;
    return m;
}
RTK_INLINE float vf4_reduce_min(vfloat4 a)
{
    return rtk_s_min(rtk_s_min(a.f[0], a.f[1]), rtk_s_min(a.f[2], a.f[3]));
}
RTK_INLINE float vf4_reduce_max(vfloat4 a)
{
    return rtk_s_max(rtk_s_max(a.f[0], a.f[1]), rtk_s_max(a.f[2], a.f[3]));
}
RTK_INLINE float vf4_lane0(vfloat4 a) { return a.f[0]; }
#define vf4_broadcast(a, I) vf4_set1((a).f[I])
RTK_INLINE float vf4_reduce_min3(vfloat4 a) { return rtk_s_min(rtk_s_min(a.f[0], a.f[1]), a.f[2]); }
RTK_INLINE float vf4_reduce_max3(vfloat4 a) { return rtk_s_max(rtk_s_max(a.f[0], a.f[1]), a.f[2]); }

/* 4x4 transpose in place: rows a, b, c, d become columns */
RTK_INLINE void vf4_transpose(vfloat4 *a, vfloat4 *b, vfloat4 *c, vfloat4 *d)
{
    vfloat4 r0 = *a, r1 = *b, r2 = *c, r3 = *d;
    *a = (vfloat4){{r0.f[0], r1.f[0], r2.f[0], r3.f[0]}};
    *b = (vfloat4){{r0.f[1], r1.f[1], r2.f[1], r3.f[1]}};
    *c = (vfloat4){{r0.f[2], r1.f[2], r2.f[2], r3.f[2]}};
    *d = (vfloat4){{r0.f[3], r1.f[3], r2.f[3], r3.f[3]}};
}

/* ---- vint4 ------------------------------------------------------------ */
RTK_INLINE vint4 vi4_load(const int32_t *p) { vint4 r; memcpy(r.i, p, sizeof r); return r; }
RTK_INLINE void vi4_store(int32_t *p, vint4 a) { memcpy(p, a.i, sizeof a); }
RTK_INLINE vint4 vi4_set1(int32_t a) { return (vint4){{a, a, a, a}}; }
RTK_INLINE vint4 vi4_add(vint4 a, vint4 b) { RTK_S4_I((int32_t)((uint32_t)a.i[k] + (uint32_t)b.i[k])); }
RTK_INLINE vint4 vi4_min(vint4 a, vint4 b) { RTK_S4_I(a.i[k] < b.i[k] ? a.i[k] : b.i[k]); }
RTK_INLINE vint4 vi4_max(vint4 a, vint4 b) { RTK_S4_I(a.i[k] > b.i[k] ? a.i[k] : b.i[k]); }
RTK_INLINE vint4 vi4_shr(vint4 a, int n) { RTK_S4_I((int32_t)((uint32_t)a.i[k] >> n)); } /* logical */
RTK_INLINE vint4 vi4_shl(vint4 a, int n) { RTK_S4_I((int32_t)((uint32_t)a.i[k] << n)); }
RTK_INLINE vbool4 vi4_eq(vint4 a, vint4 b) { RTK_S4_I(-(a.i[k] == b.i[k])); }
RTK_INLINE vint4 vi4_select(vbool4 m, vint4 a, vint4 b) { RTK_S4_I(m.i[k] ? a.i[k] : b.i[k]); }
RTK_INLINE vfloat4 vf4_from_vi4(vint4 a) { RTK_S4_F((float)a.i[k]); }
RTK_INLINE vint4 vi4_from_vf4_trunc(vfloat4 a) { RTK_S4_I((int32_t)a.f[k]); }
RTK_INLINE vbool4 vi4_lt(vint4 a, vint4 b) { RTK_S4_I(-(a.i[k] < b.i[k])); }
#define vi4_lane(a, I) ((a).i[I])
/* reinterpretations, bits unchanged */
RTK_INLINE vint4 vf4_bits(vfloat4 a) { vint4 r; memcpy(r.i, a.f, sizeof r); return r; }
RTK_INLINE vfloat4 vf4_from_bits(vint4 a) { vfloat4 r; memcpy(r.f, a.i, sizeof r); return r; }

/* ---- vbool4 ----------------------------------------------------------- */
RTK_INLINE vbool4 vb4_and(vbool4 a, vbool4 b) { RTK_S4_I(a.i[k] & b.i[k]); }
RTK_INLINE vbool4 vb4_or(vbool4 a, vbool4 b) { RTK_S4_I(a.i[k] | b.i[k]); }
RTK_INLINE vbool4 vb4_andnot(vbool4 a, vbool4 b) { RTK_S4_I(a.i[k] & ~b.i[k]); }
RTK_INLINE vbool4 vb4_from_bits(int m) { RTK_S4_I(-((m >> k) & 1)); }
RTK_INLINE int vb4_mask(vbool4 a) /* bit k = lane k */
{
    return (a.i[0] & 1) | (a.i[1] & 2) | (a.i[2] & 4) | (a.i[3] & 8);
}
RTK_INLINE vbool4 vb4_load(const int32_t *p) { return vi4_load(p); } /* lanes 0 or -1 */

#endif
