/* 4-wide operations written once over the others, for every vfloat4
 * implementation (included by simd.h after it). */
#ifndef RTK_VFLOAT4_COMMON_H
#define RTK_VFLOAT4_COMMON_H

/* Four reductions at once: lane i the least (greatest) lane of the i-th
 * argument. */
RTK_INLINE vfloat4 vf4_reduce4_min(vfloat4 a, vfloat4 b, vfloat4 c, vfloat4 d)
{
    vf4_transpose(&a, &b, &c, &d);
    return vf4_min(vf4_min(a, b), vf4_min(c, d));
}
RTK_INLINE vfloat4 vf4_reduce4_max(vfloat4 a, vfloat4 b, vfloat4 c, vfloat4 d)
{
    vf4_transpose(&a, &b, &c, &d);
    return vf4_max(vf4_max(a, b), vf4_max(c, d));
}

/* 1 / a lane by lane, a lane below `tiny` in magnitude taken as +-tiny with
 * its sign (-0.0 as -tiny): finite reciprocals with a's signs, for the slab
 * tests of ray directions, where a zero component would give 0 * inf = NaN. */
RTK_INLINE vfloat4 vf4_rcp_clamped(vfloat4 a, float tiny)
{
    const vfloat4 t = vf4_set1(tiny);
    return vf4_div(vf4_set1(1.0f), vf4_select(vf4_lt(vf4_abs(a), t), vf4_xor_sign(t, a), a));
}

#endif
