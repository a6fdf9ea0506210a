/*
 * Backend discovery, checking, negotiation and selection.
 *
 * Search order (GStreamer's): RTK_BACKEND_PATH (read with secure_getenv, so a
 * setuid program ignores it), then <directory of librtk>/rtk (found with
 * dladdr), then the compiled-in install directory.  The config key
 * backend_path= replaces the whole order.  Within a directory files are taken
 * in name order; a backend name already found earlier is shadowed.
 *
 * For each file: check that it is a whole ELF shared object (elf_whole: a
 * cut file would be SIGBUS inside dlopen); dlopen(RTLD_NOW | RTLD_LOCAL); read the data symbol
 * rtk_backend_<name>_header (no backend code runs); check magic, size, name
 * and the CPU requirements against this CPU; only then call
 * rtk_backend_<name>_negotiate and check the answer and the descriptor tables.
 * Every file gets one line of verdict (shown with verbose=1).
 */
#include <dirent.h>
#include <dlfcn.h>
#include <elf.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <link.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "internal.h"

#ifndef RTK_INSTALL_BACKEND_DIR
#define RTK_INSTALL_BACKEND_DIR "/usr/local/lib/rtk"
#endif

#define FILE_PREFIX "librtk_backend_"
#define FILE_SUFFIX ".so"

/* The oldest and newest backend interface versions this core speaks: 2
 * only, since version 2 changed the kernels' signature (rtk_query). */
#define CORE_INTERFACE_MIN 2
#define CORE_INTERFACE_MAX RTK_BACKEND_INTERFACE_VERSION

/* The smallest descriptor/header a version-1 backend may declare. */
#define HEADER_MIN_SIZE (offsetof(rtk_backend_header, cpu_requires) + sizeof(uint64_t))
#define DESC_V1_SIZE (offsetof(rtk_backend_desc, kernels) + sizeof(void *))

typedef struct strlist {
    char **items;
    size_t count;
} strlist;

static int strlist_push(strlist *l, const char *s)
{
    char **n = realloc(l->items, (l->count + 1) * sizeof *n);
    if (!n)
        return 0;
    l->items = n;
    if (!(l->items[l->count] = strdup(s)))
        return 0;
    l->count++;
    return 1;
}

static void strlist_free(strlist *l)
{
    for (size_t i = 0; i < l->count; i++)
        free(l->items[i]);
    free(l->items);
    l->items = NULL;
    l->count = 0;
}

/* Adds each ':'-separated directory of path that is not already listed. */
static void add_dirs(strlist *dirs, const char *path)
{
    const char *p = path;
    while (p && *p) {
        const char *end = strchr(p, ':');
        size_t n = end ? (size_t)(end - p) : strlen(p);
        if (n > 0 && n < PATH_MAX) {
            char dir[PATH_MAX];
            memcpy(dir, p, n);
            dir[n] = '\0';
            int seen = 0;
            for (size_t i = 0; i < dirs->count; i++)
                seen |= !strcmp(dirs->items[i], dir);
            if (!seen)
                strlist_push(dirs, dir);
        }
        p = end ? end + 1 : NULL;
    }
}

static void search_dirs(const rtk_config *cfg, strlist *dirs)
{
    if (cfg->backend_path) {
        add_dirs(dirs, cfg->backend_path);
        return;
    }
    add_dirs(dirs, secure_getenv("RTK_BACKEND_PATH"));
    Dl_info info;
    if (dladdr((void *)&rtk_device_new, &info) && info.dli_fname) {
        char buf[PATH_MAX];
        snprintf(buf, sizeof buf, "%s", info.dli_fname);
        char *slash = strrchr(buf, '/');
        if (slash) {
            snprintf(slash, sizeof buf - (size_t)(slash - buf), "/rtk");
            add_dirs(dirs, buf);
        }
    }
    add_dirs(dirs, RTK_INSTALL_BACKEND_DIR);
}

static int cmp_str(const void *a, const void *b)
{
    return strcmp(*(char *const *)a, *(char *const *)b);
}

