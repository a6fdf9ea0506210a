/* rtktool bench: rtk beside Embree 3 (built only with Embree present). */
#ifndef RTK_TOOLS_BENCH_H
#define RTK_TOOLS_BENCH_H
int cmd_bench(int argc, char **argv);
#endif
