/* Mesh clean-ups for rtktool convert.  See mesh_tools.h. */
#include "mesh_tools.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "geometry/triangle.h"

/* The position's bits with -0.0 made +0.0, so equal floats hash alike. */
static uint64_t position_hash(const float *p)
{
    uint64_t h = 0xcbf29ce484222325ull;
    for (int k = 0; k < 3; k++) {
        const float x = p[k] == 0.0f ? 0.0f : p[k];
        uint32_t b;
        memcpy(&b, &x, sizeof b);
        h = (h ^ b) * 0x100000001b3ull;
    }
    return h ^ (h >> 29);
}

size_t rtk_mesh_merge_vertices(rtk_mesh *mesh)
{
    const size_t nv = mesh->vertex_count;
    if (nv == 0)
        return 0;
    size_t cap = 16;
    while (cap < 2 * nv)
        cap *= 2;
    uint32_t *table = malloc(cap * sizeof *table); /* vertex + 1, 0 = empty */
    uint32_t *remap = malloc(nv * sizeof *remap);
    if (!table || !remap) {
        free(table);
        free(remap);
        return (size_t)-1;
    }
    memset(table, 0, cap * sizeof *table);
    /* remap[i]: the first vertex at i's position */
    for (size_t i = 0; i < nv; i++) {
        const float *p = &mesh->vertices[3 * i];
        size_t slot = (size_t)position_hash(p) & (cap - 1);
        remap[i] = (uint32_t)i;
        for (;; slot = (slot + 1) & (cap - 1)) {
            if (!table[slot]) {
                table[slot] = (uint32_t)i + 1;
                break;
            }
            const float *q = &mesh->vertices[3 * (size_t)(table[slot] - 1)];
            if (p[0] == q[0] && p[1] == q[1] && p[2] == q[2]) {
                remap[i] = table[slot] - 1;
                break;
            }
        }
    }
    free(table);
    /* compact: the vertices that are their own representative, in order */
    size_t kept = 0;
    for (size_t i = 0; i < nv; i++) {
        if (remap[i] == i) {
            memmove(&mesh->vertices[3 * kept], &mesh->vertices[3 * i], 3 * sizeof(float));
            remap[i] = (uint32_t)kept++;
        } else {
            remap[i] = remap[remap[i]]; /* the representative comes first: already renumbered */
        }
    }
    for (size_t i = 0; i < 3 * mesh->triangle_count; i++)
        mesh->indices[i] = remap[mesh->indices[i]];
    free(remap);
    mesh->vertex_count = kept;
    return nv - kept;
}

/* 0: hittable, 1: degenerate, 2: non-finite */
static int classify(const rtk_mesh *mesh, size_t t)
{
    const uint32_t *i = &mesh->indices[3 * t];
    const float *a = &mesh->vertices[3 * (size_t)i[0]], *b = &mesh->vertices[3 * (size_t)i[1]],
                *c = &mesh->vertices[3 * (size_t)i[2]];
    if (!rtk_triangle_is_finite(a, b, c))
        return 2;
    return rtk_triangle_is_degenerate(a, b, c) ? 1 : 0;
}

void rtk_mesh_count_unhittable(const rtk_mesh *mesh, size_t *degenerate, size_t *non_finite)
{
    size_t n[3] = {0, 0, 0};
    for (size_t t = 0; t < mesh->triangle_count; t++)
        n[classify(mesh, t)]++;
    *degenerate = n[1];
    *non_finite = n[2];
}

void rtk_mesh_drop_unhittable(rtk_mesh *mesh, size_t *degenerate, size_t *non_finite)
{
    size_t n[3] = {0, 0, 0}, kept = 0;
    for (size_t t = 0; t < mesh->triangle_count; t++) {
        const int c = classify(mesh, t);
        n[c]++;
        if (c == 0)
            memmove(&mesh->indices[3 * kept++], &mesh->indices[3 * t], 3 * sizeof(uint32_t));
    }
    mesh->triangle_count = kept;
    *degenerate = n[1];
    *non_finite = n[2];
}

