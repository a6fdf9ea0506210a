/*
 * The SIMD layer's documented semantics, checked for one implementation per
 * build of this file: tests/CMakeLists.txt compiles it once with the
 * baseline flags (the width-1 version, as the scalar backend sees the layer) and
 * once with -msse4.1 (intrinsics, as sse41/avx/avx2 see it), and both
 * binaries must pass the same expectations.
 */
#include <float.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include "simd/simd.h"

static void get4(vfloat4 v, float out[4])
{
    _Alignas(16) float t[4];
    vf4_store(t, v);
    for (int i = 0; i < 4; i++)
        out[i] = t[i];
}

static void geti4(vint4 v, int32_t out[4])
{
    _Alignas(16) int32_t t[4];
    vi4_store(t, v);
    for (int i = 0; i < 4; i++)
        out[i] = t[i];
}

static void test_min_max_nan(void **state)
{
    (void)state;
    const float nan = NAN;
    vfloat4 a = vf4_set(1.0f, nan, 3.0f, -0.0f), b = vf4_set(2.0f, 5.0f, nan, 0.0f);
    float r[4];
    get4(vf4_min(a, b), r);
    assert_true(r[0] == 1.0f);
    assert_true(r[1] == 5.0f); /* NaN in a: b wins */
    assert_true(isnan(r[2]));  /* NaN in b: b is returned */
    assert_true(r[3] == 0.0f && !signbit(r[3])); /* -0 < 0 is false: b */
    get4(vf4_max(a, b), r);
    assert_true(r[0] == 2.0f);
    assert_true(r[1] == 5.0f);
    assert_true(isnan(r[2]));
    assert_true(r[3] == 0.0f && !signbit(r[3]));
}

static void test_compare_select_mask(void **state)
{
    (void)state;
    vfloat4 a = vf4_set(1.0f, 2.0f, NAN, 4.0f), b = vf4_set(2.0f, 2.0f, 1.0f, 3.0f);
    assert_int_equal(vb4_mask(vf4_lt(a, b)), 0x1);
    assert_int_equal(vb4_mask(vf4_le(a, b)), 0x3);
    assert_int_equal(vb4_mask(vf4_gt(a, b)), 0x8);
    assert_int_equal(vb4_mask(vf4_ge(a, b)), 0xa);
    assert_int_equal(vb4_mask(vf4_eq(a, b)), 0x2);
    assert_int_equal(vf4_signs(vf4_set(-1.0f, 0.0f, -0.0f, -NAN)), 0xd);
    assert_int_equal(vf4_signs(vf4_set(INFINITY, -INFINITY, 1e-30f, NAN)), 0x2);
    assert_int_equal(vb4_mask(vb4_from_bits(0x5)), 0x5);
    for (int m = 0; m < 16; m++) { /* every pattern, each lane all ones (the and keeps all of -1.5) or zeros */
        float kept[4];
        assert_int_equal(vb4_mask(vb4_from_bits(m)), m);
        get4(vf4_keep(vb4_from_bits(m), vf4_set1(-1.5f)), kept);
        for (int k = 0; k < 4; k++)
            assert_true(kept[k] == ((m >> k & 1) ? -1.5f : 0.0f));
    }
    assert_int_equal(vb4_mask(vb4_andnot(vb4_from_bits(0x7), vb4_from_bits(0x2))), 0x5);
    assert_int_equal(vb4_mask(vb4_or(vb4_from_bits(0x1), vb4_from_bits(0x8))), 0x9);
    float r[4];
    get4(vf4_select(vb4_from_bits(0x6), a, b), r);
    assert_true(r[0] == 2.0f && r[1] == 2.0f && isnan(r[2]) && r[3] == 3.0f);
    get4(vf4_keep(vb4_from_bits(0x9), b), r);
    assert_true(r[0] == 2.0f && r[1] == 0.0f && r[2] == 0.0f && r[3] == 3.0f);
    get4(vf4_clear3(vf4_set(-1.0f, 2.0f, -0.0f, -3.0f)), r);
    assert_true(r[0] == -1.0f && r[1] == 2.0f && r[2] == 0.0f && signbit(r[2]) && r[3] == 0.0f && !signbit(r[3]));
    get4(vf4_yzx(vf4_set(1.0f, 2.0f, 3.0f, 4.0f)), r);
    assert_true(r[0] == 2.0f && r[1] == 3.0f && r[2] == 1.0f && r[3] == 4.0f);
    get4(vf4_zxy(vf4_set(1.0f, 2.0f, 3.0f, 4.0f)), r);
    assert_true(r[0] == 3.0f && r[1] == 1.0f && r[2] == 2.0f && r[3] == 4.0f);
}

