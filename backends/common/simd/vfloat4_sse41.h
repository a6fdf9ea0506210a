/* 4-wide float, int and mask vectors on SSE4.1 (plus FMA where the backend has it). */
#ifndef RTK_VFLOAT4_SSE41_H
#define RTK_VFLOAT4_SSE41_H

#include <smmintrin.h>
#if defined(__FMA__)
#include <immintrin.h>
#endif

typedef __m128 vfloat4;
typedef __m128i vint4;
typedef __m128 vbool4;

#define RTK_INLINE static inline __attribute__((always_inline))

/* ---- vfloat4 ---------------------------------------------------------- */
RTK_INLINE vfloat4 vf4_load(const float *p) { return _mm_load_ps(p); } /* 16-byte aligned */
RTK_INLINE vfloat4 vf4_loadu(const float *p) { return _mm_loadu_ps(p); }
RTK_INLINE void vf4_store(float *p, vfloat4 a) { _mm_store_ps(p, a); }
RTK_INLINE void vf4_storeu(float *p, vfloat4 a) { _mm_storeu_ps(p, a); }
RTK_INLINE vfloat4 vf4_set1(float a) { return _mm_set1_ps(a); }
#if defined(__AVX__)
RTK_INLINE vfloat4 vf4_set1_at(const float *a)
{
    vfloat4 r;
    __asm__ volatile("vbroadcastss %1, %0" : "=x"(r) : "m"(*a));
    return r;
}
#endif
RTK_INLINE vfloat4 vf4_set(float a, float b, float c, float d) { return _mm_setr_ps(a, b, c, d); }
RTK_INLINE vfloat4 vf4_add(vfloat4 a, vfloat4 b) { return _mm_add_ps(a, b); }
RTK_INLINE vfloat4 vf4_sub(vfloat4 a, vfloat4 b) { return _mm_sub_ps(a, b); }
RTK_INLINE vfloat4 vf4_mul(vfloat4 a, vfloat4 b) { return _mm_mul_ps(a, b); }
RTK_INLINE vfloat4 vf4_div(vfloat4 a, vfloat4 b) { return _mm_div_ps(a, b); }
RTK_INLINE vfloat4 vf4_sqrt(vfloat4 a) { return _mm_sqrt_ps(a); }
RTK_INLINE vfloat4 vf4_min(vfloat4 a, vfloat4 b) { return _mm_min_ps(a, b); }
RTK_INLINE vfloat4 vf4_max(vfloat4 a, vfloat4 b) { return _mm_max_ps(a, b); }
/* max / min / a > b of the lanes' bits as signed integers (see simd.h) */
RTK_INLINE vfloat4 vf4_maxi(vfloat4 a, vfloat4 b)
{
    return _mm_castsi128_ps(_mm_max_epi32(_mm_castps_si128(a), _mm_castps_si128(b)));
}
RTK_INLINE vfloat4 vf4_mini(vfloat4 a, vfloat4 b)
{
    return _mm_castsi128_ps(_mm_min_epi32(_mm_castps_si128(a), _mm_castps_si128(b)));
}
RTK_INLINE vbool4 vf4_gti(vfloat4 a, vfloat4 b)
{
    return _mm_castsi128_ps(_mm_cmpgt_epi32(_mm_castps_si128(a), _mm_castps_si128(b)));
}
/* the lanes' bits plus n as integers: n ulps up for a finite positive
 * value (see simd.h) */