/* Backend files of one directory, sorted. */
static void list_dir(const char *dir, strlist *files)
{
    DIR *d = opendir(dir);
    if (!d)
        return;
    struct dirent *e;
    while ((e = readdir(d))) {
        size_t n = strlen(e->d_name);
        if (n > strlen(FILE_PREFIX) + strlen(FILE_SUFFIX) && !strncmp(e->d_name, FILE_PREFIX, strlen(FILE_PREFIX)) &&
            !strcmp(e->d_name + n - strlen(FILE_SUFFIX), FILE_SUFFIX)) {
            char path[PATH_MAX];
            snprintf(path, sizeof path, "%s/%s", dir, e->d_name);
            strlist_push(files, path);
        }
    }
    closedir(d);
    if (files->count)
        qsort(files->items, files->count, sizeof *files->items, cmp_str);
}

static rtk_backend_entry *add_entry(rtk_backend_registry *reg, const char *path)
{
    rtk_backend_entry *n = realloc(reg->entries, (reg->count + 1) * sizeof *n);
    if (!n)
        return NULL;
    reg->entries = n;
    rtk_backend_entry *e = &reg->entries[reg->count];
    memset(e, 0, sizeof *e);
    if (!(e->path = strdup(path)))
        return NULL;
    e->status = RTK_BACKEND_STATUS_REJECTED;
    reg->count++;
    return e;
}