static void test_arithmetic(void **state)
{
    (void)state;
    vfloat4 a = vf4_set(1.5f, -2.0f, 3.0f, 0.25f), b = vf4_set(2.0f, 4.0f, -1.0f, 8.0f);
    float r[4];
    get4(vf4_madd(a, b, vf4_set1(1.0f)), r);
    assert_true(r[0] == 4.0f && r[1] == -7.0f && r[2] == -2.0f && r[3] == 3.0f);
    get4(vf4_msub(a, b, vf4_set1(1.0f)), r);
    assert_true(r[0] == 2.0f && r[1] == -9.0f && r[2] == -4.0f && r[3] == 1.0f);
    get4(vf4_div(a, b), r);
    assert_true(r[0] == 0.75f && r[1] == -0.5f && r[2] == -3.0f && r[3] == 0.03125f);
    get4(vf4_abs(vf4_set(-1.0f, -0.0f, 2.0f, -INFINITY)), r);
    assert_true(r[0] == 1.0f && r[1] == 0.0f && !signbit(r[1]) && r[2] == 2.0f && r[3] == INFINITY);
    get4(vf4_xor_sign(vf4_set(1.0f, 1.0f, -1.0f, 0.0f), vf4_set(-3.0f, 3.0f, -0.0f, -1.0f)), r);
    assert_true(r[0] == -1.0f && r[1] == 1.0f && r[2] == 1.0f && r[3] == 0.0f && signbit(r[3]));
    /* bitwise xor and or: the sign bits of (x ^ y) | (x ^ z) say where signs differ */
    assert_int_equal(vf4_signs(vf4_or(vf4_xor(vf4_set(1.0f, -1.0f, 2.0f, -0.0f), vf4_set(3.0f, -3.0f, -2.0f, 0.0f)),
                                      vf4_xor(vf4_set(1.0f, -1.0f, 2.0f, -0.0f), vf4_set(4.0f, 4.0f, 1.0f, -1.0f)))),
                     0xe);
    get4(vf4_xor(vf4_set(1.0f, -2.0f, 0.0f, 8.0f), vf4_set(-0.0f, -0.0f, -0.0f, 0.0f)), r);
    assert_true(r[0] == -1.0f && r[1] == 2.0f && r[2] == 0.0f && signbit(r[2]) && r[3] == 8.0f);
    get4(vf4_or(vf4_set(1.0f, -2.0f, 0.0f, 8.0f), vf4_set(-0.0f, -0.0f, 0.0f, 0.0f)), r);
    assert_true(r[0] == -1.0f && r[1] == -2.0f && r[2] == 0.0f && !signbit(r[2]) && r[3] == 8.0f);
    assert_true(vf4_reduce_min(vf4_set(3.0f, 1.0f, 2.0f, -5.0f)) == -5.0f);
    assert_true(vf4_reduce_min3(vf4_set(3.0f, 1.0f, 2.0f, -5.0f)) == 1.0f);
    assert_true(vf4_reduce_max3(vf4_set(3.0f, 1.0f, 2.0f, 9.0f)) == 3.0f);
    assert_true(vf4_lane0(a) == 1.5f);
    get4(vf4_broadcast(a, 2), r);
    assert_true(r[0] == 3.0f && r[3] == 3.0f);
}

static void test_transpose(void **state)
{
    (void)state;
    vfloat4 a = vf4_set(0, 1, 2, 3), b = vf4_set(4, 5, 6, 7), c = vf4_set(8, 9, 10, 11), d = vf4_set(12, 13, 14, 15);
    vf4_transpose(&a, &b, &c, &d);
    float r[4][4];
    get4(a, r[0]);
    get4(b, r[1]);
    get4(c, r[2]);
    get4(d, r[3]);
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++)
            assert_true(r[i][j] == (float)(4 * j + i));
}

