#include "png_io.h"

#include "file_io.h"

#include <errno.h>
#include <png.h>
#include <setjmp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* (through file_replace: a failed write leaves the old image as it was) */
int rtk_png_write_rgb(const char *path, const unsigned char *rgb, int w, int h, char *err, size_t err_size)
{
    file_replace r;
    if (file_replace_open(&r, path, err, err_size))
        return 1;
    FILE *f = r.f;
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
    png_infop info = png ? png_create_info_struct(png) : NULL;
    if (!png || !info || setjmp(png_jmpbuf(png))) {
        png_destroy_write_struct(&png, &info);
        file_replace_abort(&r);
        snprintf(err, err_size, "%s: libpng could not write the image (the previous file, if any, is unchanged)",
                 path);
        return 1;
    }
    png_init_io(png, f);
    png_set_IHDR(png, info, (png_uint_32)w, (png_uint_32)h, 8, PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    for (int y = 0; y < h; y++)
        png_write_row(png, (png_const_bytep)(rgb + (size_t)y * (size_t)w * 3));
    png_write_end(png, NULL);
    png_destroy_write_struct(&png, &info);
    return file_replace_commit(&r, ferror(f) ? EIO : 0, err, err_size);
}

/* libpng's own messages go to stderr; ours name the file instead. */
static void quiet_error(png_structp png, png_const_charp msg)
{
    char *why = png_get_error_ptr(png);
    snprintf(why, 128, "%s", msg);
    png_longjmp(png, 1);
}

static void quiet_warning(png_structp png, png_const_charp msg)
{
    (void)png;
    (void)msg;
}

int rtk_png_read_rgb(const char *path, unsigned char **rgb, int *w, int *h, char *err, size_t err_size)
{
    *rgb = NULL;
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(err, err_size, "%s: %s", path, strerror(errno));
        return 1;
    }
    char why[128] = "";
    png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, why, quiet_error, quiet_warning);
    png_infop info = png ? png_create_info_struct(png) : NULL;
    unsigned char *volatile out = NULL;
    png_bytep *volatile rows = NULL;
    if (!png || !info || setjmp(png_jmpbuf(png))) {
        png_destroy_read_struct(&png, &info, NULL);
        fclose(f);
        free(out);
        free(rows);
        snprintf(err, err_size, "%s: not a PNG libpng can read (%s)", path, why[0] ? why : "no memory");
        return 1;
    }
    png_init_io(png, f);
    png_read_info(png, info);
    /* everything to 8-bit RGB */
    png_set_strip_16(png);
    png_set_strip_alpha(png);
    png_set_packing(png);
    png_set_expand(png);
    png_set_gray_to_rgb(png);
    png_set_interlace_handling(png);
    png_read_update_info(png, info);
    const png_uint_32 pw = png_get_image_width(png, info), ph = png_get_image_height(png, info);
    if (png_get_rowbytes(png, info) != (size_t)pw * 3 || pw > 65536 || ph > 65536) {
        png_destroy_read_struct(&png, &info, NULL);
        fclose(f);
        snprintf(err, err_size, "%s: unexpected PNG layout", path);
        return 1;
    }
    out = malloc((size_t)pw * ph * 3 + 1);
    rows = malloc((ph + 1) * sizeof *rows);
    if (!out || !rows)
        png_error(png, "out of memory");
    for (png_uint_32 y = 0; y < ph; y++)
        rows[y] = (png_bytep)(out + (size_t)y * pw * 3);
    png_read_image(png, rows);
    png_read_end(png, NULL);
    free(rows);
    png_destroy_read_struct(&png, &info, NULL);
    fclose(f);
    *rgb = out;
    *w = (int)pw;
    *h = (int)ph;
    return 0;
}