RTK_INLINE vfloat4 vf4_add_ulps(vfloat4 a, int n)
{
    return _mm_castsi128_ps(_mm_add_epi32(_mm_castps_si128(a), _mm_set1_epi32(n)));
}
/* a * b + c, fused where the ISA has FMA (one rounding) */
RTK_INLINE vfloat4 vf4_madd(vfloat4 a, vfloat4 b, vfloat4 c)
{
#if defined(__FMA__)
    return _mm_fmadd_ps(a, b, c);
#else
    return _mm_add_ps(_mm_mul_ps(a, b), c);
#endif
}
/* a * b - c, fused where the ISA has FMA */
RTK_INLINE vfloat4 vf4_msub(vfloat4 a, vfloat4 b, vfloat4 c)
{
#if defined(__FMA__)
    return _mm_fmsub_ps(a, b, c);
#else
    return _mm_sub_ps(_mm_mul_ps(a, b), c);
#endif
}
RTK_INLINE vbool4 vf4_lt(vfloat4 a, vfloat4 b) { return _mm_cmplt_ps(a, b); }
RTK_INLINE vbool4 vf4_le(vfloat4 a, vfloat4 b) { return _mm_cmple_ps(a, b); }
RTK_INLINE vbool4 vf4_gt(vfloat4 a, vfloat4 b) { return _mm_cmpgt_ps(a, b); }
RTK_INLINE vbool4 vf4_ge(vfloat4 a, vfloat4 b) { return _mm_cmpge_ps(a, b); }
RTK_INLINE vbool4 vf4_eq(vfloat4 a, vfloat4 b) { return _mm_cmpeq_ps(a, b); }
/* m ? a : b, lane by lane */
RTK_INLINE vfloat4 vf4_select(vbool4 m, vfloat4 a, vfloat4 b) { return _mm_blendv_ps(b, a, m); }
/* m ? a : +0.0, lane by lane (one and) */
RTK_INLINE vfloat4 vf4_keep(vbool4 m, vfloat4 a) { return _mm_and_ps(m, a); }
/* a with lane 3 made +0.0 (a blend with zero: no mask to keep in a register) */
RTK_INLINE vfloat4 vf4_clear3(vfloat4 a) { return _mm_blend_ps(a, _mm_setzero_ps(), 8); }
/* |a| and a with the sign of s applied (a ^ sign bit of s) */
RTK_INLINE vfloat4 vf4_abs(vfloat4 a) { return _mm_andnot_ps(_mm_set1_ps(-0.0f), a); }
/* lanes 0..2 rotated, lane 3 kept: (y, z, x, w) and (z, x, y, w) */
RTK_INLINE vfloat4 vf4_yzx(vfloat4 a) { return _mm_shuffle_ps(a, a, _MM_SHUFFLE(3, 0, 2, 1)); }
RTK_INLINE vfloat4 vf4_zxy(vfloat4 a) { return _mm_shuffle_ps(a, a, _MM_SHUFFLE(3, 1, 0, 2)); }
RTK_INLINE vfloat4 vf4_xor_sign(vfloat4 a, vfloat4 s) { return _mm_xor_ps(a, _mm_and_ps(s, _mm_set1_ps(-0.0f))); }
/* bit i = lane i's sign bit (-0.0 and negative NaNs included): one movmskps, no comparison */
/* the bits of a and b: xor, or */
RTK_INLINE vfloat4 vf4_xor(vfloat4 a, vfloat4 b) { return _mm_xor_ps(a, b); }
RTK_INLINE vfloat4 vf4_or(vfloat4 a, vfloat4 b) { return _mm_or_ps(a, b); }
RTK_INLINE int vf4_signs(vfloat4 a) { return _mm_movemask_ps(a); }
RTK_INLINE float vf4_reduce_min(vfloat4 a)
{
    vfloat4 m = _mm_min_ps(a, _mm_shuffle_ps(a, a, _MM_SHUFFLE(2, 3, 0, 1)));
    m = _mm_min_ps(m, _mm_shuffle_ps(m, m, _MM_SHUFFLE(1, 0, 3, 2)));
    return _mm_cvtss_f32(m);
}
RTK_INLINE float vf4_reduce_max(vfloat4 a)
{
    vfloat4 m = _mm_max_ps(a, _mm_shuffle_ps(a, a, _MM_SHUFFLE(2, 3, 0, 1)));
    m = _mm_max_ps(m, _mm_shuffle_ps(m, m, _MM_SHUFFLE(1, 0, 3, 2)));
    return _mm_cvtss_f32(m);
}
RTK_INLINE float vf4_lane0(vfloat4 a) { return _mm_cvtss_f32(a); }
/* broadcast lane I (a constant) to all lanes */
#define vf4_broadcast(a, I) _mm_shuffle_ps((a), (a), _MM_SHUFFLE(I, I, I, I))
RTK_INLINE float vf4_reduce_min3(vfloat4 a) /* min of lanes 0..2 */
{
    vfloat4 m = _mm_min_ps(a, _mm_shuffle_ps(a, a, _MM_SHUFFLE(3, 0, 2, 1)));
    return _mm_cvtss_f32(_mm_min_ss(m, _mm_movehl_ps(a, a)));
}
RTK_INLINE float vf4_reduce_max3(vfloat4 a) /* max of lanes 0..2 */
{
    vfloat4 m = _mm_max_ps(a, _mm_shuffle_ps(a, a, _MM_SHUFFLE(3, 0, 2, 1)));
    return _mm_cvtss_f32(_mm_max_ss(m, _mm_movehl_ps(a, a)));
}