static void test_int(void **state)
{
    (void)state;
    int32_t r[4];
    geti4(vi4_from_vf4_trunc(vf4_set(1.9f, -1.9f, 31.999f, 0.0f)), r);
    assert_true(r[0] == 1 && r[1] == -1 && r[2] == 31 && r[3] == 0);
    _Alignas(16) const int32_t p[4] = {5, -7, INT32_MAX, 0};
    vint4 a = vi4_load(p);
    geti4(vi4_add(a, vi4_set1(1)), r);
    assert_true(r[0] == 6 && r[1] == -6 && r[2] == INT32_MIN && r[3] == 1); /* wraps */
    geti4(vi4_min(a, vi4_set1(0)), r);
    assert_true(r[0] == 0 && r[1] == -7 && r[2] == 0 && r[3] == 0);
    geti4(vi4_max(a, vi4_set1(0)), r);
    assert_true(r[0] == 5 && r[1] == 0 && r[2] == INT32_MAX && r[3] == 0);
    geti4(vi4_shr(vi4_set1(-1), 28), r);
    assert_true(r[0] == 15); /* logical shift */
    geti4(vi4_shl(a, 5), r);
    assert_true(r[0] == 160 && r[1] == -224 && r[2] == -32 && r[3] == 0); /* bits shifted out are lost */
    assert_int_equal(vb4_mask(vi4_lt(a, vi4_set1(0))), 0x2);
    assert_int_equal(vb4_mask(vi4_eq(a, vi4_set1(0))), 0x8);
    geti4(vi4_select(vb4_from_bits(0x3), a, vi4_set1(9)), r);
    assert_true(r[0] == 5 && r[1] == -7 && r[2] == 9 && r[3] == 9);
    assert_int_equal(vi4_lane(a, 1), -7);
    float f[4];
    get4(vf4_from_vi4(a), f);
    assert_true(f[0] == 5.0f && f[1] == -7.0f);
    geti4(vf4_bits(vf4_set1(1.0f)), r);
    assert_true(r[0] == 0x3f800000);
    get4(vf4_from_bits(vi4_set1(0x40000000)), f);
    assert_true(f[3] == 2.0f);
}

/* The integer order of float bits: the float order for non-negative values
 * (+0.0 included), negatives (-0.0 included) below all of them. */
static void test_integer_order(void **state)
{
    (void)state;
    float r[4];
    const vfloat4 a = vf4_set(0.0f, 1.5f, -0.0f, -3.0f), b = vf4_set(0x1p-149f, INFINITY, 0.0f, 2.0f);
    get4(vf4_maxi(a, b), r);
    assert_true(r[0] == 0x1p-149f && r[1] == INFINITY && r[2] == 0.0f && !signbit(r[2]) && r[3] == 2.0f);
    get4(vf4_mini(a, b), r);
    assert_true(r[0] == 0.0f && r[1] == 1.5f && r[2] == 0.0f && signbit(r[2]) && r[3] == -3.0f);
    assert_int_equal(vb4_mask(vf4_gti(a, b)), 0x0);
    assert_int_equal(vb4_mask(vf4_gti(b, a)), 0xf);
    /* among negatives the order is that of the magnitudes: callers must
     * keep them out of anything but "below every non-negative value" */
    assert_int_equal(vb4_mask(vf4_gti(vf4_set1(-2.0f), vf4_set1(-1.0f))), 0xf);
    /* n ulps up */
    get4(vf4_add_ulps(vf4_set(1.0f, 0.0f, 0x1.fffffep-1f, 3.0f), 8), r);
    assert_true(r[0] == 0x1.000010p0f && r[1] == 0x1p-146f && r[2] == 0x1.00000ep0f && r[3] == 0x1.800010p1f);
    assert_int_equal(vb4_mask(vf4_gti(vf4_add_ulps(vf4_set1(INFINITY), 8), vf4_set1(FLT_MAX))), 0xf);
}