static void reject(rtk_backend_entry *e, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void reject(rtk_backend_entry *e, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(e->reason, sizeof e->reason, fmt, ap);
    va_end(ap);
    e->status = RTK_BACKEND_STATUS_REJECTED;
    if (e->handle)
        dlclose(e->handle);
    e->handle = NULL;
    e->desc = NULL;
}

static int has_kernel(const rtk_kernel_entry *k, uint32_t layout, uint32_t query)
{
    for (; k->layout; k++)
        if (k->layout == layout && k->query == query && k->width == 1 && k->fn.any)
            return 1;
    return 0;
}

/* Checks the tables a backend handed over: no empty slot anywhere. */
static int check_tables(rtk_backend_entry *e, const rtk_backend_desc *d)
{
    if (!d->builders || !d->builders[0].name || !d->layouts || !d->layouts[0].id || !d->kernels) {
        reject(e, "descriptor has no builders, layouts or kernels");
        return 0;
    }
    for (const rtk_layout_entry *l = d->layouts; l->id; l++) {
        if (!l->name || !l->release) {
            reject(e, "layout %u has no name or release function", l->id);
            return 0;
        }
        if (!has_kernel(d->kernels, l->id, RTK_QUERY_INTERSECT) || !has_kernel(d->kernels, l->id, RTK_QUERY_OCCLUDED)) {
            reject(e, "layout %s lacks a width-1 intersect or occluded kernel", l->name);
            return 0;
        }
    }
    for (const rtk_kernel_entry *k = d->kernels; k->layout; k++)
        if (!k->fn.any) {
            reject(e, "kernel for layout %u, query %u, width %u has no function", k->layout, k->query, k->width);
            return 0;
        }
    for (const rtk_builder_entry *b = d->builders; b->name; b++) {
        if (!b->build || !rtk_backend_find_layout(d, b->layout)) {
            reject(e, "builder %s has no build function or produces an unknown layout", b->name);
            return 0;
        }
    }
    if (RTK_DESC_HAS(d, layout_io))
        for (const rtk_layout_io_entry *io = d->layout_io; io->layout; io++) {
            if (!io->export_tree || !io->import_tree || !rtk_backend_find_layout(d, io->layout)) {
                reject(e, "tree import/export for layout %u lacks a function or the layout", io->layout);
                return 0;
            }
        }
    if (RTK_DESC_HAS(d, objects))
        for (const rtk_objects_entry *o = d->objects; o->layout; o++)
            if (!o->build || !rtk_backend_find_layout(d, o->layout)) {
                reject(e, "the objects builder for layout %u lacks a function or the layout", o->layout);
                return 0;
            }
    if (RTK_DESC_HAS(d, motion_builders))
        for (const rtk_builder_entry *b = d->motion_builders; b->name; b++)
            if (!b->build || !rtk_backend_find_layout(d, b->layout)) {
                reject(e, "motion builder %s has no build function or produces an unknown layout", b->name);
                return 0;
            }
    if (RTK_DESC_HAS(d, layout_refit))
        for (const rtk_layout_refit_entry *rf = d->layout_refit; rf->layout; rf++) {
            if (!rf->refit || !rtk_backend_find_layout(d, rf->layout)) {
                reject(e, "refit for layout %u lacks a function or the layout", rf->layout);
                return 0;
            }
        }
    return 1;
}

/* Whether the file is whole, checked before dlopen maps it: an ELF shared
 * object of this machine's class whose program headers, every segment's
 * bytes and its section headers lie within the file.  The dynamic loader
 * maps segments without checking them against the file's size, and the
 * first touch of a page past the end of a cut file (an install or upgrade
 * interrupted) is SIGBUS, which would take the application down at
 * device creation.  0 with the reason in why.  (A file cut while this
 * runs is not caught: that race is the installer's.) */
static int elf_whole(const char *path, char *why, size_t why_size)
{
    const int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0) {
        snprintf(why, why_size, "cannot open: %s", strerror(errno));
        return 0;
    }
    int ok = 0;
    struct stat st;
    ElfW(Ehdr) eh;
    if (fstat(fd, &st) != 0) {
        snprintf(why, why_size, "cannot stat: %s", strerror(errno));
    } else if (!S_ISREG(st.st_mode)) {
        snprintf(why, why_size, "not a regular file");
    } else if (st.st_size < (off_t)sizeof eh || pread(fd, &eh, sizeof eh, 0) != (ssize_t)sizeof eh) {
        snprintf(why, why_size, "truncated or damaged: %lld bytes, too short for an ELF header",
                 (long long)st.st_size);
    } else if (memcmp(eh.e_ident, ELFMAG, SELFMAG) != 0) {
        snprintf(why, why_size, "not an ELF file");
    } else if (eh.e_ident[EI_CLASS] != (sizeof(void *) == 8 ? ELFCLASS64 : ELFCLASS32) ||
               eh.e_type != ET_DYN || eh.e_phentsize != sizeof(ElfW(Phdr))) {
        snprintf(why, why_size, "not a shared object of this machine's ELF class");
    } else {
        const uint64_t size = (uint64_t)st.st_size;
        const uint64_t ph_end = (uint64_t)eh.e_phoff + (uint64_t)eh.e_phnum * sizeof(ElfW(Phdr));
        const uint64_t sh_end = (uint64_t)eh.e_shoff + (uint64_t)eh.e_shnum * (uint64_t)eh.e_shentsize;
        if (ph_end > size) {
            snprintf(why, why_size, "truncated or damaged: its program headers end at byte %llu, the file has %llu",
                     (unsigned long long)ph_end, (unsigned long long)size);
        } else if (eh.e_shnum && sh_end > size) {
            snprintf(why, why_size, "truncated or damaged: its section headers end at byte %llu, the file has %llu",
                     (unsigned long long)sh_end, (unsigned long long)size);
        } else {
            ok = 1;
            for (unsigned i = 0; ok && i < eh.e_phnum; i++) {
                ElfW(Phdr) ph;
                if (pread(fd, &ph, sizeof ph, (off_t)(eh.e_phoff + i * sizeof ph)) != (ssize_t)sizeof ph) {
                    snprintf(why, why_size, "cannot read program header %u", i);
                    ok = 0;
                } else if (ph.p_type != PT_NULL && (ph.p_offset > size || ph.p_filesz > size - ph.p_offset)) {
                    snprintf(why, why_size,
                             "truncated or damaged: segment %u (type %u) ends at byte %llu, the file has %llu", i,
                             (unsigned)ph.p_type, (unsigned long long)ph.p_offset + (unsigned long long)ph.p_filesz,
                             (unsigned long long)size);
                    ok = 0;
                }
            }
        }
    }
    close(fd);
    return ok;
}

