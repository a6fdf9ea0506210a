/* Rays aimed at points of edges shared by two triangles (the accuracy and
 * features sections), and the mesh as quads. */
#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "bench_internal.h"

/* ---- edge rays (accuracy) ---- */

/* The corner k of triangle t whose edge to corner k + 1 joins a and b
 * (either way round), or -1. */
static int edge_corner(const rtk_mesh *m, uint32_t t, uint32_t a, uint32_t b)
{
    for (int k = 0; k < 3; k++) {
        const uint32_t x = m->indices[3 * t + k], y = m->indices[3 * t + (k + 1) % 3];
        if ((x == a && y == b) || (x == b && y == a))
            return k;
    }
    return -1;
}

int quads_make(const rtk_mesh *m, quad_list *out)
{
    const size_t nt = m->triangle_count;
    rtk_mesh_edge *e;
    const size_t pairs = rtk_mesh_shared_edges(m, 0, &e);
    uint64_t *across = malloc((nt ? 3 * nt : 1) * sizeof *across); /* the edge 3 t + k's other side, or ~0 */
    unsigned char *used = calloc(nt ? nt : 1, 1);
    out->q = malloc((nt ? nt : 1) * 4 * sizeof *out->q);
    out->n = out->paired = 0;
    if (!e || !across || !used || !out->q) {
        free(e), free(across), free(used), free(out->q);
        out->q = NULL;
        return 1;
    }
    for (size_t h = 0; h < 3 * nt; h++)
        across[h] = ~0ull;
    for (size_t i = 0; i < pairs; i += 2) {
        const uint32_t t1 = e[i].tri, t2 = e[i + 1].tri;
        const uint64_t h1 = 3ull * t1 + (uint64_t)edge_corner(m, t1, e[i].a, e[i].b),
                       h2 = 3ull * t2 + (uint64_t)edge_corner(m, t2, e[i].a, e[i].b);
        across[h1] = h2;
        across[h2] = h1;
    }
    for (size_t t = 0; t < nt; t++) {
        if (used[t])
            continue;
        const uint32_t *x = &m->indices[3 * t];
        uint32_t *q = &out->q[4 * out->n++];
        used[t] = 1;
        q[0] = x[0], q[1] = x[1], q[2] = x[2], q[3] = x[2];
        for (int k = 0; k < 3; k++) {
            const uint64_t o = across[3 * t + (size_t)k];
            if (o == ~0ull || used[o / 3])
                continue;
            /* the edge x[k] -> x[k+1] is the other's x[k+1] -> x[k] (if
             * the two face the same way): the quad x[k+2] x[k] y x[k+1] */
            const uint32_t *y = &m->indices[o - o % 3];
            const uint32_t ok = (uint32_t)(o % 3);
            if (y[ok] != x[(k + 1) % 3])
                continue;
            q[0] = x[(k + 2) % 3], q[1] = x[k], q[2] = y[(ok + 2) % 3], q[3] = x[(k + 1) % 3];
            used[o / 3] = 1;
            out->paired++;
            break;
        }
    }
    free(e), free(across), free(used);
    return 0;
}

/* Whether triangle t runs along its edge a -> b (else b -> a). */
static int runs_forward(const rtk_mesh *m, uint32_t t, uint32_t a, uint32_t b)
{
    for (int k = 0; k < 3; k++)
        if (m->indices[3 * t + k] == a && m->indices[3 * t + (k + 1) % 3] == b)
            return 1;
    return 0;
}

/* Up to `want` rays, each aimed at a random point of an edge shared by
 * exactly two triangles of non-zero area, from a distance of a fifth of
 * the mesh's size, in a direction that meets both triangles' planes from
 * their front (cosine at least 0.3 with each normal, taken consistently
 * across the edge).  Each ray's direction is its point minus its origin:
 * the point is at t = 1. */
