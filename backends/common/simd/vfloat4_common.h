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

/* The far planes' reciprocals of the slab tests: inv (vf4_rcp_clamped's)
 * where dir's magnitude is at least `tiny`, +-inf with dir's sign below it.
 * The clamped reciprocal +-1/tiny is smaller than the exact one there, so
 * it moves a near distance down, as it may, but a far one down too: an
 * origin exactly on a far plane (an axis ray along a box's face) got a far
 * distance of 0 and missed what lies on that face.  With +-inf the far
 * distance is +inf, -inf (the origin beyond the plane) or, on the plane,
 * 0 * inf = NaN, which the tests drop (their users say how: a NaN must
 * never reach the final comparison). */
RTK_INLINE vfloat4 vf4_inf_below(vfloat4 inv, vfloat4 dir, float tiny)
{
    return vf4_select(vf4_lt(vf4_abs(dir), vf4_set1(tiny)), vf4_xor_sign(vf4_set1(__builtin_inff()), inv), inv);
}

#endif
