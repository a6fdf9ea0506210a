/*
 * rtk's thin SIMD layer.  Kernel code in backends/common uses only these
 * types and functions; intrinsics appear in this directory and in a backend's
 * hand-tuned overrides, nowhere else.
 *
 *   vfloat4 / vint4 / vbool4   4 lanes: SSE4.1 in the sse41, avx and avx2
 *                              backends; in the scalar backend the width-1
 *                              version (vfloat4_scalar.h), plain C run one
 *                              lane at a time with the vectorizers off
 *   vfloat8 / vbool8           8 lanes: AVX in the avx and avx2 backends,
 *                              two SSE4.1 halves in the sse41 backend
 *                              (vfloat8_sse41.h, for 8-wide nodes and
 *                              8-ray packets); none in the scalar backend
 *                              (RTK_SIMD_HAS_8 says they exist)
 *
 * Which header implements a width is decided here from the compiler's ISA
 * macros, which come from the backend's flags (backends/<name>/CMakeLists.txt),
 * so one kernel source compiles to each ISA.  All functions are static inline
 * and carry no state.  Lane order is memory order: lane 0 is p[0].
 *
 * Semantics shared by every implementation (the tests rely on them):
 *   vf4_min / vf4_max(a, b)  return b where either lane is NaN (the SSE rule),
 *                            so a NaN in a only ever loses
 *   vi4_from_vf4_trunc       truncates toward zero; lanes must be in int32
 *                            range (callers clamp in float first)
 *   vbool4                   a lane is all ones or all zeros
 *   vf4_maxi / vf4_mini /    max, min and a > b of the lanes' bit patterns
 *   vf4_gti                  as signed integers (SSE4.1; vf8_ ones on AVX2
 *                            only): the float order wherever both lanes are
 *                            non-negative (+0.0 included), and a negative
 *                            value (-0.0 included) is below every one of
 *                            those.  One cycle of latency where the float
 *                            ops take four, for kernels that can tell their
 *                            operands' signs apart
 *                            RTK_SIMD_INT_ORDER_4 / _8 say where they are
 *                            cheaper than the float ops at that width
 *                            (SSE4.1 / AVX2), so kernels use them there
 *   vf4_add_ulps(a, n)       the lanes' bit patterns plus n as integers
 *                            (wrapping): for finite positive lanes, n ulps
 *                            up (+inf becomes a NaN pattern, which the
 *                            integer order still puts above every finite
 *                            value); vf8_ on AVX2 only
 *   vf4_reduce_min / _max    the least / greatest of the lanes (vf8_ too);
 *                            with NaN lanes the answer depends on the
 *                            order of the pairings, which is not specified
 *   vf4_div / vf4_sqrt       correctly rounded (IEEE), every ISA
 *   vf4_madd / vf4_msub      fused (one rounding) where the ISA has FMA,
 *   (vf8_madd too)           two roundings elsewhere; RTK_SIMD_HAS_FMA says
 *                            which, for kernels whose error bounds depend on
 *                            it (vf8_msub exists only with FMA)
 *   vf4_set1_at / vf8_set1_at *a in every lane, loaded from memory where it
 *                            is written, every time: the compiler may not
 *                            keep it in a register across a loop (AVX only:
 *                            one vbroadcastss).  For a kernel whose loop
 *                            needs the registers more than the value.
 */
#ifndef RTK_SIMD_H
#define RTK_SIMD_H

#include <stdint.h>
#include <string.h>

#if defined(__FMA__)
#define RTK_SIMD_HAS_FMA 1
#endif

#if defined(__SSE4_1__)
#define RTK_SIMD_ISA "sse4.1"
#include "vfloat4_sse41.h"
#include "vfloat4_common.h"
#define RTK_SIMD_INT_ORDER_4 1
#define RTK_SIMD_HAS_8 1
#if defined(__AVX__)
#include "vfloat8_avx.h"
#else
#include "vfloat8_sse41.h"
#endif
#if defined(__AVX2__)
#define RTK_SIMD_INT_ORDER_8 1
#endif
#else
#define RTK_SIMD_ISA "scalar"
#include "vfloat4_scalar.h"
#include "vfloat4_common.h"
#endif
#ifndef RTK_SIMD_INT_ORDER_4
#define RTK_SIMD_INT_ORDER_4 0
#endif

/* A clock for kernels that choose between two ways of doing the same
 * work by timing them on the work at hand (the answers never depend on
 * it): the time-stamp counter, where x86 has one, else nanoseconds. */
#if defined(__x86_64__) || defined(__i386__)
static inline uint64_t rtk_cycles(void)
{
    return __builtin_ia32_rdtsc();
}
#else
#include <time.h>
static inline uint64_t rtk_cycles(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (uint64_t)t.tv_sec * 1000000000u + (uint64_t)t.tv_nsec;
}
#endif
#ifndef RTK_SIMD_INT_ORDER_8
#define RTK_SIMD_INT_ORDER_8 0
#endif

#endif
