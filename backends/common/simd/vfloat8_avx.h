/* 8-wide float vectors and masks on AVX (the avx and avx2 backends).  Only
 * what the 8-wide kernels need (8-wide nodes, 8-ray packets); integer vectors
 * stay 4-wide (AVX has no 256-bit integer arithmetic).  Same semantics as the
 * vf4_ / vb4_ functions of the same names. */
#ifndef RTK_VFLOAT8_AVX_H
#define RTK_VFLOAT8_AVX_H

#include <immintrin.h>

typedef __m256 vfloat8;
typedef __m256 vbool8;

RTK_INLINE vfloat8 vf8_load(const float *p) { return _mm256_load_ps(p); } /* 32-byte aligned */
RTK_INLINE void vf8_store(float *p, vfloat8 a) { _mm256_store_ps(p, a); }
RTK_INLINE vfloat8 vf8_set1(float a) { return _mm256_set1_ps(a); }
RTK_INLINE vfloat8 vf8_set1_at(const float *a)
{
    vfloat8 r;
    __asm__ volatile("vbroadcastss %1, %0" : "=x"(r) : "m"(*a));
    return r;
}
RTK_INLINE vfloat8 vf8_add(vfloat8 a, vfloat8 b) { return _mm256_add_ps(a, b); }
RTK_INLINE vfloat8 vf8_sub(vfloat8 a, vfloat8 b) { return _mm256_sub_ps(a, b); }
RTK_INLINE vfloat8 vf8_mul(vfloat8 a, vfloat8 b) { return _mm256_mul_ps(a, b); }
/* a * b + c, fused (one rounding) where the ISA has FMA, as vf4_madd */
RTK_INLINE vfloat8 vf8_madd(vfloat8 a, vfloat8 b, vfloat8 c)
{
#if defined(__FMA__)
    return _mm256_fmadd_ps(a, b, c);
#else
    return _mm256_add_ps(_mm256_mul_ps(a, b), c);
#endif
}
#if defined(__FMA__)
/* a * b - c with one rounding (only where the ISA has FMA: RTK_SIMD_HAS_FMA) */
RTK_INLINE vfloat8 vf8_msub(vfloat8 a, vfloat8 b, vfloat8 c) { return _mm256_fmsub_ps(a, b, c); }
#endif
#if defined(__AVX2__)
/* As vf4_maxi / vf4_mini / vf4_gti (AVX2 only) */
RTK_INLINE vfloat8 vf8_maxi(vfloat8 a, vfloat8 b)
{
    return _mm256_castsi256_ps(_mm256_max_epi32(_mm256_castps_si256(a), _mm256_castps_si256(b)));
}
RTK_INLINE vfloat8 vf8_mini(vfloat8 a, vfloat8 b)
{
    return _mm256_castsi256_ps(_mm256_min_epi32(_mm256_castps_si256(a), _mm256_castps_si256(b)));
}
RTK_INLINE vbool8 vf8_gti(vfloat8 a, vfloat8 b)
{
    return _mm256_castsi256_ps(_mm256_cmpgt_epi32(_mm256_castps_si256(a), _mm256_castps_si256(b)));
}
RTK_INLINE vfloat8 vf8_add_ulps(vfloat8 a, int n)
{
    return _mm256_castsi256_ps(_mm256_add_epi32(_mm256_castps_si256(a), _mm256_set1_epi32(n)));
}
#endif
/* lanes 0..3 (free: the lower half of the same register) */
RTK_INLINE vfloat4 vf8_low(vfloat8 a) { return _mm256_castps256_ps128(a); }
/* lanes 4..7 */
RTK_INLINE vfloat4 vf8_high(vfloat8 a) { return _mm256_extractf128_ps(a, 1); }
/* lanes 0..3 from lo, 4..7 from hi */
RTK_INLINE vfloat8 vf8_from4(vfloat4 lo, vfloat4 hi)
{
    return _mm256_insertf128_ps(_mm256_castps128_ps256(lo), hi, 1);
}
#if defined(__AVX2__)
/* the lanes as int32, added (wrapping) and returned as the bits of floats */
RTK_INLINE vfloat8 vf8_add_bits(vfloat8 a, vfloat8 b)
{
    return _mm256_castsi256_ps(_mm256_add_epi32(_mm256_castps_si256(a), _mm256_castps_si256(b)));
}
#endif
RTK_INLINE vfloat8 vf8_div(vfloat8 a, vfloat8 b) { return _mm256_div_ps(a, b); }
RTK_INLINE vfloat8 vf8_min(vfloat8 a, vfloat8 b) { return _mm256_min_ps(a, b); } /* b where either is NaN */
RTK_INLINE vfloat8 vf8_max(vfloat8 a, vfloat8 b) { return _mm256_max_ps(a, b); }
RTK_INLINE vbool8 vf8_lt(vfloat8 a, vfloat8 b) { return _mm256_cmp_ps(a, b, _CMP_LT_OQ); }
RTK_INLINE vbool8 vf8_le(vfloat8 a, vfloat8 b) { return _mm256_cmp_ps(a, b, _CMP_LE_OQ); }
RTK_INLINE vbool8 vf8_eq(vfloat8 a, vfloat8 b) { return _mm256_cmp_ps(a, b, _CMP_EQ_OQ); }
RTK_INLINE vbool8 vf8_gt(vfloat8 a, vfloat8 b) { return _mm256_cmp_ps(a, b, _CMP_GT_OQ); }
RTK_INLINE vbool8 vf8_ge(vfloat8 a, vfloat8 b) { return _mm256_cmp_ps(a, b, _CMP_GE_OQ); }
#if defined(__AVX2__) || !defined(__GNUC__) || defined(__clang__)
RTK_INLINE vfloat8 vf8_select(vbool8 m, vfloat8 a, vfloat8 b) { return _mm256_blendv_ps(b, a, m); } /* m ? a : b */
#else
/* m ? a : b.  Without AVX2, GCC 12 folds _mm256_blendv_ps into a select on
 * the mask's sign as a 256-bit integer comparison, which AVX lacks, and then
 * expands it lane by lane in scalar code with a branch per lane (the avx
 * backend's packets of 8 ran at 0.54x of Embree's where avx2's ran at 0.88x,
 * and slower than sse41's packets of 4).  The instruction itself, written out,
 * is what the intrinsic stands for. */