static void test_reduce(void **state)
{
    (void)state;
    assert_true(vf4_reduce_max(vf4_set(3.0f, 1.0f, 9.0f, -5.0f)) == 9.0f);
    assert_true(vf4_reduce_max(vf4_set(-INFINITY, -2.0f, -INFINITY, -7.0f)) == -2.0f);
    assert_true(vf4_reduce_min(vf4_set(INFINITY, 2.0f, INFINITY, 7.0f)) == 2.0f);
#if RTK_SIMD_HAS_8
    /* every lane position as the extreme one */
    for (int i = 0; i < 8; i++) {
        _Alignas(32) float x[8];
        for (int k = 0; k < 8; k++)
            x[k] = (float)(k * 3 % 8) - 4.0f; /* a permutation of -4..3, -4 at 0 */
        x[i] = -100.0f;
        assert_true(vf8_reduce_min(vf8_load(x)) == -100.0f);
        x[i] = 100.0f;
        assert_true(vf8_reduce_max(vf8_load(x)) == 100.0f);
        assert_true(vf8_reduce_min(vf8_load(x)) == (i == 0 ? -3.0f : -4.0f));
    }
#endif
    /* several reductions at once: lane j that of argument j, each with its
     * extreme in another lane, infinities as the packets' inactive lanes */
    {
        float r[4];
        get4(vf4_reduce4_min(vf4_set(5.0f, 1.0f, 2.0f, 3.0f), vf4_set(4.0f, 6.0f, -2.0f, INFINITY),
                             vf4_set(INFINITY, INFINITY, INFINITY, 7.0f), vf4_set(-1.0f, 0.0f, 0.0f, 0.0f)),
             r);
        assert_true(r[0] == 1.0f && r[1] == -2.0f && r[2] == 7.0f && r[3] == -1.0f);
        get4(vf4_reduce4_max(vf4_set(5.0f, 1.0f, 2.0f, 3.0f), vf4_set(4.0f, 6.0f, -2.0f, -INFINITY),
                             vf4_set(-INFINITY, -INFINITY, -INFINITY, 7.0f), vf4_set(-1.0f, 0.0f, 0.0f, 9.0f)),
             r);
        assert_true(r[0] == 5.0f && r[1] == 6.0f && r[2] == 7.0f && r[3] == 9.0f);
    }
#if RTK_SIMD_HAS_8
    {
        /* vector j holds j + 1 in every lane but lane (3 * j + 1) % 8, which
         * holds -(j + 1) for the minimum and 100 + j for the maximum */
        _Alignas(32) float x[8], r[8];
        vfloat8 lo[8], hi[8];
        for (int j = 0; j < 8; j++) {
            for (int k = 0; k < 8; k++)
                x[k] = (float)(j + 1);
            x[(3 * j + 1) % 8] = -(float)(j + 1);
            lo[j] = vf8_load(x);
            x[(3 * j + 1) % 8] = 100.0f + (float)j;
            hi[j] = vf8_load(x);
        }
        vf8_store(r, vf8_reduce8_min(lo));
        for (int j = 0; j < 8; j++)
            assert_true(r[j] == -(float)(j + 1));
        vf8_store(r, vf8_reduce8_max(hi));
        for (int j = 0; j < 8; j++)
            assert_true(r[j] == 100.0f + (float)j);
    }
#endif
}

