/* PNG files through libpng: rtktool's pictures, and the reference images
 * the renderer's tests compare with. */
#ifndef RTK_TOOLS_PNG_IO_H
#define RTK_TOOLS_PNG_IO_H
#include <stddef.h>

/* Writes 8-bit RGB rows (w * 3 bytes each); 0 on success, else err says why. */
int rtk_png_write_rgb(const char *path, const unsigned char *rgb, int w, int h, char *err, size_t err_size);
/* Reads a PNG of any colour type and depth as 8-bit RGB rows into a new
 * buffer (*rgb, free it) of *w x *h pixels; 0, else err says why. */
int rtk_png_read_rgb(const char *path, unsigned char **rgb, int *w, int *h, char *err, size_t err_size);
#endif
