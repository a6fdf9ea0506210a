/* PNG output through libpng, for rtktool's pictures. */
#ifndef RTK_TOOLS_PNG_WRITE_H
#define RTK_TOOLS_PNG_WRITE_H
#include <stddef.h>

/* Writes 8-bit RGB rows (w * 3 bytes each); 0 on success, else err says why. */
int rtk_png_write_rgb(const char *path, const unsigned char *rgb, int w, int h, char *err, size_t err_size);
#endif