#if RTK_SIMD_HAS_8
static void test_width8(void **state)
{
    (void)state;
    _Alignas(32) float a[8] = {1.0f, -2.0f, 0.0f, -0.0f, INFINITY, 3.0f, 0x1p-149f, NAN}, r[8];
    _Alignas(32) const float b[8] = {2.0f, -3.0f, -0.0f, 0.0f, 1.0f, NAN, 0.0f, 5.0f};
    const vfloat8 va = vf8_load(a), vb = vf8_load(b);
    vf8_store(r, vf8_min(va, vb)); /* b where either is NaN */
    assert_true(r[0] == 1.0f && r[1] == -3.0f && r[4] == 1.0f && isnan(r[5]) && r[6] == 0.0f && r[7] == 5.0f);
    vf8_store(r, vf8_max(va, vb));
    assert_true(r[0] == 2.0f && r[1] == -2.0f && r[4] == INFINITY && isnan(r[5]) && r[6] == 0x1p-149f && r[7] == 5.0f);
    assert_int_equal(vb8_mask(vf8_lt(va, vb)), 0x01);
    assert_int_equal(vb8_mask(vf8_le(va, vb)), 0x0d); /* 0 <= -0 and -0 <= 0 */
    vf8_store(r, vf8_select(vf8_gt(va, vb), va, vb));
    assert_true(r[1] == -2.0f && r[4] == INFINITY && r[6] == 0x1p-149f && r[7] == 5.0f && isnan(r[5]));
    /* every pattern of lanes, each lane from its own side (the avx
     * backend's select is written out in assembly, see vfloat8_avx.h) */
    for (int m = 0; m < 256; m++) {
        _Alignas(32) float x[8], y[8], lim[8];
        for (int k = 0; k < 8; k++) {
            x[k] = (float)(k + 1);
            y[k] = -(float)(k + 1);
            lim[k] = (m >> k & 1) ? 0.0f : 100.0f; /* x > lim where bit k is set */
        }
        const vbool8 sel = vf8_gt(vf8_load(x), vf8_load(lim));
        assert_int_equal(vb8_mask(sel), m);
        assert_int_equal(vb8_mask(vb8_from_bits(m)), m);
        /* all ones where set: a select through it takes whole lanes */
        vf8_store(r, vf8_select(vb8_from_bits(m), vf8_set1(NAN), vf8_load(y)));
        for (int k = 0; k < 8; k++)
            assert_true((m >> k & 1) ? isnan(r[k]) : r[k] == y[k]);
        vf8_store(r, vf8_select(sel, vf8_load(x), vf8_load(y)));
        for (int k = 0; k < 8; k++)
            assert_true(r[k] == ((m >> k & 1) ? x[k] : y[k]));
        vf8_store(r, vf8_select(sel, vf8_load(x), vf8_set1(NAN))); /* a constant side, as the packets' NaN */
        for (int k = 0; k < 8; k++)
            assert_true((m >> k & 1) ? r[k] == x[k] : isnan(r[k]));
    }
    vf8_store(r, vf8_xor_sign(vf8_abs(va), vb));
    assert_true(r[0] == 1.0f && r[1] == -2.0f && r[2] == 0.0f && signbit(r[2]) && r[3] == 0.0f && !signbit(r[3]));
    vf4_store(r, vf8_low(va));
    assert_true(r[0] == 1.0f && r[1] == -2.0f && r[3] == 0.0f && signbit(r[3]));
    vf8_store(r, vf8_from4(vf4_set(1.0f, 2.0f, 3.0f, 4.0f), vf4_set(5.0f, 6.0f, 7.0f, 8.0f)));
    assert_true(r[0] == 1.0f && r[3] == 4.0f && r[4] == 5.0f && r[7] == 8.0f);
    vf4_store(r, vf8_high(va));
    assert_true(r[0] == INFINITY && r[1] == 3.0f && r[2] == 0x1p-149f && isnan(r[3]));
#if defined(__AVX2__)
    vf8_store(r, vf8_add_bits(vf8_set1(1.0f), vf8_set1(0x1p-149f))); /* + 1 as an integer: the next float */
    assert_true(r[0] == nextafterf(1.0f, 2.0f) && r[7] == nextafterf(1.0f, 2.0f));
#endif
#if RTK_SIMD_HAS_FMA
    /* one rounding: (1 + 2^-12)^2 - 1 keeps its 2^-24 term */
    const float e = 1.0f + 0x1p-12f;
    vf8_store(r, vf8_msub(vf8_set1(e), vf8_set1(e), vf8_set1(1.0f)));
    assert_true(r[0] == 0x1p-11f + 0x1p-24f);
#endif
#if RTK_SIMD_INT_ORDER_8
    vf8_store(r, vf8_add_ulps(vf8_set1(1.0f), 8));
    assert_true(r[7] == 0x1.000010p0f);
    assert_int_equal(vb8_mask(vf8_gti(vf8_add_ulps(vf8_set1(INFINITY), 8), vf8_set1(FLT_MAX))), 0xff);
    vf8_store(r, vf8_maxi(vf8_set1(-0.0f), vf8_set1(0x1p-149f)));
    assert_true(r[3] == 0x1p-149f);
#endif
}
#endif

int main(void)
{
#if RTK_SIMD_HAS_8
    print_message("SIMD layer implementation: %s, and 8 lanes\n", RTK_SIMD_ISA);
#else
    print_message("SIMD layer implementation: %s\n", RTK_SIMD_ISA);
#endif
#if defined(__AVX2__)
    if (!__builtin_cpu_supports("avx2") || !__builtin_cpu_supports("fma")) {
        print_message("this CPU has no AVX2 and FMA: nothing to test\n");
        return 0;
    }
#elif defined(__AVX__)
    if (!__builtin_cpu_supports("avx")) {
        print_message("this CPU has no AVX: nothing to test\n");
        return 0;
    }
#endif
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_reduce),
        cmocka_unit_test(test_min_max_nan), cmocka_unit_test(test_compare_select_mask),
        cmocka_unit_test(test_arithmetic),  cmocka_unit_test(test_transpose),
        cmocka_unit_test(test_int),         cmocka_unit_test(test_integer_order),
#if RTK_SIMD_HAS_8
        cmocka_unit_test(test_width8),
#endif
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
