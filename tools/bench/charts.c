/* The bench's charts: each a data file (NAME.dat) and a gnuplot script
 * (NAME.gp) that the sections write, and the PNG gnuplot draws from them.
 * Like bench.csv, they replace the previous run's only once the run is
 * whole: the sections write into temporary files beside them
 * (file_replace), charts_finish puts them in place and draws them when the
 * run succeeded and removes them when it did not, and a PNG that gnuplot
 * fails to draw is put back as it was. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_internal.h"
#include "file_io.h"

/* One file of a chart, pending until charts_finish. */
typedef struct chart_file {
    file_replace r;
    char name[200], path[700];
    int script; /* the .gp, else the .dat */
    int written; /* in place */
} chart_file;

struct charts {
    const char *outdir;
    chart_file **v; /* (pointers: file_replace keeps its path's address) */
    int n, cap;
};

charts *charts_new(const char *outdir)
{
    charts *cs = calloc(1, sizeof *cs);
    if (cs)
        cs->outdir = outdir;
    return cs;
}

FILE *chart_open(charts *cs, const char *name, int script)
{
    char err[1024];
    chart_file *f = NULL;
    if (cs->n == cs->cap) {
        const int cap = cs->cap ? 2 * cs->cap : 8;
        chart_file **v = realloc(cs->v, (size_t)cap * sizeof *v);
        if (!v)
            goto fail;
        cs->v = v, cs->cap = cap;
    }
    if (!(f = calloc(1, sizeof *f)))
        goto fail;
    snprintf(f->name, sizeof f->name, "%s", name);
    snprintf(f->path, sizeof f->path, "%s/%s.%s", cs->outdir, name, script ? "gp" : "dat");
    f->script = script;
    if (file_replace_open(&f->r, f->path, err, sizeof err)) {
        fprintf(stderr, "rtktool bench: chart %s left out: %s\n", name, err);
        free(f);
        return NULL;
    }
    cs->v[cs->n++] = f;
    return f->r.f;
fail:
    free(f);
    fprintf(stderr, "rtktool bench: chart %s left out: out of memory\n", name);
    return NULL;
}

static int have_gnuplot(void)
{
    return system("command -v gnuplot >/dev/null 2>&1") == 0;
}

/* Runs gnuplot on DIR/NAME.gp; 1 on success. */
static int run_gnuplot(const char *dir, const char *name)
{
    char cmd[1200];
    snprintf(cmd, sizeof cmd, "cd '%s' && gnuplot '%s.gp' 2>'%s.gp.log'", dir, name, name);
    return system(cmd) == 0;
}

/* gnuplot on DIR/NAME.gp, the PNG it replaces kept aside until it has
 * drawn the new one; 1 on success, else 0 with why. */
static int draw(const char *dir, const char *name, const char **why)
{
    char png[700], kept[720];
    snprintf(png, sizeof png, "%s/%s.png", dir, name);
    snprintf(kept, sizeof kept, "%s/.%s.png.previous", dir, name);
    const int had = rename(png, kept) == 0;
    if (!had && errno != ENOENT) { /* (gnuplot would overwrite it) */
        *why = "the previous PNG could not be put aside";
        return 0;
    }
    *why = "gnuplot failed, see the .gp.log beside it";
    if (run_gnuplot(dir, name)) {
        if (had)
            remove(kept);
        return 1;
    }
    if (had)
        rename(kept, png);
    else
        remove(png); /* what gnuplot began */
    return 0;
}

/* Whether both files of the chart called name are in place. */
static int chart_whole(const charts *cs, const char *name)
{
    int have[2] = {0, 0};
    for (int i = 0; i < cs->n; i++)
        if (!strcmp(cs->v[i]->name, name))
            have[cs->v[i]->script] |= cs->v[i]->written;
    return have[0] && have[1];
}

int charts_finish(charts *cs, int commit)
{
    if (!cs)
        return 0;
    int bad = 0;
    for (int i = 0; i < cs->n; i++) {
        chart_file *f = cs->v[i];
        char err[1024];
        if (!commit) {
            file_replace_abort(&f->r);
        } else if (file_replace_commit(&f->r, ferror(f->r.f) ? EIO : 0, err, sizeof err)) {
            fprintf(stderr, "rtktool bench: %s\n", err);
            bad = 1;
        } else {
            f->written = 1;
        }
    }
    const int gnuplot = commit && cs->n && have_gnuplot();
    for (int i = 0; commit && i < cs->n; i++) {
        const chart_file *f = cs->v[i];
        if (!f->script) /* each chart once, at its script */
            continue;
        const char *why = "gnuplot is not installed";
        if (!chart_whole(cs, f->name))
            printf("chart: %s/%s not drawn (its files were not written)\n", cs->outdir, f->name);
        else if (gnuplot && draw(cs->outdir, f->name, &why))
            printf("chart: %s/%s.png\n", cs->outdir, f->name);
        else
            printf("chart: %s/%s.gp not drawn (%s)\n", cs->outdir, f->name, why);
    }
    for (int i = 0; i < cs->n; i++)
        free(cs->v[i]);
    free(cs->v);
    free(cs);
    return bad;
}
