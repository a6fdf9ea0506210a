/* 4-wide float, int and mask vectors in portable GNU C (vector extensions,
 * no intrinsics), for the scalar backend.  The compiler lowers them to
 * whatever the baseline target has (SSE2 on x86-64) or to four scalar
 * operations.  Same functions and semantics as vfloat4_sse41.h. */
#ifndef RTK_VFLOAT4_C_H
#define RTK_VFLOAT4_C_H

typedef float vfloat4 __attribute__((vector_size(16)));
typedef int32_t vint4 __attribute__((vector_size(16)));
typedef uint32_t rtk_vuint4 __attribute__((vector_size(16)));
typedef vint4 vbool4; /* lanes are 0 or -1 */

#define RTK_INLINE static inline __attribute__((always_inline))

RTK_INLINE vfloat4 rtk_v4_blend(vbool4 m, vfloat4 a, vfloat4 b) /* m ? a : b */
{
    return (vfloat4)(((vint4)a & m) | ((vint4)b & ~m)); /* vector casts keep the bits */
}

/* ---- vfloat4 ---------------------------------------------------------- */
RTK_INLINE vfloat4 vf4_load(const float *p) { return *(const vfloat4 *)__builtin_assume_aligned(p, 16); }
RTK_INLINE vfloat4 vf4_loadu(const float *p) { vfloat4 r; memcpy(&r, p, sizeof r); return r; }
RTK_INLINE void vf4_store(float *p, vfloat4 a) { *(vfloat4 *)__builtin_assume_aligned(p, 16) = a; }
RTK_INLINE void vf4_storeu(float *p, vfloat4 a) { memcpy(p, &a, sizeof a); }
RTK_INLINE vfloat4 vf4_set1(float a) { return (vfloat4){a, a, a, a}; }
RTK_INLINE vfloat4 vf4_set(float a, float b, float c, float d) { return (vfloat4){a, b, c, d}; }
RTK_INLINE vfloat4 vf4_add(vfloat4 a, vfloat4 b) { return a + b; }
RTK_INLINE vfloat4 vf4_sub(vfloat4 a, vfloat4 b) { return a - b; }
RTK_INLINE vfloat4 vf4_mul(vfloat4 a, vfloat4 b) { return a * b; }
RTK_INLINE vfloat4 vf4_div(vfloat4 a, vfloat4 b) { return a / b; }
/* written lane by lane so the compiler sees min/max (minps/maxps on x86) */
#define RTK_V4_LANES(f) (vfloat4){f(0), f(1), f(2), f(3)}
RTK_INLINE vfloat4 vf4_min(vfloat4 a, vfloat4 b)
{
#define RTK_MIN_LANE(i) (a[i] < b[i] ? a[i] : b[i])
    return RTK_V4_LANES(RTK_MIN_LANE);
#undef RTK_MIN_LANE
}
RTK_INLINE vfloat4 vf4_max(vfloat4 a, vfloat4 b)
{
#define RTK_MAX_LANE(i) (a[i] > b[i] ? a[i] : b[i])
    return RTK_V4_LANES(RTK_MAX_LANE);
#undef RTK_MAX_LANE
}
/* max / min / a > b of the lanes' bits as signed integers (see simd.h) */
RTK_INLINE vbool4 vf4_gti(vfloat4 a, vfloat4 b) { return (vint4)a > (vint4)b; }
RTK_INLINE vfloat4 vf4_maxi(vfloat4 a, vfloat4 b) { return rtk_v4_blend(vf4_gti(a, b), a, b); }
RTK_INLINE vfloat4 vf4_mini(vfloat4 a, vfloat4 b) { return rtk_v4_blend(vf4_gti(a, b), b, a); }
RTK_INLINE vfloat4 vf4_madd(vfloat4 a, vfloat4 b, vfloat4 c) { return a * b + c; }
RTK_INLINE vfloat4 vf4_msub(vfloat4 a, vfloat4 b, vfloat4 c) { return a * b - c; }
RTK_INLINE vbool4 vf4_lt(vfloat4 a, vfloat4 b) { return a < b; }
RTK_INLINE vbool4 vf4_le(vfloat4 a, vfloat4 b) { return a <= b; }
RTK_INLINE vbool4 vf4_gt(vfloat4 a, vfloat4 b) { return a > b; }
RTK_INLINE vbool4 vf4_ge(vfloat4 a, vfloat4 b) { return a >= b; }
RTK_INLINE vbool4 vf4_eq(vfloat4 a, vfloat4 b) { return a == b; }
RTK_INLINE vfloat4 vf4_select(vbool4 m, vfloat4 a, vfloat4 b) { return rtk_v4_blend(m, a, b); }
RTK_INLINE vfloat4 vf4_keep(vbool4 m, vfloat4 a) { return rtk_v4_blend(m, a, vf4_set1(0.0f)); }
RTK_INLINE vfloat4 vf4_abs(vfloat4 a) { return (vfloat4)((vint4)a & 0x7fffffff); }
RTK_INLINE vfloat4 vf4_xor_sign(vfloat4 a, vfloat4 s) { return (vfloat4)((vint4)a ^ ((vint4)s & INT32_MIN)); }
RTK_INLINE float vf4_reduce_min(vfloat4 a)
{
    float m0 = a[1] < a[0] ? a[1] : a[0], m1 = a[3] < a[2] ? a[3] : a[2];
    return m1 < m0 ? m1 : m0;
}
RTK_INLINE float vf4_lane0(vfloat4 a) { return a[0]; }
#define vf4_broadcast(a, I) vf4_set1((a)[I])
RTK_INLINE float vf4_reduce_min3(vfloat4 a)
{
    float m = a[1] < a[0] ? a[1] : a[0];
    return a[2] < m ? a[2] : m;
}
RTK_INLINE float vf4_reduce_max3(vfloat4 a)
{
    float m = a[1] > a[0] ? a[1] : a[0];
    return a[2] > m ? a[2] : m;
}

