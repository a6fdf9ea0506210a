/* See file_io.h. */
#include "file_io.h"

#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

int file_error(char *err, size_t size, const char *fmt, ...)
{
    if (err && size) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(err, size, fmt, ap);
        va_end(ap);
    }
    return 1;
}

int file_write_parts(const char *path, const file_part *parts, int count, char *err, size_t err_size)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return file_error(err, err_size, "%s: %s", path, strerror(errno));
    static const unsigned char zeros[256];
    uint64_t pos = 0;
    int ok = 1;
    errno = 0;
    for (int i = 0; i < count && ok; i++) {
        for (uint64_t gap = parts[i].offset - pos; gap && ok;) {
            const size_t n = gap < sizeof zeros ? (size_t)gap : sizeof zeros;
            ok = fwrite(zeros, 1, n, f) == n;
            gap -= n;
        }
        ok = ok && (!parts[i].size || fwrite(parts[i].data, 1, parts[i].size, f) == parts[i].size);
        pos = parts[i].offset + parts[i].size;
    }
    const int saved_errno = errno;
    if (fclose(f) != 0)
        ok = 0;
    if (!ok) {
        remove(path);
        return file_error(err, err_size, "%s: write failed: %s", path, strerror(saved_errno ? saved_errno : EIO));
    }
    return 0;
}
