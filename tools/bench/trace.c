/* The trace section: every ray set through every library and API. */
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_internal.h"
#include "progress.h"

/* The pieces each pass over a ray set is cut into (section_trace). */
enum { TRACE_CHUNKS = 8 };

/* The order the libraries trace piece `piece` in: a shuffle seeded by the
 * piece's number, so that every library follows every other about equally
 * often (with a rotation each one always came right after the same one,
 * and the caches the previous library leaves count for rays that mostly
 * test the top of the tree, as San Miguel's do). */
static void piece_order(int *order, int n, uint64_t piece)
{
    uint64_t x = piece * 0x9e3779b97f4a7c15ull + 0x2545f4914f6cdd1dull;
    for (int i = 0; i < n; i++)
        order[i] = i;
    for (int i = n - 1; i > 0; i--) {
        x ^= x >> 29;
        x *= 0xbf58476d1ce4e5b9ull;
        x ^= x >> 32;
        const int j = (int)(x % (uint64_t)(i + 1));
        const int t = order[i];
        order[i] = order[j];
        order[j] = t;
    }
}

/* Piece p of lib l's pass over set s through api a on threads[ti]: its
 * time at PIECE_SECS(l, ti, s, a)[p] (npairs per combination). */
#define PIECE_SECS(l, ti, s, a)                                                                                       \
    (piece_secs + ((((size_t)(l) * 4 + (size_t)(ti)) * NSETS + (size_t)(s)) * NAPIS + (size_t)(a)) * (size_t)npairs)

/* Per set and thread count, the API Embree isa=avx2 (the first library)
 * traces the set fastest with (its best pass), and each other library's
 * best API against that one: the median, with quartiles, of the pieces'
 * time ratios (the same rays, traced at different moments of the run,
 * since every API has its own pass). */
static void print_best_api(const ctx *c, double rate[MAXLIBS][4][NSETS][NAPIS], const double *piece_secs, int npairs)
{
    const bench_opts *o = c->o;
    printf("  Embree's fastest API per ray set (of %s), and each library's best API against it:\n",
           c->libs[0].name);
    double *r = malloc(sizeof(double) * (size_t)npairs);
    if (!r)
        return;
    for (int ti = 0; ti < o->nthreads; ti++)
        for (int s = 0; s < NSETS; s++) {
            int eb = -1;
            for (int a = 0; a < NAPIS; a++)
                if (o->api_on[a] && o->set_on[s] && (eb < 0 || rate[0][ti][s][a] > rate[0][ti][s][eb]))
                    eb = a;
            if (eb < 0 || !(rate[0][ti][s][eb] > 0))
                continue;
            printf("  %-10s %d thread%s  %s %-8s %7.2f", set_names[s], o->threads[ti], o->threads[ti] > 1 ? "s" : " ",
                   c->libs[0].name, render_api_name(apis[eb]), rate[0][ti][s][eb]);
            const double *ref = PIECE_SECS(0, ti, s, eb);
            for (int l = 1; l < c->nlibs; l++) {
                int best_a = -1;
                double best_m = 0, best_lo = 0, best_hi = 0;
                for (int a = 0; a < NAPIS; a++) {
                    if (!o->api_on[a])
                        continue;
                    const double *t = PIECE_SECS(l, ti, s, a);
                    int n = 0;
                    for (int p = 0; p < npairs; p++)
                        if (t[p] > 0 && ref[p] > 0)
                            r[n++] = ref[p] / t[p];
                    if (!n)
                        continue;
                    qsort(r, (size_t)n, sizeof *r, cmp_double);
                    const double m = 0.5 * (r[(n - 1) / 2] + r[n / 2]);
                    if (best_a < 0 || m > best_m) {
                        best_a = a;
                        best_m = m;
                        best_lo = r[(n - 1) / 4];
                        best_hi = r[n - 1 - (n - 1) / 4];
                    }
                }
                if (best_a < 0)
                    continue;
                printf(" | %s %s %5.3fx [%5.3f-%5.3f]", c->libs[l].name, render_api_name(apis[best_a]), best_m,
                       best_lo, best_hi);
                char variant[80];
                snprintf(variant, sizeof variant, "%s against embree's best (%s)", mode_names[o->trace_mode],
                         render_api_name(apis[eb]));
                csv_row(&c->csv, "trace best api", c->libs[l].name, variant, set_names[s],
                        render_api_name(apis[best_a]), o->threads[ti], best_m, "ratio", best_m);
            }
            printf("\n");
        }
    free(r);
}

