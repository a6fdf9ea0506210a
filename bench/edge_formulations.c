/*
 * Ray-triangle formulations at shared edges, outside the library: how
 * often the two triangles of an edge both accept (a double hit) or both
 * reject (a leak, unless another triangle is in the way) a ray aimed at a
 * point of the edge.  Rays as rtktool bench's accuracy section makes them
 * (tools/bench/edges.c: a random point of a random edge shared by exactly
 * two triangles, from a fifth of the mesh's size away, meeting both
 * triangles' fronts), each formulation in float without FMA (the build's
 * -ffp-contract=off) but Embree's fused one (fmaf), per million rays:
 *
 *   build/bin/edge_formulations ../shared/meshes/dragon.ply [RAYS] [--hubs | --lowest]
 *
 * --hubs first turns each triangle's vertices round (keeping the winding)
 * so that neighbours start at the same vertex where a greedy choice can
 * (which the Embree form needs to compute an edge the same way in both
 * triangles); --lowest turns each to start at its lowest corner (no
 * adjacency needed).  For docs/benchmarks/accuracy.md, "Shared edges"; not a speed
 * benchmark, and the library's own kernels are measured by rtktool bench.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "geometry/triangle.h"
#include "mesh_import.h"
#include "mesh_tools.h"

static uint64_t rng_state = 88172645463325252ull;
static float rnd(void)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (float)(rng_state >> 40) * 0x1p-24f;
}

/* ---- the formulations: 1 when the ray (t >= 0) hits the triangle v ---- */

/* rtk 0.2's default: Moeller-Trumbore, U = s . (d x e2), V = d . (s x e1);
 * U, V, T (times |det|), |det| and the edges in *r, and whether it hits. */
typedef struct mt {
    float U, V, T, ad;
    float e1[3], e2[3];
} mt;

static int mt_test(const float *o, const float *d, const float v[3][3], mt *r)
{
    float *e1 = r->e1, *e2 = r->e2;
    for (int k = 0; k < 3; k++)
        e1[k] = v[1][k] - v[0][k], e2[k] = v[2][k] - v[0][k];
    const float px = d[1] * e2[2] - d[2] * e2[1], py = d[2] * e2[0] - d[0] * e2[2], pz = d[0] * e2[1] - d[1] * e2[0];
    const float det = e1[0] * px + e1[1] * py + e1[2] * pz;
    const float sx = o[0] - v[0][0], sy = o[1] - v[0][1], sz = o[2] - v[0][2];
    const float qx = sy * e1[2] - sz * e1[1], qy = sz * e1[0] - sx * e1[2], qz = sx * e1[1] - sy * e1[0];
    r->ad = fabsf(det);
    r->U = rtk_xor_sign(sx * px + sy * py + sz * pz, det);
    r->V = rtk_xor_sign(d[0] * qx + d[1] * qy + d[2] * qz, det);
    r->T = rtk_xor_sign(e2[0] * qx + e2[1] * qy + e2[2] * qz, det);
    return r->U >= 0 && r->V >= 0 && r->U + r->V <= r->ad && r->ad >= FLT_MIN && r->T >= 0;
}

static int f_rtk(const float *o, const float *d, const float v[3][3])
{
    mt r;
    return mt_test(o, d, v, &r);
}

/* The first nonzero component's sign of e: which of an edge's two
 * triangles takes a ray exactly on it (ties, below). */
static int edge_key(const float *e)
{
    return e[0] != 0 ? e[0] > 0 : e[1] != 0 ? e[1] > 0 : e[2] > 0;
}

/* a x b and a . b in float, or as Embree's AVX2 build computes them
 * (fused): each cross product term a*b - c*d as one fused a*b - round(c*d),
 * each dot product as fused multiply-adds from its last term. */
