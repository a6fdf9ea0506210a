/* A progress bar on stderr for long work: drawn only when stderr is a
 * terminal and the work has taken more than a second, erased at the end. */
#ifndef RTK_TOOLS_PROGRESS_H
#define RTK_TOOLS_PROGRESS_H

typedef struct progress {
    const char *label;
    int enabled, drawn;
    double start;
} progress;

void progress_begin(progress *p, const char *label);
/* done: the share finished, 0..1 */
void progress_update(progress *p, double done);
void progress_end(progress *p);

#endif
