/* Closed procedural meshes and rays aimed at their vertices and edges; see closed_mesh.h. */
#include "closed_mesh.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static const double pi = 3.14159265358979323846;

double rtk_closed_depth(const rtk_closed_mesh *m, const float p[3])
{
    const double x = p[0] - m->c[0], y = p[1] - m->c[1], z = p[2] - m->c[2];
    switch (m->shape) {
    case RTK_SOLID_SPHERE: return m->a - sqrt(x * x + y * y + z * z);
    case RTK_SOLID_TORUS: {
        const double q = sqrt(x * x + y * y) - m->a;
        return m->b - sqrt(q * q + z * z);
    }
    case RTK_SOLID_CYLINDER: return fmin(m->a - sqrt(x * x + y * y), m->b - fabs(z));
    default: return m->a - fmax(fabs(x), fmax(fabs(y), fabs(z)));
    }
}

static int mesh_alloc(rtk_closed_mesh *m, size_t nv, size_t nt)
{
    m->mesh.vertices = calloc(3 * nv + 1, sizeof *m->mesh.vertices);
    m->mesh.indices = calloc(3 * nt + 1, sizeof *m->mesh.indices);
    m->normal = calloc(nv + 1, sizeof *m->normal);
    m->mesh.vertex_count = nv;
    m->mesh.triangle_count = 0;
    if (m->mesh.vertices && m->mesh.indices && m->normal)
        return 0;
    rtk_closed_free(m);
    return 1;
}

static void add_tri(rtk_closed_mesh *m, uint32_t a, uint32_t b, uint32_t c)
{
    uint32_t *t = m->mesh.indices + 3 * m->mesh.triangle_count++;
    t[0] = a, t[1] = b, t[2] = c;
}

static void add_vertex(rtk_closed_mesh *m, size_t i, double x, double y, double z, double nx, double ny, double nz)
{
    float *v = m->mesh.vertices + 3 * i;
    v[0] = (float)x, v[1] = (float)y, v[2] = (float)z;
    const double l = sqrt(nx * nx + ny * ny + nz * nz);
    m->normal[i][0] = (float)(nx / l), m->normal[i][1] = (float)(ny / l), m->normal[i][2] = (float)(nz / l);
}

static void set_solid(rtk_closed_mesh *m, const char *name, rtk_solid shape, const double c[3], double a, double b)
{
    memset(m, 0, sizeof *m);
    m->name = name;
    m->shape = shape;
    m->c[0] = c[0], m->c[1] = c[1], m->c[2] = c[2];
    m->a = a, m->b = b;
}

int rtk_closed_sphere(const double c[3], double r, int seg, int rings, rtk_closed_mesh *m)
{
    set_solid(m, "sphere", RTK_SOLID_SPHERE, c, r, 0);
    if (mesh_alloc(m, (size_t)seg * (size_t)rings + 2, 2 * (size_t)seg * (size_t)rings))
        return 1;
    for (int i = 0; i < rings; i++)
        for (int j = 0; j < seg; j++) {
            const double th = pi * (i + 1) / (rings + 1), ph = 2 * pi * j / seg;
            const double n[3] = {sin(th) * cos(ph), sin(th) * sin(ph), cos(th)};
            add_vertex(m, (size_t)i * seg + j, c[0] + r * n[0], c[1] + r * n[1], c[2] + r * n[2], n[0], n[1], n[2]);
        }
    const uint32_t top = (uint32_t)(seg * rings), bottom = top + 1;
    add_vertex(m, top, c[0], c[1], c[2] + r, 0, 0, 1);
    add_vertex(m, bottom, c[0], c[1], c[2] - r, 0, 0, -1);
    for (int j = 0; j < seg; j++) {
        const uint32_t j1 = (uint32_t)((j + 1) % seg);
        add_tri(m, top, (uint32_t)j, j1);
        const uint32_t last = (uint32_t)((rings - 1) * seg);
        add_tri(m, bottom, last + j1, last + (uint32_t)j);
        for (int i = 0; i + 1 < rings; i++) {
            const uint32_t a = (uint32_t)(i * seg + j), b = (uint32_t)(i * seg) + j1;
            add_tri(m, a, a + (uint32_t)seg, b);
            add_tri(m, b, a + (uint32_t)seg, b + (uint32_t)seg);
        }
    }
    m->closed_triangles = m->mesh.triangle_count;
    return 0;
}