int rtk_mesh_procedural(size_t triangles, rtk_mesh *mesh)
{
    memset(mesh, 0, sizeof *mesh);
    size_t r = (size_t)sqrt((double)triangles / 2.0);
    r = r < 1 ? 1 : r;
    const size_t nv = (r + 1) * (r + 1), nt = 2 * r * r;
    mesh->vertices = malloc(nv * 3 * sizeof(float));
    mesh->indices = malloc(nt * 3 * sizeof(uint32_t));
    if (!mesh->vertices || !mesh->indices || nv > UINT32_MAX) {
        free(mesh->vertices);
        free(mesh->indices);
        memset(mesh, 0, sizeof *mesh);
        return 1;
    }
    for (size_t j = 0; j <= r; j++)
        for (size_t i = 0; i <= r; i++) {
            const double th = 3.14159265358979 * ((double)j + 0.5) / ((double)r + 1.0);
            const double ph = 6.28318530717959 * (double)i / (double)r;
            const double bump = 0.06 * sin(7.0 * th) * cos(5.0 * ph) + 0.02 * sin(41.0 * th) * sin(37.0 * ph) +
                                0.005 * sin(263.0 * th + 1.0) * cos(241.0 * ph);
            float *p = mesh->vertices + 3 * (j * (r + 1) + i);
            p[0] = (float)((1.0 + bump) * sin(th) * cos(ph));
            p[1] = (float)((1.0 + bump) * cos(th));
            p[2] = (float)((1.0 + bump) * sin(th) * sin(ph));
        }
    size_t t = 0;
    for (size_t j = 0; j < r; j++)
        for (size_t i = 0; i < r; i++) {
            const uint32_t a = (uint32_t)(j * (r + 1) + i), b = a + 1, c = a + (uint32_t)r + 1, d = c + 1;
            uint32_t *q = mesh->indices + 3 * t;
            q[0] = a, q[1] = c, q[2] = b, q[3] = b, q[4] = c, q[5] = d;
            t += 2;
        }
    mesh->vertex_count = nv;
    mesh->triangle_count = nt;
    mesh->faces_read = nt;
    return 0;
}

int rtk_mesh_procedural_name(const char *name, size_t *triangles)
{
    static const char prefix[] = "procedural:";
    if (strncmp(name, prefix, sizeof prefix - 1))
        return 0;
    const char *s = name + sizeof prefix - 1;
    char *end;
    const double v = strtod(s, &end);
    double scale = 1.0;
    if (*end == 'k')
        scale = 1e3, end++;
    else if (*end == 'M')
        scale = 1e6, end++;
    if (end == s || *end || !(v * scale >= 2.0) || v * scale > 2147483648.0)
        return 0;
    *triangles = (size_t)(v * scale);
    return 1;
}

static int edge_cmp(const void *x, const void *y)
{
    const rtk_mesh_edge *p = x, *q = y;
    if (p->a != q->a)
        return p->a < q->a ? -1 : 1;
    if (p->b != q->b)
        return p->b < q->b ? -1 : 1;
    return p->tri < q->tri ? -1 : p->tri > q->tri;
}

size_t rtk_mesh_shared_edges(const rtk_mesh *m, int distinct, rtk_mesh_edge **out)
{
    const size_t nt = m->triangle_count;
    rtk_mesh_edge *e = *out = malloc(3 * nt * sizeof *e + 1);
    if (!e)
        return 0;
    for (size_t t = 0; t < nt; t++)
        for (int k = 0; k < 3; k++) {
            const uint32_t a = m->indices[3 * t + (size_t)k], b = m->indices[3 * t + (size_t)(k + 1) % 3];
            e[3 * t + (size_t)k] = (rtk_mesh_edge){a < b ? a : b, a < b ? b : a, (uint32_t)t};
        }
    qsort(e, 3 * nt, sizeof *e, edge_cmp);
    size_t pairs = 0;
    for (size_t i = 0; i + 1 < 3 * nt; i++) {
        const int starts = i == 0 || e[i - 1].a != e[i].a || e[i - 1].b != e[i].b;
        const int two = e[i + 1].a == e[i].a && e[i + 1].b == e[i].b &&
                        (i + 2 >= 3 * nt || e[i + 2].a != e[i].a || e[i + 2].b != e[i].b);
        if (starts && two && (!distinct || e[i].a != e[i].b))
            e[pairs++] = e[i], e[pairs++] = e[i + 1];
    }
    return pairs;
}
