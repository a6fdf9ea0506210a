/* 8-wide float vectors and masks as two SSE4.1 halves (the sse41 backend):
 * the 8-wide nodes' layouts on a 4-wide ISA.  Only the operations the
 * avx backend has too (no FMA, no integer order); same semantics as the
 * vf4_ / vb4_ functions of the same names, lane i of the pair being lane i
 * of lo for i < 4 and lane i - 4 of hi after. */
#ifndef RTK_VFLOAT8_SSE41_H
#define RTK_VFLOAT8_SSE41_H

typedef struct vfloat8 {
    vfloat4 lo, hi;
} vfloat8;
typedef vfloat8 vbool8;

#define RTK_V8_MAP2(name, op)                                                                                          \
    RTK_INLINE vfloat8 name(vfloat8 a, vfloat8 b) { return (vfloat8){op(a.lo, b.lo), op(a.hi, b.hi)}; }

RTK_INLINE vfloat8 vf8_load(const float *p) { return (vfloat8){vf4_load(p), vf4_load(p + 4)}; } /* 16-byte aligned */
RTK_INLINE void vf8_store(float *p, vfloat8 a)
{
    vf4_store(p, a.lo);
    vf4_store(p + 4, a.hi);
}
RTK_INLINE vfloat8 vf8_set1(float a) { return (vfloat8){vf4_set1(a), vf4_set1(a)}; }
RTK_V8_MAP2(vf8_add, vf4_add)
RTK_V8_MAP2(vf8_sub, vf4_sub)
RTK_V8_MAP2(vf8_mul, vf4_mul)
RTK_V8_MAP2(vf8_div, vf4_div)
RTK_V8_MAP2(vf8_min, vf4_min)
RTK_V8_MAP2(vf8_max, vf4_max)
RTK_V8_MAP2(vf8_lt, vf4_lt)
RTK_V8_MAP2(vf8_le, vf4_le)
RTK_V8_MAP2(vf8_eq, vf4_eq)
RTK_V8_MAP2(vf8_gt, vf4_gt)
RTK_V8_MAP2(vf8_ge, vf4_ge)
RTK_V8_MAP2(vf8_xor_sign, vf4_xor_sign)
RTK_V8_MAP2(vb8_and, vb4_and)
RTK_V8_MAP2(vb8_or, vb4_or)
RTK_V8_MAP2(vb8_andnot, vb4_andnot)
#undef RTK_V8_MAP2
/* a * b + c, two roundings (no FMA here) */
RTK_INLINE vfloat8 vf8_madd(vfloat8 a, vfloat8 b, vfloat8 c)
{
    return (vfloat8){vf4_madd(a.lo, b.lo, c.lo), vf4_madd(a.hi, b.hi, c.hi)};
}
RTK_INLINE vfloat4 vf8_low(vfloat8 a) { return a.lo; }
RTK_INLINE vfloat4 vf8_high(vfloat8 a) { return a.hi; }
RTK_INLINE vfloat8 vf8_from4(vfloat4 lo, vfloat4 hi) { return (vfloat8){lo, hi}; }
RTK_INLINE vfloat8 vf8_select(vbool8 m, vfloat8 a, vfloat8 b)
{
    return (vfloat8){vf4_select(m.lo, a.lo, b.lo), vf4_select(m.hi, a.hi, b.hi)};
}
RTK_INLINE vfloat8 vf8_abs(vfloat8 a) { return (vfloat8){vf4_abs(a.lo), vf4_abs(a.hi)}; }
RTK_INLINE float vf8_reduce_min(vfloat8 a) { return vf4_reduce_min(vf4_min(a.lo, a.hi)); }
RTK_INLINE float vf8_reduce_max(vfloat8 a) { return vf4_reduce_max(vf4_max(a.lo, a.hi)); }
RTK_INLINE int vb8_mask(vbool8 a) { return vb4_mask(a.lo) | vb4_mask(a.hi) << 4; } /* bit i = lane i */
RTK_INLINE vbool8 vb8_load(const int32_t *p) { return (vbool8){vb4_load(p), vb4_load(p + 4)}; }
/* Eight reductions at once: lane i the least (greatest) lane of v[i]. */
RTK_INLINE vfloat8 vf8_reduce8_min(const vfloat8 *v)
{
    vfloat4 h[8];
    for (int i = 0; i < 8; i++)
        h[i] = vf4_min(v[i].lo, v[i].hi);
    return (vfloat8){vf4_reduce4_min(h[0], h[1], h[2], h[3]), vf4_reduce4_min(h[4], h[5], h[6], h[7])};
}
RTK_INLINE vfloat8 vf8_reduce8_max(const vfloat8 *v)
{
    vfloat4 h[8];
    for (int i = 0; i < 8; i++)
        h[i] = vf4_max(v[i].lo, v[i].hi);
    return (vfloat8){vf4_reduce4_max(h[0], h[1], h[2], h[3]), vf4_reduce4_max(h[4], h[5], h[6], h[7])};
}
RTK_INLINE vbool8 vb8_from_bits(int m) { return (vbool8){vb4_from_bits(m & 15), vb4_from_bits(m >> 4 & 15)}; } /* lane i: bit i */

#endif
