/* The order a batch of point queries is walked in: along a Morton
 * (Z-order) curve over the points' box.  Applications hand over points in
 * any order (a random sample, a grid, a scan); walked along the curve,
 * consecutive queries meet the same nodes and triangles while they are
 * still in cache.  Each query's answer does not depend on the order. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "scene_internal.h"

/* 5 bits moved to every third bit */
static const uint32_t spread5[32] = {
    0x00000, 0x00001, 0x00008, 0x00009, 0x00040, 0x00041, 0x00048, 0x00049, 0x00200, 0x00201, 0x00208, 0x00209, 0x00240, 0x00241, 0x00248, 0x00249,
    0x01000, 0x01001, 0x01008, 0x01009, 0x01040, 0x01041, 0x01048, 0x01049, 0x01200, 0x01201, 0x01208, 0x01209, 0x01240, 0x01241, 0x01248, 0x01249};

/* 10 bits of v (< 1024) moved to every third bit: two lookups, where the
 * shifts and masks of the usual form took the largest share of the order's
 * time (perf) */
static inline uint32_t spread3(uint32_t v) { return spread5[v & 31] | spread5[v >> 5] << 15; }

int point_order(const point_src *src, size_t count, uint32_t *order)
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
    /* (a point out of range has no answer, and its place in the order does
     * not matter; one whose time is wrong neither, so only the range is
     * asked for here) */
    for (size_t i = 0; i < count; i++) {
        double p[3];
        point_src_at(src, i, p);
        if (!xyz_in_range(p[0], p[1], p[2]))
            continue;
        for (int a = 0; a < 3; a++) {
            lo[a] = p[a] < lo[a] ? p[a] : lo[a];
            hi[a] = p[a] > hi[a] ? p[a] : hi[a];
        }
    }
    double scale[3];
    uint32_t start[3][1025] = {{0}}; /* per pass: the digits' counts, then where each goes (count < 2^32) */
    for (int a = 0; a < 3; a++)
        scale[a] = hi[a] > lo[a] ? 1023.0 / (hi[a] - lo[a]) : 0.0;
    for (size_t i = 0; i < count; i++) {
        uint32_t k = 0;
        double p[3];
        point_src_at(src, i, p);
        if (xyz_in_range(p[0], p[1], p[2])) {
            for (int a = 0; a < 3; a++) {
                double c = (p[a] - lo[a]) * scale[a];
                c = c < 0.0 ? 0.0 : c > 1023.0 ? 1023.0 : c;
                k |= spread3((uint32_t)c) << a;
            }
        }
        key[i] = k;
        /* the three passes' digits counted here, not in a pass each */
        start[0][(k & 0x3ff) + 1]++;
        start[1][(k >> 10 & 0x3ff) + 1]++;
        start[2][(k >> 20) + 1]++;
    }
    /* least significant digit first, 10 bits a pass, stable: the first
     * pass takes the queries as they come, the last one needs no keys, and
     * the three end in order */
    for (int d = 0; d < 3; d++)
        for (int b = 0; b < 1024; b++)
            start[d][b + 1] += start[d][b];
    uint32_t *const k1 = key + count;
    for (size_t i = 0; i < count; i++) {
        const uint32_t at = start[0][key[i] & 0x3ff]++;
        k1[at] = key[i];
        order[at] = (uint32_t)i;
    }
    for (size_t i = 0; i < count; i++) {
        const uint32_t at = start[1][k1[i] >> 10 & 0x3ff]++;
        key[at] = k1[i];
        tmp[at] = order[i];
    }
    for (size_t i = 0; i < count; i++)
        order[start[2][key[i] >> 20]++] = tmp[i];
    free(key);
    free(tmp);
    return 0;
}
