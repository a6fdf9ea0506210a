/* Tree statistics and the picture of boxes by level.  See bvh_stats.h. */
#include "bvh_stats.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "png_io.h"

static int is_leaf(uint32_t ref)
{
    return ref != RTK_BVH_EMPTY && (ref & RTK_BVH_LEAF_BIT);
}

static double half_area(const float lo[3], const float hi[3])
{
    const double dx = (double)hi[0] - lo[0], dy = (double)hi[1] - lo[1], dz = (double)hi[2] - lo[2];
    return dx * dy + dy * dz + dz * dx;
}

/* The union of node i's used slots. */
static void node_box(const rtk_bvh *t, uint64_t i, float lo[3], float hi[3])
{
    for (int k = 0; k < 3; k++)
        lo[k] = INFINITY, hi[k] = -INFINITY;
    for (uint32_t c = 0; c < t->width; c++) {
        const uint64_t s = i * t->width + c;
        if (t->children[s] == RTK_BVH_EMPTY)
            continue;
        for (int k = 0; k < 3; k++) {
            lo[k] = fminf(lo[k], t->child_lower[3 * s + k]);
            hi[k] = fmaxf(hi[k], t->child_upper[3 * s + k]);
        }
    }
}

/* Each inner node's depth (the root's is 1), in one pass: parents come
 * before their children (rtk_bvh_check).  NULL when out of memory. */
static uint8_t *node_depths(const rtk_bvh *t)
{
    uint8_t *depth = calloc(t->node_count ? t->node_count : 1, 1);
    if (!depth)
        return NULL;
    depth[0] = 1;
    for (uint64_t i = 0; i < t->node_count; i++)
        for (uint32_t c = 0; c < t->width; c++) {
            const uint32_t ref = t->children[i * t->width + c];
            if (ref != RTK_BVH_EMPTY && !is_leaf(ref))
                depth[ref] = (uint8_t)(depth[i] + 1);
        }
    return depth;
}

static void count_leaf(const rtk_bvh *t, uint32_t ref, uint32_t depth, bvh_stats *s, double *depth_sum, double area)
{
    const uint64_t j = ref & ~RTK_BVH_LEAF_BIT;
    const uint64_t n = t->leaf_first[j + 1] - t->leaf_first[j];
    s->leaf_prims[n > 16 ? 16 : n - 1]++;
    s->leaf_blocks += (n + 3) / 4;
    *depth_sum += depth;
    if (depth > s->depth_max)
        s->depth_max = depth;
    s->sah += area * (double)((n + 3) / 4);
}

static int prim_order(const void *a, const void *b)
{
    const rtk_bvh_prim *x = a, *y = b;
    if (x->geom_id != y->geom_id)
        return x->geom_id < y->geom_id ? -1 : 1;
    return x->prim_id < y->prim_id ? -1 : x->prim_id > y->prim_id;
}

int bvh_stats_compute(const rtk_bvh *t, bvh_stats *s)
{
    memset(s, 0, sizeof *s);
    s->width = t->width;
    s->nodes = t->node_count;
    s->leaves = t->leaf_count;
    s->refs = s->prims = t->prim_count;
    if (t->prim_count) { /* distinct triangles: spatial splits put one in several leaves */
        rtk_bvh_prim *p = malloc(t->prim_count * sizeof *p);
        if (!p)
            return 1;
        memcpy(p, t->prims, t->prim_count * sizeof *p);
        qsort(p, t->prim_count, sizeof *p, prim_order);
        s->prims = 1;
        for (uint64_t k = 1; k < t->prim_count; k++)
            s->prims += p[k].geom_id != p[k - 1].geom_id || p[k].prim_id != p[k - 1].prim_id;
        free(p);
    }
    if (t->root == RTK_BVH_EMPTY)
        return 0;
    double depth_sum = 0.0;
    if (is_leaf(t->root)) { /* no boxes: the cost is the leaf's blocks */
        count_leaf(t, t->root, 1, s, &depth_sum, 1.0);
        s->depth_mean = 1.0;
        return 0;
    }
    uint8_t *depth = node_depths(t);
    if (!depth)
        return 1;
    node_box(t, 0, s->lower, s->upper);
    for (uint64_t i = 0; i < t->node_count; i++) {
        const uint32_t d = depth[i];
        float lo[3], hi[3];
        node_box(t, i, lo, hi);
        s->sah += half_area(lo, hi);
        if (d > s->depth_max)
            s->depth_max = d;
        for (uint32_t c = 0; c < t->width; c++) {
            const uint64_t slot = i * t->width + c;
            const uint32_t ref = t->children[slot];
            if (ref == RTK_BVH_EMPTY)
                continue;
            s->slots_used++;
            if (is_leaf(ref))
                count_leaf(t, ref, d + 1, s, &depth_sum,
                           half_area(t->child_lower + 3 * slot, t->child_upper + 3 * slot));
        }
    }
    free(depth);
    const double root = half_area(s->lower, s->upper);
    s->sah = root > 0.0 ? s->sah / root : 0.0;
    s->depth_mean = s->leaves ? depth_sum / (double)s->leaves : 0.0;
    return 0;
}

/* ---- the picture ---- */

/* 3x5 digits: one octal digit per row (3 bits, left pixel highest), top row first. */
static const uint16_t digits[10] = {
    075557, 026227, 071747, 071317, 055711, 074717, 074757, 071111, 075757, 075717,
};

