/* See file_io.h. */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE /* mkostemp */
#endif
#include "file_io.h"

#include <errno.h>
#include <fcntl.h>
#include <libgen.h>
#include <limits.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

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

int file_replace_open(file_replace *r, const char *path, char *err, size_t err_size)
{
    memset(r, 0, sizeof *r);
    r->path = path;
    char dir_buf[PATH_MAX], base_buf[PATH_MAX];
    if (snprintf(dir_buf, sizeof dir_buf, "%s", path) >= (int)sizeof dir_buf ||
        snprintf(base_buf, sizeof base_buf, "%s", path) >= (int)sizeof base_buf)
        return file_error(err, err_size, "%s: path too long", path);
    const char *dir = dirname(dir_buf), *base = basename(base_buf);
    if (snprintf(r->tmp, sizeof r->tmp, "%s/.%s.XXXXXX", dir, base) >= (int)sizeof r->tmp)
        return file_error(err, err_size, "%s: path too long", path);
    const int fd = mkostemp(r->tmp, O_CLOEXEC);
    if (fd < 0)
        return file_error(err, err_size, "%s: cannot create a file beside it to write into: %s", path,
                          strerror(errno));
    /* the new file gets the old one's permissions, or those a new file
     * would get (mkostemp makes it 0600) */
    struct stat st;
    mode_t mode;
    if (stat(path, &st) == 0) {
        mode = st.st_mode & 07777;
    } else {
        const mode_t mask = umask(0);
        umask(mask);
        mode = 0666 & ~mask;
    }
    if (fchmod(fd, mode) != 0 || !(r->f = fdopen(fd, "wb"))) {
        const int e = errno;
        close(fd);
        unlink(r->tmp);
        return file_error(err, err_size, "%s: %s", path, strerror(e));
    }
    return 0;
}

void file_replace_abort(file_replace *r)
{
    if (r->f)
        fclose(r->f);
    r->f = NULL;
    unlink(r->tmp);
}

int file_replace_commit(file_replace *r, int write_errno, char *err, size_t err_size)
{
    int e = write_errno;
    if (!e && fflush(r->f) != 0)
        e = errno ? errno : EIO;
    if (!e && fsync(fileno(r->f)) != 0)
        e = errno;
    if (fclose(r->f) != 0 && !e)
        e = errno ? errno : EIO;
    r->f = NULL;
    if (!e && rename(r->tmp, r->path) != 0)
        e = errno;
    if (e) {
        unlink(r->tmp);
        return file_error(err, err_size, "%s: write failed: %s (the previous file, if any, is unchanged)", r->path,
                          strerror(e));
    }
    /* the rename itself to disk: the directory synced (best effort) */
    char dir_buf[PATH_MAX];
    snprintf(dir_buf, sizeof dir_buf, "%s", r->path);
    const int dfd = open(dirname(dir_buf), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (dfd >= 0) {
        fsync(dfd);
        close(dfd);
    }
    return 0;
}

int file_write_parts(const char *path, const file_part *parts, int count, char *err, size_t err_size)
{
    file_replace r;
    if (file_replace_open(&r, path, err, err_size))
        return 1;
    static const unsigned char zeros[256];
    uint64_t pos = 0;
    int ok = 1;
    errno = 0;
    for (int i = 0; i < count && ok; i++) {
        for (uint64_t gap = parts[i].offset - pos; gap && ok;) {
            const size_t n = gap < sizeof zeros ? (size_t)gap : sizeof zeros;
            ok = fwrite(zeros, 1, n, r.f) == n;
            gap -= n;
        }
        ok = ok && (!parts[i].size || fwrite(parts[i].data, 1, parts[i].size, r.f) == parts[i].size);
        pos = parts[i].offset + parts[i].size;
    }
    return file_replace_commit(&r, ok ? 0 : errno ? errno : EIO, err, err_size);
}