size_t make_edge_rays(const rtk_mesh *m, size_t want, rayset *set)
{
    set->rays = NULL;
    set->pair = NULL;
    set->n = 0;
    rtk_mesh_edge *e;
    const size_t pairs = rtk_mesh_shared_edges(m, 1, &e);
    if (!e)
        return 0;
    float lo[3], hi[3];
    const float diag = rtk_mesh_bounds(m, lo, hi);
    set->rays = calloc(want ? want : 1, sizeof(rtk_ray));
    set->pair = calloc(want ? want : 1, sizeof *set->pair);
    set->n = 0;
    for (size_t tries = 0; set->rays && set->pair && pairs >= 2 && set->n < want && tries < 20 * want; tries++) {
        const size_t p = (size_t)(rnd() * (float)(pairs / 2)) % (pairs / 2) * 2;
        const uint32_t a = e[p].a, b = e[p].b, t1 = e[p].tri, t2 = e[p + 1].tri;
        double n1[3], n2[3];
        tri_normal(m, t1, n1);
        tri_normal(m, t2, n2);
        /* consistently oriented neighbours run along the edge in opposite
         * directions; otherwise turn the second normal round */
        const double s2 = runs_forward(m, t1, a, b) != runs_forward(m, t2, a, b) ? 1.0 : -1.0;
        double d[3], dl = 0;
        for (int k = 0; k < 3; k++) {
            n2[k] *= s2;
            d[k] = -(n1[k] + n2[k]) + 0.8 * (2.0 * rnd() - 1.0);
            dl += d[k] * d[k];
        }
        dl = sqrt(dl);
        if (!(dl > 0))
            continue;
        double c1 = 0, c2 = 0;
        for (int k = 0; k < 3; k++) {
            d[k] /= dl;
            c1 += d[k] * n1[k];
            c2 += d[k] * n2[k];
        }
        if (!(c1 <= -0.3 && c2 <= -0.3))
            continue;
        const float u = rnd();
        const float *va = &m->vertices[3 * a], *vb = &m->vertices[3 * b];
        float target[3], org[3], dir[3];
        for (int k = 0; k < 3; k++) {
            target[k] = va[k] + u * (vb[k] - va[k]);
            org[k] = target[k] - (float)d[k] * 0.2f * diag;
            dir[k] = target[k] - org[k];
        }
        set->rays[set->n] = (rtk_ray){.org_x = org[0], .org_y = org[1], .org_z = org[2], .dir_x = dir[0],
                                      .dir_y = dir[1], .dir_z = dir[2], .tfar = INFINITY, .mask = ~0u};
        set->pair[set->n][0] = t1;
        set->pair[set->n][1] = t2;
        set->n++;
    }
    free(e);
    set->n &= ~(size_t)15;
    return set->n;
}

/* Rays that leaked: missed, or hit beyond their edge point (t > 1 + 1e-4). */
size_t count_leaks(const render_tracer *t, const rayset *set)
{
    size_t leaks = 0;
    for (size_t i = 0; i < set->n; i++) {
        _Alignas(16) rtk_rayhit rh = {.ray = set->rays[i], .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
        t->intersect1(t->scene, &rh);
        leaks += rh.hit.geomID == RTK_INVALID_GEOMETRY_ID || rh.ray.tfar > 1.0f + 1e-4f;
    }
    return leaks;
}

/* Rays that hit both triangles of their edge, through a scene built with
 * bench_collect. */
size_t count_double_hits(const render_tracer *t, const rayset *set)
{
    size_t twice = 0;
    for (size_t i = 0; i < set->n; i++) {
        _Alignas(16) rtk_rayhit rh = {.ray = set->rays[i], .hit = {.geomID = RTK_INVALID_GEOMETRY_ID}};
        bench_seen.n = 0;
        t->intersect1(t->scene, &rh);
        int both = 0;
        for (unsigned k = 0; k < bench_seen.n; k++)
            both += bench_seen.prim[k] == set->pair[i][0] || bench_seen.prim[k] == set->pair[i][1];
        twice += both == 2;
    }
    return twice;
}
