/* What rtk's two file formats (.rtkm, .rtkb) share: errors naming the file
 * and the problem, and writing a header and arrays at aligned offsets. */
#ifndef RTK_TOOLS_FILE_IO_H
#define RTK_TOOLS_FILE_IO_H
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

/* Formats the message into err (when given) and returns 1. */
int file_error(char *err, size_t size, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

typedef struct file_part {
    const void *data;
    uint64_t offset, size; /* ascending offsets, not overlapping */
} file_part;

/* Writes the parts at their offsets with zero bytes between, replacing
 * path through file_replace; 0, or non-zero with err. */
int file_write_parts(const char *path, const file_part *parts, int count, char *err, size_t err_size);

/* Replacing a file so that a failed write (a full disk, a file size
 * limit, an error of the caller's) loses nothing: the new contents go to
 * a temporary file beside it (same directory, so the same file system),
 * which is synced and renamed over the old one only once it is whole; on
 * failure it is removed and the old file stays as it was.  The new file
 * keeps the old one's permissions.
 *   file_replace_open: 0 with r->f open for writing, or non-zero with err;
 *   file_replace_commit: write_errno non-zero if a write failed (then it
 *     only cleans up); 0 once the file is in place, else non-zero with err;
 *   file_replace_abort: gives up (the caller's own error). */
typedef struct file_replace {
    FILE *f;
    const char *path;
    char tmp[4096 + 32]; /* (PATH_MAX and room for the temporary name) */
} file_replace;
int file_replace_open(file_replace *r, const char *path, char *err, size_t err_size);
int file_replace_commit(file_replace *r, int write_errno, char *err, size_t err_size);
void file_replace_abort(file_replace *r);
#endif
