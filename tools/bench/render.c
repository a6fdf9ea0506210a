/* The render section: the diffuse path tracer of rtktool trace per library. */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_internal.h"

/* A render of the diffuse path tracer per library, API and thread count. */
int section_render(ctx *c, char *err, size_t err_size)
{
    const bench_opts *o = c->o;
    render_settings rs;
    float lo[3], hi[3];
    rtk_mesh_bounds(c->m, lo, hi);
    render_defaults(&rs, lo, hi, o->render_w, o->render_h);
    {
        /* the trace sets' tight framing (make_primary), so most paths hit */
        const float diag = rtk_mesh_bounds(c->m, lo, hi);
        const float ctr[3] = {0.5f * (lo[0] + hi[0]), 0.5f * (lo[1] + hi[1]), 0.5f * (lo[2] + hi[2])};
        const float eye[3] = {ctr[0] + 0.35f * diag, ctr[1] + 0.3f * diag, ctr[2] + 1.0f * diag};
        const float dist = sqrtf(0.35f * 0.35f + 0.3f * 0.3f + 1.0f) * diag;
        const float fov = 2.0f * atanf(0.25f * diag * (float)o->render_h / (float)o->render_w / dist) * 57.29578f;
        render_camera_look(&rs.camera, eye, ctr, (const float[3]){0, 1, 0}, fov, o->render_w, o->render_h, err,
                           err_size);
    }
    rs.mode = RENDER_DIFFUSE;
    rs.spp = o->render_spp;
    float *rgb = malloc((size_t)o->render_w * (size_t)o->render_h * 3 * sizeof *rgb);
    if (!rgb) {
        snprintf(err, err_size, "out of memory");
        return 1;
    }
    printf("\nrender (Tables 2/3 of the Embree paper)%s: rtktool trace's diffuse path tracer, %dx%d, %d spp, up to %d "
           "bounces, shading and sampling included; Mrays/s of all rays traced, best of %d (ratio to %s)\n",
           o->trace_mode == MODE_ROBUST ? " (every library in robust mode)" : "", o->render_w, o->render_h, rs.spp,
           rs.max_bounces, o->repeat, c->libs[0].name);
    double best[MAXLIBS][4][NAPIS] = {{{0}}}; /* lib, threads index, api */
    render_stats first = {0};
    for (int l = 0; l < c->nlibs; l++) {
        scene sc;
        if (scene_build(&sc, &c->libs[l], c->m, c->padded, o->trace_mode, 1, err, err_size)) {
            free(rgb);
            return 1;
        }
        const render_tracer t = scene_tracer(&sc, 0);
        for (int ti = 0; ti < o->nthreads; ti++)
            for (int a = 0; a < NAPIS; a++) {
                if (!o->api_on[a])
                    continue;
                rs.api = apis[a];
                rs.threads = o->threads[ti];
                render_stats st;
                for (int r = 0; r < o->repeat; r++) {
                    if (render_image(&t, &rs, rgb, &st, err, err_size)) {
                        scene_release(&sc);
                        free(rgb);
                        return 1;
                    }
                    const double v = (double)render_stats_rays(&st) / st.seconds * 1e-6;
                    best[l][ti][a] = v > best[l][ti][a] ? v : best[l][ti][a];
                }
                if (!first.primary)
                    first = st;
            }
        scene_release(&sc);
    }
    print_header(c);
    for (int ti = 0; ti < o->nthreads; ti++)
        for (int a = 0; a < NAPIS; a++) {
            if (!o->api_on[a])
                continue;
            char label[48];
            snprintf(label, sizeof label, "%s, %d thread%s", render_api_name(apis[a]), o->threads[ti], o->threads[ti] > 1 ? "s" : "");
            print_row_label(label);
            for (int l = 0; l < c->nlibs; l++) {
                const double v = best[l][ti][a], r = best[0][ti][a];
                print_cell(v, r, l == 0);
                csv_row(&c->csv, "render", c->libs[l].name, mode_names[o->trace_mode], "diffuse path tracer",
                        render_api_name(apis[a]),
                        o->threads[ti], v, "Mrays/s", ratio(v, r));
            }
            printf("\n");
        }
    /* each library's fastest API against the first library's fastest */
    for (int ti = 0; ti < o->nthreads; ti++) {
        int eb = -1;
        for (int a = 0; a < NAPIS; a++)
            if (o->api_on[a] && (eb < 0 || best[0][ti][a] > best[0][ti][eb]))
                eb = a;
        if (eb < 0)
            continue;
        printf("  fastest API, %d thread%s: %s %s %.2f", o->threads[ti], o->threads[ti] > 1 ? "s" : "",
               c->libs[0].name, render_api_name(apis[eb]), best[0][ti][eb]);
        for (int l = 1; l < c->nlibs; l++) {
            int b = -1;
            for (int a = 0; a < NAPIS; a++)
                if (o->api_on[a] && (b < 0 || best[l][ti][a] > best[l][ti][b]))
                    b = a;
            printf(", %s %s %.2f (%.2fx)", c->libs[l].name, render_api_name(apis[b]), best[l][ti][b],
                   ratio(best[l][ti][b], best[0][ti][eb]));
            char variant[80];
            snprintf(variant, sizeof variant, "%s against embree's best (%s)", mode_names[o->trace_mode],
                     render_api_name(apis[eb]));
            csv_row(&c->csv, "render best api", c->libs[l].name, variant, "diffuse path tracer",
                    render_api_name(apis[b]), o->threads[ti], best[l][ti][b], "Mrays/s",
                    ratio(best[l][ti][b], best[0][ti][eb]));
        }
        printf("\n");
    }
    printf("  rays per image: %llu primary (%.1f%% hit), %llu bounce, %llu shadow\n",
           (unsigned long long)first.primary, first.primary ? 100.0 * (double)first.primary_hits / first.primary : 0.0,
           (unsigned long long)first.bounce, (unsigned long long)first.shadow);
    free(rgb);
    return 0;
}