static void load_one(rtk_backend_entry *e, uint64_t cpu)
{
    const char *base = strrchr(e->path, '/');
    base = base ? base + 1 : e->path;
    size_t n = strlen(base) - strlen(FILE_PREFIX) - strlen(FILE_SUFFIX);
    if (n >= RTK_BACKEND_NAME_MAX) {
        reject(e, "file name too long for a backend name");
        return;
    }
    memcpy(e->name, base + strlen(FILE_PREFIX), n);
    e->name[n] = '\0';

    char why[sizeof e->reason - 16];
    if (!elf_whole(e->path, why, sizeof why)) {
        reject(e, "%s", why);
        return;
    }
    dlerror();
    e->handle = dlopen(e->path, RTLD_NOW | RTLD_LOCAL);
    if (!e->handle) {
        const char *err = dlerror();
        reject(e, "dlopen failed: %s", err ? err : "unknown reason");
        return;
    }

    char sym[128];
    snprintf(sym, sizeof sym, "rtk_backend_%s_header", e->name);
    const rtk_backend_header *h = dlsym(e->handle, sym);
    if (!h) {
        reject(e, "not an rtk backend: no symbol %s", sym);
        return;
    }
    if (h->magic != RTK_BACKEND_MAGIC) {
        reject(e, "symbol %s has the wrong magic 0x%08x", sym, h->magic);
        return;
    }
    if (h->struct_size < HEADER_MIN_SIZE) {
        reject(e, "header too small: %u bytes, at least %zu needed", h->struct_size, (size_t)HEADER_MIN_SIZE);
        return;
    }
    if (strncmp(h->name, e->name, RTK_BACKEND_NAME_MAX) != 0) {
        reject(e, "header names the backend '%.*s' but the file is named for '%s'", RTK_BACKEND_NAME_MAX, h->name,
               e->name);
        return;
    }
    e->level = h->level;
    e->header_version = h->interface_version;
    e->cpu_requires = h->cpu_requires;
    uint64_t missing = h->cpu_requires & ~cpu;
    if (missing) {
        char names[256];
        rtk_cpu_features_string(missing, names, sizeof names);
        reject(e, "this CPU lacks %s, which the backend requires", names);
        return;
    }

    /* Only now may backend code run. */
    snprintf(sym, sizeof sym, "rtk_backend_%s_negotiate", e->name);
    rtk_backend_negotiate_fn negotiate;
    *(void **)&negotiate = dlsym(e->handle, sym);
    if (!negotiate) {
        reject(e, "missing entry point %s", sym);
        return;
    }
    rtk_backend_offer offer = {
        .struct_size = sizeof offer,
        .version_max = CORE_INTERFACE_MAX,
        .version_min = CORE_INTERFACE_MIN,
        .cpu_features = cpu,
    };
    rtk_backend_answer answer = {.struct_size = sizeof answer};
    if (negotiate(&offer, &answer) != 0) {
        /* (the header's interface_version only names the backend's side) */
        const uint32_t v = e->header_version;
        if (v)
            reject(e, "refused to negotiate: the backend speaks backend interface version %u, this core (rtk %s) "
                   "versions %d to %d", v, RTK_VERSION_STRING, CORE_INTERFACE_MIN, CORE_INTERFACE_MAX);
        else
            reject(e, "refused to negotiate: the backend predates rtk 0.2.0 (backend interface version 1), this "
                   "core (rtk %s) speaks versions %d to %d", RTK_VERSION_STRING, CORE_INTERFACE_MIN,
                   CORE_INTERFACE_MAX);
        return;
    }
    if (answer.version < CORE_INTERFACE_MIN || answer.version > CORE_INTERFACE_MAX) {
        reject(e, "answered backend interface version %u; the core speaks versions %d to %d", answer.version,
               CORE_INTERFACE_MIN, CORE_INTERFACE_MAX);
        return;
    }
    e->interface_version = answer.version;
    const rtk_backend_desc *d = answer.desc;
    if (!d) {
        reject(e, "negotiation returned no descriptor");
        return;
    }
    if (d->struct_size < DESC_V1_SIZE) {
        reject(e, "descriptor too small: %u bytes, interface version %u needs at least %zu", d->struct_size,
               answer.version, (size_t)DESC_V1_SIZE);
        return;
    }
    if (!check_tables(e, d))
        return;
    e->desc = d;
    e->status = RTK_BACKEND_STATUS_USABLE;
}

