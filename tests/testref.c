/* The double-precision reference of test_instance and test_motion
 * (testlib.h: placed_ref), and the small mesh they use. */
#include <math.h>
#include <stdlib.h>

#include "testlib.h"

test_mesh test_ball(int r)
{
    const int R = r;
    test_mesh mesh = {0}, *m = &mesh;
    m->nv = (size_t)(R + 1) * (R + 1);
    m->nt = (size_t)2 * R * R;
    m->v = malloc(m->nv * 3 * sizeof *m->v);
    m->idx = malloc(m->nt * 3 * sizeof *m->idx);
    for (int j = 0; j <= R; j++)
        for (int i = 0; i <= R; i++) {
            const float th = 3.14159265f * (float)j / R, ph = 6.2831853f * (float)i / R;
            const float rad = 1.0f + 0.1f * sinf(5.0f * th) * cosf(3.0f * ph);
            float *p = m->v + 3 * ((size_t)j * (R + 1) + i);
            p[0] = rad * sinf(th) * cosf(ph);
            p[1] = rad * sinf(th) * sinf(ph);
            p[2] = rad * cosf(th);
        }
    size_t t = 0;
    for (int j = 0; j < R; j++)
        for (int i = 0; i < R; i++) {
            const uint32_t a = (uint32_t)(j * (R + 1) + i), b = a + 1, c = a + R + 1, d = c + 1;
            uint32_t *q = m->idx + 3 * t;
            q[0] = a, q[1] = b, q[2] = c, q[3] = b, q[4] = d, q[5] = c;
            t += 2;
        }
    return mesh;
}

placed *placed_add(placed_ref *r)
{
    if (r->n == r->cap) {
        r->cap = r->cap ? 2 * r->cap : 1024;
        r->t = realloc(r->t, r->cap * sizeof *r->t);
        assert_non_null(r->t);
    }
    return &r->t[r->n++];
}

void placed_normal(placed *p, const double o[3][3])
{
    const double e1[3] = {o[1][0] - o[0][0], o[1][1] - o[0][1], o[1][2] - o[0][2]};
    const double e2[3] = {o[2][0] - o[0][0], o[2][1] - o[0][1], o[2][2] - o[0][2]};
    p->n_obj[0] = e1[1] * e2[2] - e1[2] * e2[1];
    p->n_obj[1] = e1[2] * e2[0] - e1[0] * e2[2];
    p->n_obj[2] = e1[0] * e2[1] - e1[1] * e2[0];
}

/* Moeller-Trumbore in double: t, and the smallest barycentric (how far the
 * hit is from an edge); 0 when missed. */
static int tri_hit(const placed *p, const double o[3], const double d[3], double *t, double *margin)
{
    const double *v0 = p->v[0];
    const double e1[3] = {p->v[1][0] - v0[0], p->v[1][1] - v0[1], p->v[1][2] - v0[2]};
    const double e2[3] = {p->v[2][0] - v0[0], p->v[2][1] - v0[1], p->v[2][2] - v0[2]};
    const double pv[3] = {d[1] * e2[2] - d[2] * e2[1], d[2] * e2[0] - d[0] * e2[2], d[0] * e2[1] - d[1] * e2[0]};
    const double det = e1[0] * pv[0] + e1[1] * pv[1] + e1[2] * pv[2];
    if (det == 0.0)
        return 0;
    const double tv[3] = {o[0] - v0[0], o[1] - v0[1], o[2] - v0[2]};
    const double u = (tv[0] * pv[0] + tv[1] * pv[1] + tv[2] * pv[2]) / det;
    const double q[3] = {tv[1] * e1[2] - tv[2] * e1[1], tv[2] * e1[0] - tv[0] * e1[2], tv[0] * e1[1] - tv[1] * e1[0]};
    const double v = (d[0] * q[0] + d[1] * q[1] + d[2] * q[2]) / det;
    const double tt = (e2[0] * q[0] + e2[1] * q[1] + e2[2] * q[2]) / det;
    const double w = 1.0 - u - v;
    *margin = fmin(fmin(u, v), w);
    *t = tt;
    return *margin >= 0.0;
}

/* The closest placed triangle hit within [tnear, tfar]; -1 for none. */
static long ref_closest_placed(const placed_ref *r, const rtk_ray *ray, double *t_out, double *margin_out)
{
    const double o[3] = {ray->org_x, ray->org_y, ray->org_z}, d[3] = {ray->dir_x, ray->dir_y, ray->dir_z};
    long best = -1;
    double bt = INFINITY, bm = 0;
    for (size_t k = 0; k < r->n; k++) {
        double t, m;
        if (tri_hit(&r->t[k], o, d, &t, &m) && t >= ray->tnear && t <= ray->tfar && t < bt) {
            bt = t;
            bm = m;
            best = (long)k;
        }
    }
    *t_out = bt;
    *margin_out = bm;
    return best;
}

