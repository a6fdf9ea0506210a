/*
 * Included first by every file of backends/common/.  These files are compiled
 * once per backend with -DRTK_BACKEND_NAME=<name>, that backend's ISA flags and
 * its own directory first on the include path (for backend_config.h), and are
 * never built alone.  Every internal symbol carries the backend's suffix (as
 * dav1d's *_tmpl.c files do), so two backends linked into one program never
 * collide, and profiles say which ISA ran.
 */
#ifndef RTK_BACKEND_COMMON_H
#define RTK_BACKEND_COMMON_H

#ifndef RTK_BACKEND_NAME
#error "backends/common is compiled per backend: define RTK_BACKEND_NAME"
#endif

#include "backend_config.h" /* from the backend's own directory */

#define RTK_CAT_(a, b) a##b
#define RTK_CAT(a, b) RTK_CAT_(a, b)
#define RTK_STR_(a) #a
#define RTK_STR(a) RTK_STR_(a)
/* name -> name_<backend> */
#define RTK_SYM(name) RTK_CAT(RTK_CAT(name, _), RTK_BACKEND_NAME)

#define RTK_HIDDEN __attribute__((visibility("hidden")))

/* A direction component below this in magnitude is a zero direction to the
 * box tests: its near planes' reciprocal is clamped to +-1e18 (as Embree
 * does), its far planes' is +-inf (traverse_bvhn.h ray_pre_init_v), and on
 * FMA backends such a ray takes the subtract-then-multiply test. */
#define RTK_ZERO_DIR 1e-18f

#endif