static void cross3(const float *a, const float *b, float *c, int fused)
{
    if (fused) {
        c[0] = fmaf(a[1], b[2], -(a[2] * b[1]));
        c[1] = fmaf(a[2], b[0], -(a[0] * b[2]));
        c[2] = fmaf(a[0], b[1], -(a[1] * b[0]));
    } else {
        c[0] = a[1] * b[2] - a[2] * b[1];
        c[1] = a[2] * b[0] - a[0] * b[2];
        c[2] = a[0] * b[1] - a[1] * b[0];
    }
}

static float dot3(const float *a, const float *b, int fused)
{
    return fused ? fmaf(a[0], b[0], fmaf(a[1], b[1], a[2] * b[2])) : a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* Embree 3's default form: R = (v0 - o) x d, U = R . e2, V = R . e1 with
 * e1 = v0 - v1 and the normal e2 x e1 (rtk's default test, to the bit,
 * unfused; Embree's own, fused, where a ray is decided by den != 0 rather
 * than |den| >= FLT_MIN): two triangles that reach their shared edge from
 * the same v0 compute it from the same floats, negated.  ties: an edge
 * function exactly zero is given to one of its triangles by the edge's
 * direction, walked in the triangle's winding (v0 -> v1 is -e1). */
static int f_embree(const float *o, const float *d, const float v[3][3], int ties, int fused)
{
    float e1[3], e2[3], c[3], r[3], n[3];
    for (int k = 0; k < 3; k++)
        e1[k] = v[0][k] - v[1][k], e2[k] = v[2][k] - v[0][k], c[k] = v[0][k] - o[k];
    cross3(c, d, r, fused);
    cross3(e2, e1, n, fused);
    const float den = dot3(n, d, fused), ad = fabsf(den);
    const float U = rtk_xor_sign(dot3(r, e2, fused), den), V = rtk_xor_sign(dot3(r, e1, fused), den);
    const float T = rtk_xor_sign(dot3(n, c, fused), den);
    const float ne1[3] = {-e1[0], -e1[1], -e1[2]};
    const int u_ok = ties ? U > 0 || (U == 0 && edge_key(e2)) : U >= 0;
    const int v_ok = ties ? V > 0 || (V == 0 && !edge_key(ne1)) : V >= 0;
    return (fused ? den != 0 : ad >= FLT_MIN) && u_ok && v_ok && U + V <= ad && T >= 0;
}

/* rtk's default test as its kernels compute it (traverse_leaf.h:
 * e1 = v1 - v0, V's sign turned by det's and one more), its edge tests
 * either >= 0 (signs 0; what f_embree's unfused form decides too) or on
 * the sign bits (signs 1): an exactly zero edge function counts as inside
 * only as +0.0.  Two triangles that reach their shared edge from the same
 * v0 hold it as U in one and V in the other, computed from the same floats
 * and negated by the sign turn, so on the sign bits exactly one of them
 * takes a zero. */
static int f_rtk_embree_form(const float *o, const float *d, const float v[3][3], int signs)
{
    float e1[3], e2[3], c[3], r[3], n[3];
    for (int k = 0; k < 3; k++)
        e1[k] = v[1][k] - v[0][k], e2[k] = v[2][k] - v[0][k], c[k] = v[0][k] - o[k];
    cross3(e1, e2, n, 0);
    const float det = dot3(n, d, 0), ad = fabsf(det);
    const float T = rtk_xor_sign(dot3(n, c, 0), det);
    cross3(c, d, r, 0);
    const float U = rtk_xor_sign(dot3(r, e2, 0), det), V = rtk_xor_sign(dot3(r, e1, 0), -det);
    const int u_ok = signs ? !signbit(U) : U >= 0, v_ok = signs ? !signbit(V) : V >= 0;
    return ad >= FLT_MIN && u_ok && v_ok && U + V <= ad && T >= 0;
}

/* The watertight test (every rtk kernel's robust intersector). */
static int f_watertight(const float *o, const float *d, const float v[3][3])
{
    rtk_watertight_ray w;
    rtk_watertight_ray_init(d, &w);
    rtk_tri_hit h;
    return rtk_triangle_intersect_watertight(o, &w, 0.0f, INFINITY, v[0], v[1], v[2], &h);
}

/* Moeller-Trumbore with a margin: a ray inside or outside by more than
 * margin |det| is decided by it, one nearer an edge by the watertight test
 * on the vertices as a triangle4 leaf gives them back (v0, v0 + e1,
 * v0 + e2: v1 and v2 themselves wherever the subtraction was exact). */
static size_t hybrid_tests, hybrid_border;
static int f_hybrid(const float *o, const float *d, const float v[3][3], float margin)
{
    mt r;
    mt_test(o, d, v, &r);
    const float U = r.U, V = r.V, T = r.T, ad = r.ad, *e1 = r.e1, *e2 = r.e2;
    const float m = margin * ad;
    hybrid_tests++;
    if (!(U >= -m && V >= -m && U + V <= ad + m && ad >= FLT_MIN && T >= 0))
        return 0;
    if (U >= m && V >= m && U + V <= ad - m)
        return 1;
    hybrid_border++;
    float back[3][3];
    for (int k = 0; k < 3; k++)
        back[0][k] = v[0][k], back[1][k] = v[0][k] + e1[k], back[2][k] = v[0][k] + e2[k];
    return f_watertight(o, d, (const float(*)[3])back);
}

/* ---- the mesh ---- */

/* Each triangle's first corner (0, 1 or 2): greedily, vertices in index
 * order become hubs where none of their triangles has one yet, and each
 * triangle starts at its hub (or at corner 0 without one). */
static unsigned char *hub_corners(const rtk_mesh *m, size_t *without)
{
    const size_t nt = m->triangle_count, nv = m->vertex_count;
    unsigned char *first = calloc(nt ? nt : 1, 1);
    uint32_t *start = calloc(nv + 1, sizeof *start), *fill = malloc((nv + 1) * sizeof *fill);
    uint32_t *tris = malloc((nt ? 3 * nt : 1) * sizeof *tris);
    signed char *has = malloc(nt ? nt : 1);
    if (!first || !start || !fill || !tris || !has) {
        fprintf(stderr, "out of memory\n");
        exit(1);
    }
    for (size_t i = 0; i < 3 * nt; i++)
        start[m->indices[i] + 1]++;
    for (size_t i = 0; i < nv; i++)
        start[i + 1] += start[i];
    memcpy(fill, start, (nv + 1) * sizeof *fill);
    for (size_t i = 0; i < 3 * nt; i++)
        tris[fill[m->indices[i]]++] = (uint32_t)(i / 3);
    memset(has, -1, nt);
    for (uint32_t w = 0; w < nv; w++) {
        int free_fan = 1;
        for (uint32_t j = start[w]; j < start[w + 1] && free_fan; j++)
            free_fan = has[tris[j]] < 0;
        if (!free_fan)
            continue;
        for (uint32_t j = start[w]; j < start[w + 1]; j++)
            for (int k = 0; k < 3; k++)
                if (m->indices[3 * (size_t)tris[j] + (size_t)k] == w)
                    has[tris[j]] = (signed char)k;
    }
    *without = 0;
    for (size_t t = 0; t < nt; t++) {
        *without += has[t] < 0;
        first[t] = has[t] < 0 ? 0 : (unsigned char)has[t];
    }
    free(start), free(fill), free(tris), free(has);
    return first;
}

/* Each triangle's first corner by a rule of its own: the corner whose
 * coordinates are lowest in lexicographic order (x, then y, then z), so
 * that two triangles of an edge start at the same end of it whenever that
 * end is the lowest corner of both, with no adjacency to look up. */
static unsigned char *lowest_corners(const rtk_mesh *m)
{
    const size_t nt = m->triangle_count;
    unsigned char *first = calloc(nt ? nt : 1, 1);
    if (!first) {
        fprintf(stderr, "out of memory\n");
        exit(1);
    }
    for (size_t t = 0; t < nt; t++) {
        int best = 0;
        for (int k = 1; k < 3; k++) {
            const float *a = &m->vertices[3 * (size_t)m->indices[3 * t + (size_t)k]];
            const float *b = &m->vertices[3 * (size_t)m->indices[3 * t + (size_t)best]];
            if (a[0] < b[0] || (a[0] == b[0] && (a[1] < b[1] || (a[1] == b[1] && a[2] < b[2]))))
                best = k;
        }
        first[t] = (unsigned char)best;
    }
    return first;
}

static void corners(const rtk_mesh *m, uint32_t t, int first, float v[3][3])
{
    for (int j = 0; j < 3; j++)
        memcpy(v[j], &m->vertices[3 * (size_t)m->indices[3 * (size_t)t + (size_t)((j + first) % 3)]], sizeof v[j]);
}

static void unit_normal(const float v[3][3], double n[3])
{
    double a[3], b[3];
    for (int k = 0; k < 3; k++)
        a[k] = (double)v[1][k] - v[0][k], b[k] = (double)v[2][k] - v[0][k];
    n[0] = a[1] * b[2] - a[2] * b[1];
    n[1] = a[2] * b[0] - a[0] * b[2];
    n[2] = a[0] * b[1] - a[1] * b[0];
    const double l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (int k = 0; k < 3 && l > 0; k++)
        n[k] /= l;
}

enum { F_RTK, F_EMBREE, F_RTK_EMBREE, F_RTK_SIGNS, F_EMBREE_TIES, F_EMBREE_FMA, F_EMBREE_FMA_TIES, F_WATERTIGHT, F_HYBRID_12, F_HYBRID_16, F_COUNT };
static const char *const names[F_COUNT] = {"Moeller-Trumbore, rtk 0.2 form", "Embree 3 default form",
                                           "rtk's kernels (Embree form)", "rtk's kernels, zeros by sign bit",
                                           "Embree form, ties by edge direction", "Embree form, fused (AVX2)",
                                           "Embree form, fused, ties", "watertight (rtk robust)",
                                           "hybrid, margin 2^-12", "hybrid, margin 2^-16"};

static int decide(int f, const float *o, const float *d, const float v[3][3])
{
    switch (f) {
    case F_RTK:
        return f_rtk(o, d, v);
    case F_EMBREE:
        return f_embree(o, d, v, 0, 0);
    case F_RTK_EMBREE:
        return f_rtk_embree_form(o, d, v, 0);
    case F_RTK_SIGNS:
        return f_rtk_embree_form(o, d, v, 1);
    case F_EMBREE_TIES:
        return f_embree(o, d, v, 1, 0);
    case F_EMBREE_FMA:
        return f_embree(o, d, v, 0, 1);
    case F_EMBREE_FMA_TIES:
        return f_embree(o, d, v, 1, 1);
    case F_WATERTIGHT:
        return f_watertight(o, d, v);
    case F_HYBRID_12:
        return f_hybrid(o, d, v, 0x1p-12f);
    default:
        return f_hybrid(o, d, v, 0x1p-16f);
    }
}

int main(int argc, char **argv)
{
    size_t want = 200000;
    int hubs = 0, lowest = 0;
    const char *path = NULL;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--hubs"))
            hubs = 1;
        else if (!strcmp(argv[i], "--lowest"))
            lowest = 1;
        else if (!path)
            path = argv[i];
        else
            want = strtoul(argv[i], NULL, 10);
    }
    if (!path || !want) {
        fprintf(stderr, "usage: edge_formulations MESH [RAYS] [--hubs | --lowest]\n");
        return 2;
    }
    rtk_mesh m;
    char err[512];
    if (rtk_mesh_load(path, &m, err, sizeof err)) {
        fprintf(stderr, "edge_formulations: %s\n", err);
        return 1;
    }
    const size_t nt = m.triangle_count;
    rtk_mesh_edge *e;
    const size_t pairs = rtk_mesh_shared_edges(&m, 1, &e);
    if (!e) {
        fprintf(stderr, "out of memory\n");
        return 1;
    }
    if (pairs < 2) {
        fprintf(stderr, "edge_formulations: %s has no edge shared by two triangles\n", path);
        return 1;
    }
    size_t without = 0;
    unsigned char *first = hubs ? hub_corners(&m, &without) : lowest ? lowest_corners(&m) : calloc(nt ? nt : 1, 1);
    float lo[3], hi[3];
    const float diag = rtk_mesh_bounds(&m, lo, hi);
    size_t both[F_COUNT] = {0}, neither[F_COUNT] = {0}, n = 0, same_start = 0;
    for (size_t tries = 0; n < want && tries < 20 * want; tries++) {
        const size_t p = (size_t)(rnd() * (float)(pairs / 2)) % (pairs / 2) * 2;
        const uint32_t a = e[p].a, b = e[p].b, t1 = e[p].tri, t2 = e[p + 1].tri;
        float v1[3][3], v2[3][3];
        corners(&m, t1, first[t1], v1);
        corners(&m, t2, first[t2], v2);
        double n1[3], n2[3], dd[3], dl = 0, c1 = 0, c2 = 0;
        unit_normal(v1, n1);
        unit_normal(v2, n2);
        for (int k = 0; k < 3; k++) {
            dd[k] = -(n1[k] + n2[k]) + 0.8 * (2.0 * rnd() - 1.0);
            dl += dd[k] * dd[k];
        }
        dl = sqrt(dl);
        if (!(dl > 0))
            continue;
        for (int k = 0; k < 3; k++) {
            dd[k] /= dl;
            c1 += dd[k] * n1[k];
            c2 += dd[k] * n2[k];
        }
        if (!(c1 <= -0.3 && c2 <= -0.3))
            continue;
        const float u = rnd();
        const float *va = &m.vertices[3 * (size_t)a], *vb = &m.vertices[3 * (size_t)b];
        float o[3], d[3];
        for (int k = 0; k < 3; k++) {
            const float target = va[k] + u * (vb[k] - va[k]);
            o[k] = target - (float)dd[k] * 0.2f * diag;
            d[k] = target - o[k];
        }
        n++;
        const uint32_t s1 = m.indices[3 * (size_t)t1 + first[t1]], s2 = m.indices[3 * (size_t)t2 + first[t2]];
        same_start += s1 == s2 && (s1 == a || s1 == b);
        for (int f = 0; f < F_COUNT; f++) {
            const int h1 = decide(f, o, d, (const float(*)[3])v1), h2 = decide(f, o, d, (const float(*)[3])v2);
            both[f] += h1 && h2;
            neither[f] += !h1 && !h2;
        }
    }
    printf("%s: %zu rays at shared edges%s; edges whose two triangles start at the same end of it: %.1f%%\n", path,
           n, hubs     ? " (triangles turned to start at hubs)"
           : lowest ? " (triangles turned to start at their lowest corner)"
                    : "", n ? 100.0 * (double)same_start / (double)n : 0.0);
    if (hubs)
        printf("  (%zu of %zu triangles have no hub)\n", without, nt);
    printf("  %-38s %14s %14s\n", "per million rays", "both triangles", "neither");
    for (int f = 0; f < F_COUNT; f++)
        printf("  %-38s %14.0f %14.0f\n", names[f], n ? 1e6 * (double)both[f] / (double)n : 0.0,
               n ? 1e6 * (double)neither[f] / (double)n : 0.0);
    printf("  hybrid tests decided by the watertight test: %.1f%% of %zu (both margins)\n",
           hybrid_tests ? 100.0 * (double)hybrid_border / (double)hybrid_tests : 0.0, hybrid_tests);
    free(first);
    free(e);
    return 0;
}