int rtk_closed_torus(const double c[3], double R, double r, int nu, int nv, rtk_closed_mesh *m)
{
    set_solid(m, "torus", RTK_SOLID_TORUS, c, R, r);
    if (mesh_alloc(m, (size_t)nu * (size_t)nv, 2 * (size_t)nu * (size_t)nv))
        return 1;
    for (int i = 0; i < nu; i++)
        for (int j = 0; j < nv; j++) {
            const double u = 2 * pi * i / nu, w = 2 * pi * j / nv;
            const double n[3] = {cos(w) * cos(u), cos(w) * sin(u), sin(w)};
            add_vertex(m, (size_t)i * nv + j, c[0] + (R + r * cos(w)) * cos(u), c[1] + (R + r * cos(w)) * sin(u),
                       c[2] + r * sin(w), n[0], n[1], n[2]);
        }
    for (int i = 0; i < nu; i++)
        for (int j = 0; j < nv; j++) {
            const uint32_t a = (uint32_t)(i * nv + j), b = (uint32_t)(((i + 1) % nu) * nv + j);
            const uint32_t a1 = (uint32_t)(i * nv + (j + 1) % nv), b1 = (uint32_t)(((i + 1) % nu) * nv + (j + 1) % nv);
            add_tri(m, a, b, a1);
            add_tri(m, a1, b, b1);
        }
    m->closed_triangles = m->mesh.triangle_count;
    return 0;
}

int rtk_closed_box(const double c[3], double h, int n, rtk_closed_mesh *m)
{
    set_solid(m, "box", RTK_SOLID_BOX, c, h, 0);
    const size_t side = (size_t)n + 1;
    if (mesh_alloc(m, side * side * side, 12 * (size_t)n * (size_t)n))
        return 1;
    /* every lattice point gets an index; only the surface ones are used */
    for (size_t i = 0; i < side; i++)
        for (size_t j = 0; j < side; j++)
            for (size_t k = 0; k < side; k++) {
                const double p[3] = {-1 + 2.0 * i / n, -1 + 2.0 * j / n, -1 + 2.0 * k / n};
                add_vertex(m, (i * side + j) * side + k, c[0] + h * p[0], c[1] + h * p[1], c[2] + h * p[2], p[0],
                           p[1], p[2]);
            }
#define LAT(i, j, k) ((uint32_t)(((size_t)(i) * side + (size_t)(j)) * side + (size_t)(k)))
    for (int axis = 0; axis < 3; axis++)
        for (int s = 0; s < 2; s++)
            for (int a = 0; a < n; a++)
                for (int b = 0; b < n; b++) {
                    uint32_t q[4];
                    const int corner[4][2] = {{a, b}, {a + 1, b}, {a + 1, b + 1}, {a, b + 1}};
                    for (int k = 0; k < 4; k++) {
                        int p[3];
                        p[axis] = s * n;
                        p[(axis + 1) % 3] = corner[k][0];
                        p[(axis + 2) % 3] = corner[k][1];
                        q[k] = LAT(p[0], p[1], p[2]);
                    }
                    /* outward: the face at s = 0 runs the other way round */
                    if (!s) {
                        const uint32_t t = q[1];
                        q[1] = q[3], q[3] = t;
                    }
                    if ((a + b) % 2) {
                        add_tri(m, q[0], q[1], q[2]);
                        add_tri(m, q[0], q[2], q[3]);
                    } else {
                        add_tri(m, q[0], q[1], q[3]);
                        add_tri(m, q[1], q[2], q[3]);
                    }
                }
#undef LAT
    m->closed_triangles = m->mesh.triangle_count;
    return 0;
}

