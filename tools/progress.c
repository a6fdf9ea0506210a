#define _POSIX_C_SOURCE 200809L
#include "progress.h"

#include <stdio.h>
#include <time.h>
#include <unistd.h>

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

void progress_begin(progress *p, const char *label)
{
    *p = (progress){.label = label, .enabled = isatty(STDERR_FILENO), .start = now()};
}

void progress_update(progress *p, double done)
{
    const double el = now() - p->start;
    if (!p->enabled || el < 1.0)
        return;
    done = done < 0.0 ? 0.0 : done > 1.0 ? 1.0 : done;
    char bar[41];
    const int fill = (int)(done * 40.0);
    for (int i = 0; i < 40; i++)
        bar[i] = i < fill ? '#' : '.';
    bar[40] = 0;
    if (done > 0.0)
        fprintf(stderr, "\r%s [%s] %3.0f%%  %.0f s left  ", p->label, bar, 100.0 * done, el / done - el);
    else
        fprintf(stderr, "\r%s [%s] %3.0f%%  ", p->label, bar, 0.0);
    fflush(stderr);
    p->drawn = 1;
}

void progress_end(progress *p)
{
    if (p->drawn)
        fprintf(stderr, "\r\033[K");
    p->drawn = 0;
}