static long ref_find(const placed_ref *r, uint32_t inst, uint32_t geom, uint32_t prim)
{
    for (size_t k = 0; k < r->n; k++)
        if (r->t[k].inst == inst && r->t[k].geom == geom && r->t[k].prim == prim)
            return (long)k;
    return -1;
}

void check_ray_placed(rtk_scene s, const placed_ref *r, const rtk_ray ray, int i, double tol, int *hits,
                      int *excused)
{
    rtk_rayhit rh = {.ray = ray};
    rh.hit.geomID = rh.hit.instID = RTK_INVALID_GEOMETRY_ID;
    assert_int_equal(rtk_intersect1(s, &rh), RTK_OK);
    rtk_ray oc = ray;
    assert_int_equal(rtk_occluded1(s, &oc), RTK_OK);
    double t_ref, margin;
    const long want = ref_closest_placed(r, &ray, &t_ref, &margin);
    const int got = rh.hit.geomID != RTK_INVALID_GEOMETRY_ID;
    if ((want >= 0) != got || (oc.tfar == -INFINITY) != (want >= 0)) {
        if (want >= 0 && margin < tol) {
            (*excused)++;
            return;
        }
        if (got) { /* rtk's triangle: its own edge margin */
            const long k = ref_find(r, rh.hit.instID, rh.hit.geomID, rh.hit.primID);
            const double ro[3] = {ray.org_x, ray.org_y, ray.org_z}, rd[3] = {ray.dir_x, ray.dir_y, ray.dir_z};
            double t2, m2;
            tri_hit(&r->t[k], ro, rd, &t2, &m2);
            if (m2 > -tol && m2 < tol) {
                (*excused)++;
                return;
            }
        }
        fail_msg("ray %d (%a %a %a -> %a %a %a, time %g): rtk %s (inst %u geom %u prim %u, occluded %d), "
                 "reference %s (margin %g)",
                 i, ray.org_x, ray.org_y, ray.org_z, ray.dir_x, ray.dir_y, ray.dir_z, ray.time, got ? "hit" : "missed",
                 rh.hit.instID, rh.hit.geomID, rh.hit.primID, oc.tfar == -INFINITY, want >= 0 ? "hit" : "missed",
                 margin);
    }
    if (!got)
        return;
    (*hits)++;
    const placed *p = &r->t[want];
    if (fabs(rh.ray.tfar - t_ref) > tol * (t_ref + 1.0))
        fail_msg("ray %d: t %.9g, reference %.9g", i, rh.ray.tfar, t_ref);
    if (p->inst != rh.hit.instID || p->geom != rh.hit.geomID || p->prim != rh.hit.primID) {
        /* a tie: rtk's triangle must be hit as near */
        const long k = ref_find(r, rh.hit.instID, rh.hit.geomID, rh.hit.primID);
        if (k < 0)
            fail_msg("ray %d: rtk reports inst %u geom %u prim %u, which does not exist", i, rh.hit.instID,
                     rh.hit.geomID, rh.hit.primID);
        const double ro[3] = {ray.org_x, ray.org_y, ray.org_z}, rd[3] = {ray.dir_x, ray.dir_y, ray.dir_z};
        double t2, m2;
        tri_hit(&r->t[k], ro, rd, &t2, &m2);
        if (!(fabs(t2 - t_ref) <= tol * (t_ref + 1.0) || margin < tol || fabs(m2) < tol))
            fail_msg("ray %d: rtk hit inst %u geom %u prim %u at %.9g, reference inst %u geom %u prim %u at %.9g",
                     i, rh.hit.instID, rh.hit.geomID, rh.hit.primID, rh.ray.tfar, p->inst, p->geom, p->prim,
                     t_ref);
        (*excused)++;
        return;
    }
    /* the normal, in the innermost object space */
    const double ng[3] = {rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z};
    const double dot = ng[0] * p->n_obj[0] + ng[1] * p->n_obj[1] + ng[2] * p->n_obj[2];
    const double len = sqrt(ng[0] * ng[0] + ng[1] * ng[1] + ng[2] * ng[2]) *
                       sqrt(p->n_obj[0] * p->n_obj[0] + p->n_obj[1] * p->n_obj[1] + p->n_obj[2] * p->n_obj[2]);
    if (!(dot > 0.9999 * len))
        fail_msg("ray %d: Ng (%g %g %g) is not the object-space normal", i, ng[0], ng[1], ng[2]);
}