RTK_INLINE vfloat8 vf8_select(vbool8 m, vfloat8 a, vfloat8 b)
{
    vfloat8 r;
    __asm__("vblendvps %3, %2, %1, %0" : "=x"(r) : "x"(b), "x"(a), "x"(m));
    return r;
}
#endif
RTK_INLINE vfloat8 vf8_abs(vfloat8 a) { return _mm256_andnot_ps(_mm256_set1_ps(-0.0f), a); }
RTK_INLINE vfloat8 vf8_xor_sign(vfloat8 a, vfloat8 s)
{
    return _mm256_xor_ps(a, _mm256_and_ps(s, _mm256_set1_ps(-0.0f)));
}
/* the least and greatest lane (NaN-free lanes: the order of the pairings
 * is not specified) */
RTK_INLINE float vf8_reduce_min(vfloat8 a)
{
    return vf4_reduce_min(_mm_min_ps(_mm256_castps256_ps128(a), _mm256_extractf128_ps(a, 1)));
}
RTK_INLINE float vf8_reduce_max(vfloat8 a)
{
    return vf4_reduce_max(_mm_max_ps(_mm256_castps256_ps128(a), _mm256_extractf128_ps(a, 1)));
}

/* Eight reductions at once: lane i the least (greatest) lane of v[i].  The
 * halves of v[i] and v[i + 4] meet first (lanes 0-3 for v[i], 4-7 for
 * v[i + 4]), then pairs within each half, then neighbours: 21 instructions
 * for eight reductions against about 6 each. */
#define RTK_V8_REDUCE8(name, op)                                                                                       \
    RTK_INLINE vfloat8 name(const vfloat8 *v)                                                                          \
    {                                                                                                                  \
        vfloat8 a[4], b[2];                                                                                            \
        for (int i = 0; i < 4; i++)                                                                                    \
            a[i] = op(_mm256_permute2f128_ps(v[i], v[i + 4], 0x20), _mm256_permute2f128_ps(v[i], v[i + 4], 0x31));     \
        for (int i = 0; i < 2; i++)                                                                                    \
            b[i] = op(_mm256_shuffle_ps(a[2 * i], a[2 * i + 1], _MM_SHUFFLE(1, 0, 1, 0)),                              \
                      _mm256_shuffle_ps(a[2 * i], a[2 * i + 1], _MM_SHUFFLE(3, 2, 3, 2)));                             \
        return op(_mm256_shuffle_ps(b[0], b[1], _MM_SHUFFLE(2, 0, 2, 0)),                                              \
                  _mm256_shuffle_ps(b[0], b[1], _MM_SHUFFLE(3, 1, 3, 1)));                                             \
    }
RTK_V8_REDUCE8(vf8_reduce8_min, _mm256_min_ps)
RTK_V8_REDUCE8(vf8_reduce8_max, _mm256_max_ps)
#undef RTK_V8_REDUCE8

RTK_INLINE vbool8 vb8_and(vbool8 a, vbool8 b) { return _mm256_and_ps(a, b); }
RTK_INLINE vbool8 vb8_or(vbool8 a, vbool8 b) { return _mm256_or_ps(a, b); }
RTK_INLINE vbool8 vb8_andnot(vbool8 a, vbool8 b) { return _mm256_andnot_ps(b, a); } /* a & ~b */
RTK_INLINE int vb8_mask(vbool8 a) { return _mm256_movemask_ps(a); }               /* bit i = lane i */
/* eight int32 lanes (32-byte aligned), each 0 or -1, as a mask */
RTK_INLINE vbool8 vb8_load(const int32_t *p) { return _mm256_load_ps((const float *)p); }
/* lane i all ones where bit i of m is set: the bits picked out by an and
 * (as floats, AVX having no 8-wide integer ops) and compared as integers
 * turned into floats, which are exact and non-zero where a bit is set.  A
 * mask built by lane stores and a vector load would wait on store
 * forwarding. */
RTK_INLINE vbool8 vb8_from_bits(int m)
{
    const __m256 bit = _mm256_castsi256_ps(_mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128));
    const __m256 x = _mm256_and_ps(_mm256_castsi256_ps(_mm256_set1_epi32(m)), bit);
    return _mm256_cmp_ps(_mm256_cvtepi32_ps(_mm256_castps_si256(x)), _mm256_setzero_ps(), _CMP_NEQ_OQ);
}

#endif
