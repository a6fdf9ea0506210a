/*
 * Settings of the avx2 backend beyond its compiler flags and CPU requirements
 * (both in CMakeLists.txt, rtk_add_backend).  Define RTK_OVERRIDE_* here to
 * replace a common kernel with a hand-tuned one (see
 * backends/common/backend_entry.c); none is needed yet.
 */
#ifndef RTK_BACKEND_CONFIG_H
#define RTK_BACKEND_CONFIG_H
#endif