/* 4x4 transpose in place: rows a, b, c, d become columns */
RTK_INLINE void vf4_transpose(vfloat4 *a, vfloat4 *b, vfloat4 *c, vfloat4 *d)
{
    vfloat4 r0 = *a, r1 = *b, r2 = *c, r3 = *d;
    *a = (vfloat4){r0[0], r1[0], r2[0], r3[0]};
    *b = (vfloat4){r0[1], r1[1], r2[1], r3[1]};
    *c = (vfloat4){r0[2], r1[2], r2[2], r3[2]};
    *d = (vfloat4){r0[3], r1[3], r2[3], r3[3]};
}

/* ---- vint4 ------------------------------------------------------------ */
RTK_INLINE vint4 vi4_load(const int32_t *p) { return *(const vint4 *)__builtin_assume_aligned(p, 16); }
RTK_INLINE void vi4_store(int32_t *p, vint4 a) { *(vint4 *)__builtin_assume_aligned(p, 16) = a; }
RTK_INLINE vint4 vi4_set1(int32_t a) { return (vint4){a, a, a, a}; }
RTK_INLINE vint4 vi4_add(vint4 a, vint4 b) { return (vint4)((rtk_vuint4)a + (rtk_vuint4)b); }
RTK_INLINE vint4 vi4_min(vint4 a, vint4 b) { vbool4 m = a < b; return (a & m) | (b & ~m); }
RTK_INLINE vint4 vi4_max(vint4 a, vint4 b) { vbool4 m = a > b; return (a & m) | (b & ~m); }
RTK_INLINE vint4 vi4_shr(vint4 a, int n) { return (vint4)((rtk_vuint4)a >> n); } /* logical */
RTK_INLINE vbool4 vi4_eq(vint4 a, vint4 b) { return a == b; }
RTK_INLINE vint4 vi4_select(vbool4 m, vint4 a, vint4 b) { return (a & m) | (b & ~m); }
RTK_INLINE vfloat4 vf4_from_vi4(vint4 a) { return __builtin_convertvector(a, vfloat4); }
RTK_INLINE vint4 vi4_from_vf4_trunc(vfloat4 a) { return __builtin_convertvector(a, vint4); }
RTK_INLINE vbool4 vi4_lt(vint4 a, vint4 b) { return a < b; }
#define vi4_lane(a, I) ((a)[I])
RTK_INLINE vint4 vf4_bits(vfloat4 a) { return (vint4)a; }
RTK_INLINE vfloat4 vf4_from_bits(vint4 a) { return (vfloat4)a; }

/* ---- vbool4 ----------------------------------------------------------- */
RTK_INLINE vbool4 vb4_and(vbool4 a, vbool4 b) { return a & b; }
RTK_INLINE vbool4 vb4_or(vbool4 a, vbool4 b) { return a | b; }
RTK_INLINE vbool4 vb4_andnot(vbool4 a, vbool4 b) { return a & ~b; }
RTK_INLINE vbool4 vb4_from_bits(int m) { return -((vint4){m, m >> 1, m >> 2, m >> 3} & 1); }
RTK_INLINE int vb4_mask(vbool4 a) { return (a[0] & 1) | (a[1] & 2) | (a[2] & 4) | (a[3] & 8); }
RTK_INLINE vbool4 vb4_load(const int32_t *p) { return vi4_load(p); } /* lanes 0 or -1 */

#endif