static void append(char *buf, size_t size, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static void append(char *buf, size_t size, const char *fmt, ...)
{
    size_t len = strlen(buf);
    if (len + 1 >= size)
        return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf + len, size - len, fmt, ap);
    va_end(ap);
}

/* "scalar, sse41" for the usable backends. */
static void usable_names(const rtk_backend_registry *reg, char *buf, size_t size)
{
    buf[0] = '\0';
    for (size_t i = 0; i < reg->count; i++)
        if (reg->entries[i].status != RTK_BACKEND_STATUS_REJECTED)
            append(buf, size, "%s%s", buf[0] ? ", " : "", reg->entries[i].name);
    if (!buf[0])
        snprintf(buf, size, "none");
}

static void rejections(const rtk_backend_registry *reg, char *buf, size_t size)
{
    for (size_t i = 0; i < reg->count; i++)
        if (reg->entries[i].status == RTK_BACKEND_STATUS_REJECTED)
            append(buf, size, "; %s: %s", reg->entries[i].path, reg->entries[i].reason);
}

rtk_error rtk_backends_load(rtk_backend_registry *reg, const rtk_config *cfg, uint64_t cpu, char *msg,
                            size_t msg_size)
{
    memset(reg, 0, sizeof *reg);
    reg->active = -1;
    strlist dirs = {0};
    search_dirs(cfg, &dirs);

    size_t joined = 1;
    for (size_t i = 0; i < dirs.count; i++)
        joined += strlen(dirs.items[i]) + 1;
    reg->search_path = calloc(1, joined);
    if (!reg->search_path) {
        strlist_free(&dirs);
        snprintf(msg, msg_size, "out of memory");
        return RTK_ERROR_OUT_OF_MEMORY;
    }
    for (size_t i = 0; i < dirs.count; i++) {
        if (i)
            strcat(reg->search_path, ":");
        strcat(reg->search_path, dirs.items[i]);
    }

    for (size_t di = 0; di < dirs.count; di++) {
        strlist files = {0};
        list_dir(dirs.items[di], &files);
        for (size_t fi = 0; fi < files.count; fi++) {
            rtk_backend_entry *e = add_entry(reg, files.items[fi]);
            if (!e)
                continue;
            const char *shadow = NULL;
            const char *base = strrchr(e->path, '/') + 1;
            for (size_t k = 0; k + 1 < reg->count && !shadow; k++) {
                const char *other = strrchr(reg->entries[k].path, '/') + 1;
                if (!strcmp(other, base))
                    shadow = reg->entries[k].path;
            }
            if (shadow) {
                size_t n = strlen(base) - strlen(FILE_PREFIX) - strlen(FILE_SUFFIX);
                snprintf(e->name, sizeof e->name, "%.*s", (int)n, base + strlen(FILE_PREFIX));
                reject(e, "shadowed by %s, found earlier in the search path", shadow);
            } else {
                load_one(e, cpu);
            }
        }
        strlist_free(&files);
    }
    strlist_free(&dirs);

    /* Narrowing: isa= and RTK_ISA name one backend, max_isa= caps the level. */
    const char *env_isa = secure_getenv("RTK_ISA");
    const char *want[2] = {cfg->isa[0] ? cfg->isa : NULL, env_isa && env_isa[0] ? env_isa : NULL};
    const char *want_src[2] = {"isa", "RTK_ISA"};
    int max_level = -1;
    if (cfg->max_isa[0]) {
        max_level = rtk_isa_level(cfg->max_isa);
        for (size_t i = 0; i < reg->count && max_level < 0; i++)
            if (reg->entries[i].status != RTK_BACKEND_STATUS_REJECTED && !strcmp(reg->entries[i].name, cfg->max_isa))
                max_level = (int)reg->entries[i].level;
        if (max_level < 0) {
            snprintf(msg, msg_size, "max_isa=%s: not a known ISA level (scalar, sse41, avx, avx2, avx512)",
                     cfg->max_isa);
            return RTK_ERROR_INVALID_CONFIG;
        }
    }
    if (want[0] && want[1] && strcmp(want[0], want[1]) != 0) {
        snprintf(msg, msg_size, "isa=%s conflicts with RTK_ISA=%s: each may only narrow the choice", want[0], want[1]);
        return RTK_ERROR_INVALID_CONFIG;
    }

    int best = -1;
    for (size_t i = 0; i < reg->count; i++) {
        rtk_backend_entry *e = &reg->entries[i];
        if (e->status == RTK_BACKEND_STATUS_REJECTED)
            continue;
        int excluded = 0;
        for (int w = 0; w < 2; w++)
            if (want[w] && strcmp(want[w], e->name) != 0) {
                snprintf(e->reason, sizeof e->reason, "not chosen: %s=%s", want_src[w], want[w]);
                excluded = 1;
            }
        if (!excluded && max_level >= 0 && (int)e->level > max_level) {
            snprintf(e->reason, sizeof e->reason, "not chosen: above max_isa=%s", cfg->max_isa);
            excluded = 1;
        }
        if (excluded)
            continue;
        if (best < 0 || e->level > reg->entries[best].level)
            best = (int)i;
    }
    for (size_t i = 0; i < reg->count; i++) {
        rtk_backend_entry *e = &reg->entries[i];
        if (e->status == RTK_BACKEND_STATUS_USABLE && (int)i != best) {
            if (!e->reason[0])
                snprintf(e->reason, sizeof e->reason, "not chosen: %s is preferred", reg->entries[best].name);
            if (e->handle)
                dlclose(e->handle);
            e->handle = NULL;
            e->desc = NULL;
        }
    }
    if (best < 0) {
        char names[256];
        usable_names(reg, names, sizeof names);
        msg[0] = '\0';
        const char *w = want[0] ? want[0] : want[1];
        if (w)
            append(msg, msg_size, "%s=%s: no such usable backend; usable: %s. ", want[0] ? "isa" : "RTK_ISA", w, names);
        else if (max_level >= 0 && strcmp(names, "none") != 0)
            append(msg, msg_size, "max_isa=%s excludes every usable backend (%s). ", cfg->max_isa, names);
        else
            append(msg, msg_size, "no usable rtk backend. ");
        append(msg, msg_size, "Searched: %s", reg->search_path[0] ? reg->search_path : "(no directories)");
        if (reg->count == 0)
            append(msg, msg_size, "; no librtk_backend_*.so files there");
        rejections(reg, msg, msg_size);
        /* Asking for a backend the CPU cannot run is its own kind of failure. */
        for (size_t i = 0; w && i < reg->count; i++)
            if (!strcmp(reg->entries[i].name, w) && reg->entries[i].status == RTK_BACKEND_STATUS_REJECTED &&
                (reg->entries[i].cpu_requires & ~cpu))
                return RTK_ERROR_UNSUPPORTED_CPU;
        return RTK_ERROR_NO_BACKEND;
    }
    reg->active = best;
    reg->entries[best].status = RTK_BACKEND_STATUS_ACTIVE;
    reg->entries[best].reason[0] = '\0';
    return RTK_OK;
}

void rtk_backends_unload(rtk_backend_registry *reg)
{
    for (size_t i = 0; i < reg->count; i++) {
        if (reg->entries[i].handle)
            dlclose(reg->entries[i].handle);
        free(reg->entries[i].path);
    }
    free(reg->entries);
    free(reg->search_path);
    memset(reg, 0, sizeof *reg);
    reg->active = -1;
}

const rtk_layout_entry *rtk_backend_find_layout(const rtk_backend_desc *d, uint32_t id)
{
    for (const rtk_layout_entry *l = d->layouts; l->id; l++)
        if (l->id == id)
            return l;
    return NULL;
}
