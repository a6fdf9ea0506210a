/* What rtk's two file formats (.rtkm, .rtkb) share: errors naming the file
 * and the problem, and writing a header and arrays at aligned offsets. */
#ifndef RTK_TOOLS_FILE_IO_H
#define RTK_TOOLS_FILE_IO_H
#include <stddef.h>
#include <stdint.h>

/* Formats the message into err (when given) and returns 1. */
int file_error(char *err, size_t size, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

typedef struct file_part {
    const void *data;
    uint64_t offset, size; /* ascending offsets, not overlapping */
} file_part;

/* Writes the parts at their offsets with zero bytes between, replacing
 * path (removed again if anything fails); 0, or non-zero with err. */
int file_write_parts(const char *path, const file_part *parts, int count, char *err, size_t err_size);
#endif
