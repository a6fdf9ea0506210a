/* The accuracy section: rays aimed at shared edges that leak through. */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>

#include "bench_internal.h"

int section_accuracy(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    rayset edges;
    make_edge_rays(c->m, (size_t)o->edge_rays, &edges);
    const rayset diff = c->sets[SET_DIFFUSE];
    printf("\naccuracy: %zu rays aimed at points of edges shared by two triangles, from the side both face; a ray "
           "that misses or hits beyond its edge point leaked through the mesh, and one that hits both triangles "
           "(every hit collected by a filter) hit twice; beside the diffuse rays' rate (single rays, 1 thread)\n",
           edges.n);
    printf("  %-20s %-8s %10s %12s %10s %12s %16s %8s\n", "library", "mode", "leaks", "per million", "twice",
           "per million", "diffuse Mrays/s", "B/tri");
    char chart[200];
    snprintf(chart, sizeof chart, "%s-accuracy", c->stem);
    FILE *dat = chart_open(c->charts, chart, 0);
    unsigned char *hits = malloc(diff.n + 1);
    int bad = !hits;
    if (bad)
        snprintf(err, err_size, "accuracy: out of memory for the diffuse rays' hits");
    for (int l = 0; l < c->nlibs && !bad; l++) {
        for (int mode = 0; mode < 3 && !bad; mode++) {
            scene sc;
            if ((bad = scene_build(&sc, &c->libs[l], c->m, c->padded, mode, 1, err, err_size)))
                break;
            const render_tracer t = scene_tracer(&sc, 0);
            const size_t leaks = count_leaks(&t, &edges);
            const double rate = trace_set(&t, &diff, 1, 0, 1, o->repeat, hits), bytes = sc.bytes_per_tri;
            scene_release(&sc);
            bench_collect = 1;
            bad = scene_build(&sc, &c->libs[l], c->m, c->padded, mode, 1, err, err_size);
            bench_collect = 0;
            if (bad)
                break;
            const render_tracer tc = scene_tracer(&sc, 0);
            const size_t twice = count_double_hits(&tc, &edges);
            scene_release(&sc);
            const double ppm = edges.n ? 1e6 * (double)leaks / (double)edges.n : 0.0;
            const double ppm2 = edges.n ? 1e6 * (double)twice / (double)edges.n : 0.0;
            printf("  %-20s %-8s %10zu %12.1f %10zu %12.1f %16.2f %8.1f\n", c->libs[l].name, mode_names[mode], leaks,
                   ppm, twice, ppm2, rate, bytes);
            csv_row(&c->csv, "accuracy", c->libs[l].name, mode_names[mode], "edge", "single", 1, ppm,
                    "leaks per million", 0);
            csv_row(&c->csv, "accuracy", c->libs[l].name, mode_names[mode], "edge", "single", 1, ppm2,
                    "double hits per million", 0);
            csv_row(&c->csv, "accuracy", c->libs[l].name, mode_names[mode], "diffuse", "single", 1, rate, "Mrays/s",
                    0);
            if (dat)
                fprintf(dat, "%.3f %.4f %s\n", ppm, rate, mode_names[mode]);
        }
        if (dat)
            fprintf(dat, "\n\n"); /* one gnuplot index per library */
    }
    if (dat && !bad) {
        FILE *gp = chart_open(c->charts, chart, 1);
        if (gp) {
            fprintf(gp,
                    "set terminal pngcairo noenhanced size 900,600 font 'sans,10'\nset output '%s-accuracy.png'\n"
                    "set title '%s: speed against accuracy per intersector and mode'\n"
                    "set xlabel 'rays leaking through shared edges, per million (lower is better)'\n"
                    "set ylabel 'diffuse rays, Mrays/s, 1 thread (higher is better)'\n"
                    "set grid\nset key outside right\nset xrange [0:*]\nset yrange [0:*]\n"
                    "set offsets graph 0.05, graph 0.1, graph 0.1, graph 0\nplot ",
                    c->stem, base_name(c->csv.mesh));
            for (int l = 0; l < c->nlibs; l++)
                fprintf(gp, "%s'%s-accuracy.dat' index %d using 1:2 with points pt %d ps 1.5 lc %d title '%s', "
                        "'' index %d using 1:2:3 with labels offset 0.8,0.5 left font 'sans,7' tc lt -1 notitle",
                        l ? ", " : "", c->stem, l, 5 + 2 * (l % 3), l + 1, c->libs[l].name, l);
            fprintf(gp, "\n");
        }
    }
    free(edges.rays);
    free(edges.pair);
    free(hits);
    return bad;
}
