/* The order a batch of point queries is walked in: along a Morton
 * (Z-order) curve over the points' box.  Applications hand over points in
 * any order (a random sample, a grid, a scan); walked along the curve,
 * consecutive queries meet the same nodes and triangles while they are
 * still in cache.  Each query's answer does not depend on the order. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "scene_internal.h"

/* 10 bits of v moved to every third bit. */
static uint32_t spread3(uint32_t v)
{
    v &= 0x3ff;
    v = (v | (v << 16)) & 0x030000ff;
    v = (v | (v << 8)) & 0x0300f00f;
    v = (v | (v << 4)) & 0x030c30c3;
    v = (v | (v << 2)) & 0x09249249;
    return v;
}

int point_order(const rtk_point_query *q, size_t count, uint32_t *order)
{
    if (count > UINT32_MAX)
        return 1;
    uint32_t *key = malloc(2 * count * sizeof *key), *tmp = malloc(count * sizeof *tmp);
    if (!key || !tmp) {
        free(key);
        free(tmp);
        return 1;
    }
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t i = 0; i < count; i++) {
        if (point_fault(&q[i]))
            continue;
        const double p[3] = {q[i].x, q[i].y, q[i].z};
        for (int a = 0; a < 3; a++) {
            lo[a] = p[a] < lo[a] ? p[a] : lo[a];
            hi[a] = p[a] > hi[a] ? p[a] : hi[a];
        }
    }
    double scale[3];
    for (int a = 0; a < 3; a++)
        scale[a] = hi[a] > lo[a] ? 1023.0 / (hi[a] - lo[a]) : 0.0;
    for (size_t i = 0; i < count; i++) {
        uint32_t k = 0;
        if (!point_fault(&q[i])) {
            const double p[3] = {q[i].x, q[i].y, q[i].z};
            for (int a = 0; a < 3; a++) {
                double c = (p[a] - lo[a]) * scale[a];
                c = c < 0.0 ? 0.0 : c > 1023.0 ? 1023.0 : c;
                k |= spread3((uint32_t)c) << a;
            }
        }
        key[i] = k;
        order[i] = (uint32_t)i;
    }
    /* least significant digit first, 10 bits a pass, stable */
    uint32_t *kin = key, *kout = key + count, *oin = order, *oout = tmp;
    for (int shift = 0; shift < 30; shift += 10) {
        size_t start[1025] = {0};
        for (size_t i = 0; i < count; i++)
            start[((kin[i] >> shift) & 0x3ff) + 1]++;
        for (int b = 0; b < 1024; b++)
            start[b + 1] += start[b];
        for (size_t i = 0; i < count; i++) {
            const size_t at = start[(kin[i] >> shift) & 0x3ff]++;
            kout[at] = kin[i];
            oout[at] = oin[i];
        }
        uint32_t *t = kin;
        kin = kout, kout = t;
        t = oin, oin = oout, oout = t;
    }
    /* three passes: the order ended in tmp */
    memcpy(order, oin, count * sizeof *order);
    free(key);
    free(tmp);
    return 0;
}