int rtk_closed_cylinder(const double c[3], double r, double h, int seg, int degenerate, rtk_closed_mesh *m)
{
    set_solid(m, "cylinder", RTK_SOLID_CYLINDER, c, r, h);
    /* 2 seg rim vertices, 2 cap centres, seg middle points */
    const size_t nv = 3 * (size_t)seg + 2, nt = 4 * (size_t)seg + (degenerate ? 2 * (size_t)seg : 0);
    if (mesh_alloc(m, nv, nt))
        return 1;
    const uint32_t s = (uint32_t)seg, top = 2 * s, bottom = 2 * s + 1, mid = 2 * s + 2;
    for (int j = 0; j < seg; j++) {
        const double ph = 2 * pi * j / seg, x = cos(ph), y = sin(ph);
        add_vertex(m, (size_t)j, c[0] + r * x, c[1] + r * y, c[2] + h, x, y, 1);
        add_vertex(m, (size_t)j + s, c[0] + r * x, c[1] + r * y, c[2] - h, x, y, -1);
        add_vertex(m, (size_t)j + mid, c[0] + r * x, c[1] + r * y, c[2], x, y, 0);
    }
    add_vertex(m, top, c[0], c[1], c[2] + h, 0, 0, 1);
    add_vertex(m, bottom, c[0], c[1], c[2] - h, 0, 0, -1);
    for (uint32_t j = 0; j < s; j++) {
        const uint32_t j1 = (j + 1) % s;
        add_tri(m, top, j, j1);
        add_tri(m, bottom, s + j1, s + j);
        add_tri(m, j, s + j, j1);
        add_tri(m, j1, s + j, s + j1);
    }
    m->closed_triangles = m->mesh.triangle_count;
    for (uint32_t j = 0; degenerate && j < s; j++) {
        add_tri(m, j, mid + j, s + j);          /* top, middle and bottom of a side line */
        add_tri(m, top, j, top);                /* a repeated vertex */
    }
    return 0;
}

void rtk_closed_free(rtk_closed_mesh *m)
{
    free(m->mesh.vertices);
    free(m->mesh.indices);
    free(m->normal);
    memset(m, 0, sizeof *m);
}

/* splitmix64, as the tests' generator */
static uint32_t next_u32(uint64_t *s)
{
    uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return (uint32_t)((z ^ (z >> 31)) >> 32);
}
static float next_float(uint64_t *s)
{
    return (float)(next_u32(s) >> 8) * 0x1p-24f;
}

int rtk_aimed_add(rtk_aimed *a, const float o[3], const float i[3], int zero_sign)
{
    if (a->count == a->cap) {
        const size_t cap = a->cap ? 2 * a->cap : 1024;
        rtk_ray *rays = realloc(a->rays, cap * sizeof *rays);
        if (rays)
            a->rays = rays;
        float *t_in = realloc(a->t_in, cap * sizeof *t_in);
        if (t_in)
            a->t_in = t_in;
        if (!rays || !t_in)
            return 1;
        a->cap = cap;
    }
    double dd[3], l = 0.0;
    for (int k = 0; k < 3; k++) {
        dd[k] = (double)i[k] - o[k];
        l += dd[k] * dd[k];
    }
    l = sqrt(l);
    float d[3];
    for (int k = 0; k < 3; k++) {
        d[k] = (float)(dd[k] / l);
        if (d[k] == 0.0f)
            d[k] = zero_sign ? -0.0f : 0.0f;
    }
    a->t_in[a->count] = (float)l;
    a->rays[a->count++] = (rtk_ray){.org_x = o[0], .org_y = o[1], .org_z = o[2], .dir_x = d[0], .dir_y = d[1],
                                    .dir_z = d[2], .tnear = 0.0f, .tfar = INFINITY, .mask = ~0u};
    return 0;
}

void rtk_aimed_free(rtk_aimed *a)
{
    free(a->rays);
    free(a->t_in);
    memset(a, 0, sizeof *a);
}

