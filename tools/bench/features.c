/* The features section: what masks, filters and quads cost. */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_internal.h"

/* What masks, filters and quads cost when a scene uses them: the default
 * scene, one whose geometry has a mask every ray passes (MODE_MASK), the
 * mesh as two geometries of different masks (MODE_MASKS2: each candidate's
 * mask tested), one with filters that accept every candidate (the same
 * hits), and the same triangles as quads (MODE_QUAD),
 * each library against its own default and rtk against Embree in the same
 * mode; 1 thread. */
enum { NFEAT = 5 };

int section_features(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    static const int modes[NFEAT] = {MODE_DEFAULT, MODE_MASK, MODE_MASKS2, MODE_FILTER, MODE_QUAD};
    static const int sets[2] = {SET_DIFFUSE, SET_SHADOW};
    if (quads_make(c->m, &bench_quads)) {
        snprintf(err, err_size, "out of memory for the quads");
        return 1;
    }
    printf("\nfeatures: a geometry mask (mask: one geometry of mask 1; masks2: the mesh's two halves, masks 1 and 2; "
           "the rays' all ones), filters accepting every hit, and the triangles as quads (%zu, %zu of them "
           "two triangles; the same surfaces as default); Mrays/s, 1 thread (ratio to the same library's default) "
           "[ratio to %s in the same mode]\n",
           bench_quads.n, bench_quads.paired, c->libs[0].name);
    printf("  %-20s %-8s %-28s %-28s %-28s %-28s\n", "library", "mode", "diffuse single", "diffuse packet8",
           "shadow single", "shadow packet8");
    /* Every scene built first, then the passes interleaved (one pass of
     * every cell per round, the best of the rounds kept), so that drift in
     * the machine's speed falls on all cells alike. */
    enum { MAXL = 8 };
    const int nl = c->nlibs < MAXL ? c->nlibs : MAXL;
    scene sc[MAXL][NFEAT];
    memset(sc, 0, sizeof sc);
    double rate[MAXL][NFEAT][2][2] = {{{{0}}}}; /* lib, mode, set, api */
    unsigned char *hits = malloc(c->sets[SET_DIFFUSE].n + c->sets[SET_SHADOW].n + 1);
    int bad = !hits;
    for (int l = 0; l < nl && !bad; l++)
        for (int mi = 0; mi < NFEAT && !bad; mi++)
            bad = scene_build(&sc[l][mi], &c->libs[l], c->m, c->padded, modes[mi], 1, err, err_size);
    for (int round = 0; round < o->repeat && !bad; round++)
        for (int l = 0; l < nl; l++)
            for (int mi = 0; mi < NFEAT; mi++)
                for (int k = 0; k < 2; k++)
                    for (int a = 0; a < 2; a++) {
                        const render_tracer t = scene_tracer(&sc[l][mi], 0);
                        const double r =
                            trace_set(&t, &c->sets[sets[k]], a ? 8 : 1, sets[k] == SET_SHADOW, 1, 1, hits);
                        rate[l][mi][k][a] = r > rate[l][mi][k][a] ? r : rate[l][mi][k][a];
                    }
    for (int l = 0; l < nl && !bad; l++)
        for (int mi = 0; mi < NFEAT; mi++) {
            printf("  %-20s %-8s", c->libs[l].name, mode_names[modes[mi]]);
            for (int k = 0; k < 2; k++)
                for (int a = 0; a < 2; a++) {
                    const double r = rate[l][mi][k][a];
                    char cell[64];
                    snprintf(cell, sizeof cell, "%.2f (%.2fx)", r, ratio(r, rate[l][0][k][a]));
                    if (l > 0)
                        snprintf(cell + strlen(cell), sizeof cell - strlen(cell), " [%.2fx]",
                                 ratio(r, rate[0][mi][k][a]));
                    printf(" %-28s", cell);
                    csv_row(&c->csv, "features", c->libs[l].name, mode_names[modes[mi]], set_names[sets[k]],
                            a ? "packet8" : "single", 1, r, "Mrays/s", 0);
                }
            printf("\n");
        }
    for (int l = 0; l < nl; l++)
        for (int mi = 0; mi < NFEAT; mi++)
            if (sc[l][mi].lib)
                scene_release(&sc[l][mi]);
    free(hits);
    free(bench_quads.q);
    bench_quads = (quad_list){0};
    return bad;
}