int section_trace(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    const rayset *sets = c->sets;
    printf("\ntrace%s: %zu primary rays (%.1f%% hit), %zu diffuse, %zu shadow, %zu incoherent, %zu sun; %d "
           "passes, each cut into %d pieces that every library traces in turn; Mrays/s (best pass), then the\n"
           "  ratio to %s: the median of the %d pieces' time ratios [and their quartiles]\n",
           o->trace_mode == MODE_ROBUST ? " (every library in robust mode)" : "", sets[0].n,
           100.0 * (double)sets[1].n / (double)sets[0].n, sets[1].n, sets[2].n, sets[3].n, sets[4].n, o->repeat,
           TRACE_CHUNKS, c->libs[0].name, o->repeat * TRACE_CHUNKS);
    printf("  packets of primary rays are 2x2, 4x2, 4x4 pixel blocks, given Embree's coherent flag; packets of\n"
           "  diffuse and shadow rays are those of neighbouring pixels, traced without it; incoherent rays bounce\n"
           "  from random points of the whole mesh, one after the other; sun rays are shadow rays to a\n"
           "  directional light from random points of the whole mesh\n");
    unsigned char *lhits[MAXLIBS], *ref_hits[NSETS];
    double rate[MAXLIBS][4][NSETS][NAPIS] = {{{{0}}}}; /* lib, threads index, set, api: the best pass */
    double med[MAXLIBS][4][NSETS][NAPIS] = {{{{0}}}}, lo[MAXLIBS][4][NSETS][NAPIS] = {{{{0}}}},
           hi[MAXLIBS][4][NSETS][NAPIS] = {{{{0}}}}; /* the paired ratios' median and quartiles */
    const int npairs = o->repeat * TRACE_CHUNKS;
    double *pairs = malloc(sizeof(double) * (size_t)(npairs * c->nlibs));
    /* every piece's time, by lib, threads, set, api: for the ratios across APIs */
    double *piece_secs = calloc((size_t)c->nlibs * 4 * NSETS * NAPIS * (size_t)npairs, sizeof(double));
    size_t disagree[MAXLIBS] = {0};
    int oom = !pairs || !piece_secs;
    for (int l = 0; l < c->nlibs; l++)
        oom |= !(lhits[l] = malloc(sets[0].n ? sets[0].n : 1));
    for (int s = 0; s < NSETS; s++)
        oom |= !(ref_hits[s] = calloc(sets[s].n ? sets[s].n : 1, 1));
    if (oom) {
        free(pairs);
        free(piece_secs);
        for (int l = 0; l < c->nlibs; l++)
            free(lhits[l]);
        for (int s = 0; s < NSETS; s++)
            free(ref_hits[s]);
        snprintf(err, err_size, "trace: out of memory for the hit records");
        return 1;
    }
    char chart[200];
    snprintf(chart, sizeof chart, "%s-trace", c->stem);
    FILE *dat = chart_open(c->charts, chart, 0);
    progress bar;
    progress_begin(&bar, "rtktool bench: trace");
    const int work = c->nlibs * o->nthreads * NSETS * NAPIS;
    int done = 0, ref_api = 0; /* the reference hits: the first library's first API asked for */
    while (ref_api < NAPIS - 1 && !o->api_on[ref_api])
        ref_api++;
    /* Every library's scene at once.  Each pass over a set is cut into
     * TRACE_CHUNKS pieces, and each piece is traced by every library in
     * turn (in an order shuffled from piece to piece), so that what slows the
     * machine for a while (other guests of a VM) falls on all of them
     * alike: the ratio of two libraries is the median of the pieces' time
     * ratios, with their quartiles; the rate is the best pass. */
    scene sc[MAXLIBS];
    int built = 0, failed = 0;
    for (; built < c->nlibs; built++)
        if (scene_build(&sc[built], &c->libs[built], c->m, c->padded, o->trace_mode, 1, err, err_size))
            break;
    for (int ti = 0; built == c->nlibs && ti < o->nthreads; ti++)
        for (int s = 0; s < NSETS; s++)
            for (int a = 0; a < NAPIS && !failed; a++, done += c->nlibs) {
                if (!o->api_on[a] || !o->set_on[s] || !sets[s].n)
                    continue;
                const int occluded = s == SET_SHADOW || s == SET_SUN;
                const size_t blocks = sets[s].n / 16;
                int np = 0;
                for (int r = 0; r < o->repeat; r++) {
                    double pass[MAXLIBS] = {0};
                    for (int k = 0; k < TRACE_CHUNKS; k++) {
                        const size_t b = blocks * (size_t)k / TRACE_CHUNKS * 16,
                                     e = blocks * (size_t)(k + 1) / TRACE_CHUNKS * 16;
                        if (e == b)
                            continue;
                        const rayset part = {sets[s].rays + b, e - b, NULL};
                        double secs[MAXLIBS];
                        int order[MAXLIBS];
                        piece_order(order, c->nlibs, (uint64_t)(r * TRACE_CHUNKS + k));
                        for (int j = 0; j < c->nlibs; j++) {
                            const int l = order[j];
                            /* Embree's coherent flag for packets of camera rays, not for streams */
                            const int coherent = s == SET_PRIMARY && apis[a] > 1 && apis[a] <= 16;
                            const render_tracer t = scene_tracer(&sc[l], coherent);
                            unsigned char *h = l == 0 && ti == 0 && a == ref_api ? ref_hits[s] : lhits[l];
                            secs[l] = trace_pass(&t, &part, apis[a], occluded, o->threads[ti], h + b);
                            if (secs[l] < 0) {
                                snprintf(err, err_size, "trace: out of memory for a stream");
                                failed = 1;
                                break;
                            }
                            pass[l] += secs[l];
                            PIECE_SECS(l, ti, s, a)[np] = secs[l];
                        }
                        if (failed)
                            break;
                        for (int l = 0; l < c->nlibs; l++) {
                            pairs[l * npairs + np] = secs[l] > 0 ? secs[0] / secs[l] : 0.0;
                            if (r == o->repeat - 1 && !(l == 0 && ti == 0 && a == ref_api))
                                for (size_t i = b; i < e; i++)
                                    disagree[l] += lhits[l][i] != ref_hits[s][i];
                        }
                        np++;
                    }
                    for (int l = 0; l < c->nlibs; l++) {
                        const double v = pass[l] > 0 ? (double)sets[s].n / pass[l] * 1e-6 : 0.0;
                        if (v > rate[l][ti][s][a])
                            rate[l][ti][s][a] = v;
                    }
                }
                for (int l = 0; l < c->nlibs; l++) {
                    double *pl = pairs + l * npairs;
                    qsort(pl, (size_t)np, sizeof *pl, cmp_double);
                    med[l][ti][s][a] = np ? 0.5 * (pl[(np - 1) / 2] + pl[np / 2]) : 0.0;
                    lo[l][ti][s][a] = np ? pl[(np - 1) / 4] : 0.0;
                    hi[l][ti][s][a] = np ? pl[np - 1 - (np - 1) / 4] : 0.0;
                }
                progress_update(&bar, (double)(done + c->nlibs) / work);
            }
    progress_end(&bar);
    free(pairs);
    for (int l = 0; l < c->nlibs; l++)
        free(lhits[l]);
    for (int l = 0; l < built; l++)
        scene_release(&sc[l]);
    if (built < c->nlibs || failed) {
        free(piece_secs);
        for (int s = 0; s < NSETS; s++)
            free(ref_hits[s]);
        return 1; /* (the run's end removes the chart's files) */
    }
    for (int ti = 0; ti < o->nthreads; ti++) {
        printf("  %d thread%s\n", o->threads[ti], o->threads[ti] > 1 ? "s" : "");
        print_row_label("");
        for (int l = 0; l < c->nlibs; l++)
            printf(" %-30s", c->libs[l].name);
        printf("\n");
        for (int s = 0; s < NSETS; s++)
            for (int a = 0; a < NAPIS; a++) {
                if (!o->api_on[a] || !o->set_on[s])
                    continue;
                char label[48];
                snprintf(label, sizeof label, "%s %s", set_names[s], render_api_name(apis[a]));
                print_row_label(label);
                for (int l = 0; l < c->nlibs; l++) {
                    const double v = rate[l][ti][s][a], m = med[l][ti][s][a];
                    if (l == 0)
                        printf(" %8.2f%22s", v, "");
                    else
                        printf(" %8.2f %5.3fx [%5.3f-%5.3f]", v, m, lo[l][ti][s][a], hi[l][ti][s][a]);
                    csv_row(&c->csv, "trace", c->libs[l].name, mode_names[o->trace_mode], set_names[s],
                            render_api_name(apis[a]), o->threads[ti], v, "Mrays/s", l ? m : 1.0);
                }
                printf("\n");
                if (dat && ti == 0) {
                    fprintf(dat, "\"%s\"", label);
                    for (int l = 0; l < c->nlibs; l++)
                        fprintf(dat, " %.4f", rate[l][ti][s][a]);
                    fprintf(dat, "\n");
                }
            }
    }
    print_best_api(c, rate, piece_secs, npairs);
    free(piece_secs);
    printf("  hit/miss differs from %s on:", c->libs[0].name);
    for (int l = 1; l < c->nlibs; l++)
        printf(" %s %zu%s", c->libs[l].name, disagree[l], l + 1 < c->nlibs ? "," : "");
    printf(" rays (over every pass compared)\n");
    if (dat) {
        FILE *gp = chart_open(c->charts, chart, 1);
        if (gp) {
            fprintf(gp,
                    "set terminal pngcairo noenhanced size 1200,520 font 'sans,10'\nset output '%s-trace.png'\n"
                    "set title '%s: trace rate, %d thread%s (higher is better)'\nset ylabel 'Mrays/s'\n"
                    "set style data histogram\nset style histogram clustered gap 1\nset style fill solid 0.85 border -1\n"
                    "set boxwidth 0.9\nset xtics rotate by -30 scale 0\nset key outside top center horizontal\nset grid ytics\n"
                    "set yrange [0:*]\nplot ",
                    c->stem, base_name(c->csv.mesh), o->threads[0], o->threads[0] > 1 ? "s" : "");
            for (int l = 0; l < c->nlibs; l++)
                fprintf(gp, "%s'%s-trace.dat' using %d:xtic(1) title '%s'", l ? ", " : "", c->stem, l + 2,
                        c->libs[l].name);
            fprintf(gp, "\n");
        }
    }
    for (int s = 0; s < NSETS; s++)
        free(ref_hits[s]);
    return 0;
}