static int aim(rtk_aimed *a, const rtk_closed_mesh *m, const float p[3], const float n[3], double margin, float out,
               float in, uint64_t *rng, int axis_too)
{
    /* from a random direction on the outer side */
    for (int tries = 0; tries < 32; tries++) {
        float w[3], o[3], i[3];
        for (int k = 0; k < 3; k++)
            w[k] = n[k] + 1.6f * (next_float(rng) - 0.5f);
        const float l = sqrtf(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
        for (int k = 0; k < 3; k++) {
            o[k] = p[k] + out * w[k] / l;
            i[k] = p[k] - in * w[k] / l;
        }
        if (rtk_closed_depth(m, o) < -margin && rtk_closed_depth(m, i) > margin) {
            if (rtk_aimed_add(a, o, i, tries & 1))
                return 1;
            break;
        }
    }
    if (!axis_too)
        return 0;
    /* along each axis toward the inside, the other components +0.0 or -0.0 */
    for (int k = 0; k < 3; k++) {
        float o[3] = {p[0], p[1], p[2]}, i[3] = {p[0], p[1], p[2]};
        o[k] = p[k] + (n[k] > 0 ? out : -out);
        i[k] = p[k] - (n[k] > 0 ? in : -in);
        if (rtk_closed_depth(m, o) < -margin && rtk_closed_depth(m, i) > margin &&
            rtk_aimed_add(a, o, i, (int)(next_u32(rng) & 1)))
            return 1;
    }
    return 0;
}

int rtk_closed_aim(const rtk_closed_mesh *m, double margin, float out, float in, uint64_t seed, rtk_aimed *a)
{
    memset(a, 0, sizeof *a);
    uint64_t rng = seed;
    const size_t nv = m->mesh.vertex_count, nt = m->closed_triangles;
    const uint32_t *idx = m->mesh.indices;
    unsigned char *used = calloc(nv + 1, 1);
    int bad = !used;
    for (size_t i = 0; !bad && i < 3 * nt; i++)
        used[idx[i]] = 1;
    for (size_t i = 0; !bad && i < nv; i++)
        if (used[i]) /* (the box's lattice has points inside) */
            bad = aim(a, m, m->mesh.vertices + 3 * i, m->normal[i], margin, out, in, &rng, 1);
    free(used);
    for (size_t t = 0; !bad && t < nt; t++)
        for (int e = 0; !bad && e < 3; e++) {
            const uint32_t i0 = idx[3 * t + e], i1 = idx[3 * t + (e + 1) % 3];
            const float *p0 = m->mesh.vertices + 3 * i0, *p1 = m->mesh.vertices + 3 * i1;
            for (int f = 0; !bad && f < 2; f++) {
                const float s = f ? 0.5f : 1.0f / 3.0f;
                float p[3], n[3];
                for (int k = 0; k < 3; k++) {
                    p[k] = p0[k] + s * (p1[k] - p0[k]);
                    n[k] = m->normal[i0][k] + m->normal[i1][k];
                }
                bad = aim(a, m, p, n, margin, out, in, &rng, f == 0);
            }
        }
    if (bad)
        rtk_aimed_free(a);
    return bad;
}

int rtk_closed_graze(const rtk_closed_mesh *box, int n, double deg, size_t count, int on_lines, uint64_t seed,
                     rtk_aimed *a)
{
    memset(a, 0, sizeof *a);
    uint64_t rng = seed;
    const double th = deg * pi / 180.0, h = box->a, cell = 2.0 * h / n;
    for (size_t i = 0; i < count; i++) {
        /* within 7/8 of the face's half side of its centre */
        double q[2] = {1.75 * h * (next_float(&rng) - 0.5), 1.75 * h * (next_float(&rng) - 0.5)};
        if (on_lines) {
            const int first = (int)(i % 2), both = (int)(i / 2 % 2); /* a line of x or y; every other a vertex */
            q[first] = round(q[first] / cell) * cell;
            if (both)
                q[!first] = round(q[!first] / cell) * cell;
        }
        const double p[3] = {box->c[0] + q[0], box->c[1] + q[1], box->c[2] + h};
        const double ph = 2.0 * pi * next_float(&rng);
        const double w[3] = {cos(th) * cos(ph), cos(th) * sin(ph), -sin(th)};
        float o[3], in[3];
        for (int k = 0; k < 3; k++) {
            o[k] = (float)(p[k] - 0.5 * h * w[k]);
            in[k] = (float)(p[k] + 0.05 * h * w[k]);
        }
        if (rtk_closed_depth(box, o) < 0 && rtk_closed_depth(box, in) > 0 && rtk_aimed_add(a, o, in, (int)(i & 1))) {
            rtk_aimed_free(a);
            return 1;
        }
    }
    return 0;
}