/* 4x4 transpose in place: rows a, b, c, d become columns */
RTK_INLINE void vf4_transpose(vfloat4 *a, vfloat4 *b, vfloat4 *c, vfloat4 *d)
{
    _MM_TRANSPOSE4_PS(*a, *b, *c, *d);
}

/* ---- vint4 ------------------------------------------------------------ */
RTK_INLINE vint4 vi4_load(const int32_t *p) { return _mm_load_si128((const __m128i *)p); }
RTK_INLINE void vi4_store(int32_t *p, vint4 a) { _mm_store_si128((__m128i *)p, a); }
RTK_INLINE vint4 vi4_set1(int32_t a) { return _mm_set1_epi32(a); }
RTK_INLINE vint4 vi4_add(vint4 a, vint4 b) { return _mm_add_epi32(a, b); }
RTK_INLINE vint4 vi4_min(vint4 a, vint4 b) { return _mm_min_epi32(a, b); }
RTK_INLINE vint4 vi4_max(vint4 a, vint4 b) { return _mm_max_epi32(a, b); }
RTK_INLINE vint4 vi4_shr(vint4 a, int n) { return _mm_srli_epi32(a, n); } /* logical */
RTK_INLINE vint4 vi4_shl(vint4 a, int n) { return _mm_slli_epi32(a, n); }
RTK_INLINE vbool4 vi4_eq(vint4 a, vint4 b) { return _mm_castsi128_ps(_mm_cmpeq_epi32(a, b)); }
RTK_INLINE vint4 vi4_select(vbool4 m, vint4 a, vint4 b)
{
    return _mm_castps_si128(_mm_blendv_ps(_mm_castsi128_ps(b), _mm_castsi128_ps(a), m));
}
RTK_INLINE vfloat4 vf4_from_vi4(vint4 a) { return _mm_cvtepi32_ps(a); }
RTK_INLINE vint4 vi4_from_vf4_trunc(vfloat4 a) { return _mm_cvttps_epi32(a); }
RTK_INLINE vbool4 vi4_lt(vint4 a, vint4 b) { return _mm_castsi128_ps(_mm_cmplt_epi32(a, b)); }
#define vi4_lane(a, I) _mm_extract_epi32((a), (I))
/* reinterpretations, bits unchanged */
RTK_INLINE vint4 vf4_bits(vfloat4 a) { return _mm_castps_si128(a); }
RTK_INLINE vfloat4 vf4_from_bits(vint4 a) { return _mm_castsi128_ps(a); }

/* ---- vbool4 ----------------------------------------------------------- */
RTK_INLINE vbool4 vb4_and(vbool4 a, vbool4 b) { return _mm_and_ps(a, b); }
RTK_INLINE vbool4 vb4_or(vbool4 a, vbool4 b) { return _mm_or_ps(a, b); }
RTK_INLINE vbool4 vb4_andnot(vbool4 a, vbool4 b) { return _mm_andnot_ps(b, a); } /* a & ~b */
/* lanes set where bit i of the constant mask is set */
RTK_INLINE vbool4 vb4_from_bits(int m) /* lane i all ones where bit i of m is set */
{
    const __m128i bit = _mm_setr_epi32(1, 2, 4, 8);
    return _mm_castsi128_ps(_mm_cmpeq_epi32(_mm_and_si128(_mm_set1_epi32(m), bit), bit));
}
RTK_INLINE int vb4_mask(vbool4 a) { return _mm_movemask_ps(a); }            /* bit i = lane i */
/* four int32 lanes (16-byte aligned), each 0 or -1, as a mask */
RTK_INLINE vbool4 vb4_load(const int32_t *p) { return _mm_load_ps((const float *)p); }

#endif
