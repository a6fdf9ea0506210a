/* The refit section: a deforming mesh refitted, and the refitted tree traced. */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_internal.h"

/* Deforming geometry: the mesh built once with quality REFIT, then twisted
 * a little more each frame and refitted (the time from the update calls to
 * the committed scene, best of the frames); then the diffuse rays through
 * the refitted tree, and through a tree built afresh over the final shape
 * (at medium quality), to show what keeping the tree costs in trace speed. */
int section_refit(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    const int frames = o->builds + 1;
    printf("\nrefit: the mesh twisted a little more in each of %d frames (up to 0.6 radians at the top) and "
           "refitted; refit time from the update calls to the committed scene, best of the frames; then the diffuse "
           "rays through the refitted tree and through one built afresh over the last frame (medium quality), "
           "single rays, 1 thread\n",
           frames);
    printf("  %-20s %7s %9s %8s %9s  %s\n", "library", "threads", "refit ms", "ratio", "Mtris/s",
           "diffuse Mrays/s refitted / built");
    const size_t floats = c->m->vertex_count * 3 + 4; /* Embree reads 16 bytes at the last vertex */
    float *v = calloc(floats, sizeof *v);
    const rayset diff = c->sets[SET_DIFFUSE];
    unsigned char *hits = malloc(diff.n + 1);
    if (!v || !hits) {
        free(v);
        free(hits);
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    rtk_mesh moved = *c->m;
    moved.vertices = v;
    double ref_ms[4] = {0};
    int rc = 0;
    for (int l = 0; l < c->nlibs && !rc; l++)
        for (int ti = 0; ti < o->nthreads && !rc; ti++) {
            lib bl;
            rc = lib_open(&bl, c->libs[l].name, c->libs[l].embree, c->libs[l].config, o->threads[ti], err, err_size);
            if (rc)
                break;
            scene sc;
            const double best = moving_frames(&sc, &bl, c, v, MODE_REFIT, 1, frames, err, err_size);
            rc = best < 0;
            if (!rc && sc.rscene) {
                rtk_scene_info info = {.struct_size = sizeof info};
                if (rtk_scene_get_info(sc.rscene, &info) || info.refits != (uint32_t)frames) {
                    snprintf(err, err_size, "%s did not refit: %s", bl.name, rtk_device_get_error_message(bl.rdev));
                    rc = 1;
                }
            }
            if (!rc && sc.escene && rtcGetDeviceError(bl.edev) != RTC_ERROR_NONE) {
                snprintf(err, err_size, "%s: a refit commit failed", bl.name);
                rc = 1;
            }
            double refitted = 0, built = 0;
            if (!rc && ti == 0) {
                const render_tracer t = scene_tracer(&sc, 0);
                refitted = trace_set(&t, &diff, 1, 0, 1, o->repeat, hits);
                scene fresh;
                rc = scene_build(&fresh, &bl, &moved, v, MODE_DEFAULT, 1, err, err_size);
                if (!rc) {
                    const render_tracer tf = scene_tracer(&fresh, 0);
                    built = trace_set(&tf, &diff, 1, 0, 1, o->repeat, hits);
                    scene_release(&fresh);
                }
            }
            if (sc.lib)
                scene_release(&sc);
            lib_close(&bl);
            if (rc)
                break;
            if (l == 0)
                ref_ms[ti] = best;
            printf("  %-20s %7d %9.2f %7.2fx %9.2f", c->libs[l].name, o->threads[ti], best * 1e3,
                   ratio(ref_ms[ti], best), (double)c->m->triangle_count / best * 1e-6);
            if (ti == 0)
                printf("  %.2f / %.2f", refitted, built);
            printf("\n");
            csv_row(&c->csv, "refit", c->libs[l].name, "refit", "refit", "", o->threads[ti], best * 1e3, "ms",
                    ratio(ref_ms[ti], best));
            if (ti == 0) {
                csv_row(&c->csv, "refit", c->libs[l].name, "refitted", "diffuse", "single", 1, refitted, "Mrays/s", 0);
                csv_row(&c->csv, "refit", c->libs[l].name, "built", "diffuse", "single", 1, built, "Mrays/s", 0);
            }
        }
    free(v);
    free(hits);
    return rc;
}