static void put_digit(float *img, int stride, int x0, int y0, int d, int scale)
{
    for (int row = 0; row < 5; row++)
        for (int col = 0; col < 3; col++)
            if (digits[d] >> (3 * (4 - row) + (2 - col)) & 1)
                for (int y = 0; y < scale; y++)
                    for (int x = 0; x < scale; x++) {
                        float *p = img + 3 * ((size_t)(y0 + row * scale + y) * (size_t)stride + (size_t)(x0 + col * scale + x));
                        p[0] = p[1] = p[2] = 1e6f; /* saturates to white */
                    }
}

typedef struct canvas {
    float *acc; /* RGB, accumulated */
    int w, h;
} canvas;

static void add_px(canvas *c, int x, int y, const float rgb[3])
{
    if (x < 0 || y < 0 || x >= c->w || y >= c->h)
        return;
    float *p = c->acc + 3 * ((size_t)y * (size_t)c->w + (size_t)x);
    for (int k = 0; k < 3; k++)
        p[k] += rgb[k];
}

/* A rectangle's outline from (x0, y0) to (x1, y1) inclusive. */
static void outline(canvas *c, int x0, int y0, int x1, int y1, const float rgb[3])
{
    for (int x = x0; x <= x1; x++) {
        add_px(c, x, y0, rgb);
        if (y1 != y0)
            add_px(c, x, y1, rgb);
    }
    for (int y = y0 + 1; y < y1; y++) {
        add_px(c, x0, y, rgb);
        if (x1 != x0)
            add_px(c, x1, y, rgb);
    }
}

int bvh_picture(const rtk_bvh *t, const bvh_stats *s, int levels, int panel, const char *path, char *err,
                size_t err_size)
{
    if (t->node_count == 0) {
        snprintf(err, err_size, "%s: not written: the tree has no inner node, so no boxes", path);
        return 1;
    }
    if (levels > (int)s->depth_max - 1)
        levels = (int)s->depth_max - 1;
    if (levels < 1)
        levels = 1;
    const int cols = levels < 4 ? levels : 4, rows = (levels + 3) / 4;
    canvas c = {.w = cols * panel, .h = rows * panel};
    c.acc = calloc((size_t)c.w * (size_t)c.h * 3, sizeof(float));
    unsigned char *rgb = malloc((size_t)c.w * (size_t)c.h * 3);
    uint8_t *depth = node_depths(t);
    if (!c.acc || !rgb || !depth) {
        free(c.acc);
        free(rgb);
        free(depth);
        snprintf(err, err_size, "%s: out of memory for the picture", path);
        return 1;
    }
    /* Project along the shortest axis of the root box; keep the aspect. */
    float ext[3];
    int drop = 0;
    for (int k = 0; k < 3; k++) {
        ext[k] = s->upper[k] - s->lower[k];
        if (ext[k] < ext[drop])
            drop = k;
    }
    const int ax = drop == 0 ? 1 : 0, ay = drop == 2 ? 1 : 2;
    const float margin = 0.04f * (float)panel, span = fmaxf(ext[ax], ext[ay]);
    const float scale = span > 0.0f ? ((float)panel - 2.0f * margin) / span : 1.0f;
    const float off_x = margin + 0.5f * (((float)panel - 2.0f * margin) - ext[ax] * scale);
    const float off_y = margin + 0.5f * (((float)panel - 2.0f * margin) - ext[ay] * scale);
    static const float inner[3] = {0.10f, 0.25f, 0.60f}, leaf[3] = {0.60f, 0.30f, 0.05f};

    for (uint64_t i = 0; i < t->node_count; i++) {
        const int d = depth[i];
        for (uint32_t ch = 0; ch < t->width; ch++) {
            const uint64_t slot = i * t->width + ch;
            const uint32_t ref = t->children[slot];
            if (ref == RTK_BVH_EMPTY || d > levels)
                continue;
            const float *lo = t->child_lower + 3 * slot, *hi = t->child_upper + 3 * slot;
            const int px = ((d - 1) % 4) * panel, py = ((d - 1) / 4) * panel;
            const int x0 = px + (int)(off_x + (lo[ax] - s->lower[ax]) * scale);
            const int x1 = px + (int)(off_x + (hi[ax] - s->lower[ax]) * scale);
            const int y1 = py + panel - 1 - (int)(off_y + (lo[ay] - s->lower[ay]) * scale);
            const int y0 = py + panel - 1 - (int)(off_y + (hi[ay] - s->lower[ay]) * scale);
            outline(&c, x0, y0, x1, y1, is_leaf(ref) ? leaf : inner);
        }
    }
    /* panel numbers: the depth of the nodes whose child boxes are shown */
    for (int p = 0; p < levels; p++) {
        const int px = (p % 4) * panel + 6, py = (p / 4) * panel + 6, n = p + 1;
        if (n >= 10) {
            put_digit(c.acc, c.w, px, py, n / 10, 2);
            put_digit(c.acc, c.w, px + 8, py, n % 10, 2);
        } else {
            put_digit(c.acc, c.w, px, py, n, 2);
        }
    }
    /* Tone map: the more boxes on a pixel, the brighter, never clipped
     * to a flat colour; a thin grid between the panels. */
    for (int y = 0; y < c.h; y++)
        for (int x = 0; x < c.w; x++) {
            const float *a = c.acc + 3 * ((size_t)y * (size_t)c.w + (size_t)x);
            unsigned char *o = rgb + 3 * ((size_t)y * (size_t)c.w + (size_t)x);
            const int edge = x % panel == 0 || y % panel == 0;
            for (int k = 0; k < 3; k++) {
                float v = 0.08f + 0.92f * (1.0f - expf(-2.0f * a[k]));
                o[k] = edge ? 90 : (unsigned char)(255.0f * v + 0.5f);
            }
        }
    int rc = rtk_png_write_rgb(path, rgb, c.w, c.h, err, err_size);
    free(c.acc);
    free(rgb);
    free(depth);
    return rc;
}
