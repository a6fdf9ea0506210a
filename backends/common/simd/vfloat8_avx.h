/* 8-wide float vectors and masks on AVX (the avx and avx2 backends).  Only
 * what the 8-wide kernels need; integer vectors stay 4-wide (AVX has no
 * 256-bit integer arithmetic). */
#ifndef RTK_VFLOAT8_AVX_H
#define RTK_VFLOAT8_AVX_H

#include <immintrin.h>

typedef __m256 vfloat8;
typedef __m256 vbool8;

RTK_INLINE vfloat8 vf8_load(const float *p) { return _mm256_load_ps(p); } /* 32-byte aligned */
RTK_INLINE void vf8_store(float *p, vfloat8 a) { _mm256_store_ps(p, a); }
RTK_INLINE vfloat8 vf8_set1(float a) { return _mm256_set1_ps(a); }
RTK_INLINE vfloat8 vf8_add(vfloat8 a, vfloat8 b) { return _mm256_add_ps(a, b); }
RTK_INLINE vfloat8 vf8_sub(vfloat8 a, vfloat8 b) { return _mm256_sub_ps(a, b); }
RTK_INLINE vfloat8 vf8_mul(vfloat8 a, vfloat8 b) { return _mm256_mul_ps(a, b); }
RTK_INLINE vfloat8 vf8_min(vfloat8 a, vfloat8 b) { return _mm256_min_ps(a, b); }
RTK_INLINE vfloat8 vf8_max(vfloat8 a, vfloat8 b) { return _mm256_max_ps(a, b); }
RTK_INLINE vbool8 vf8_le(vfloat8 a, vfloat8 b) { return _mm256_cmp_ps(a, b, _CMP_LE_OQ); }
RTK_INLINE int vb8_mask(vbool8 a) { return _mm256_movemask_ps(a); } /* bit i = lane i */

#endif
