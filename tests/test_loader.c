/* The backend loader: broken backends are rejected with a reason, good ones
 * still load, and selection only ever narrows what is there. */
#include <elf.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "rtk/rtk_backend.h"
#include "testlib.h"

static const rtk_backend_info *find(rtk_device dev, const char *name, rtk_backend_info *bi)
{
    for (size_t i = 0; i < rtk_device_get_backend_count(dev); i++) {
        bi->struct_size = sizeof *bi;
        assert_int_equal(rtk_device_get_backend_info(dev, i, bi), RTK_OK);
        if (!strcmp(bi->name, name))
            return bi;
    }
    fail_msg("backend %s not listed", name);
    return NULL;
}

static void expect_rejected(rtk_device dev, const char *name, const char *reason)
{
    rtk_backend_info bi;
    find(dev, name, &bi);
    assert_int_equal(bi.status, RTK_BACKEND_STATUS_REJECTED);
    if (!strstr(bi.reason, reason))
        fail_msg("backend %s: reason '%s' lacks '%s'", name, bi.reason, reason);
}

static void test_fixtures_rejected_good_ones_load(void **state)
{
    (void)state;
    rtk_device dev = NULL;
    rtk_error err = rtk_device_new("backend_path=" RTK_TEST_FIXTURES ":" RTK_TEST_BACKENDS, &dev);
    if (err)
        fail_msg("%s", rtk_device_get_error_message(NULL));
    /* a version mismatch names both sides' versions */
    expect_rejected(dev, "future", "refused to negotiate: the backend speaks backend interface version 99, this core "
                                   "(rtk " RTK_VERSION_STRING ") versions 2 to 2");
    expect_rejected(dev, "old", "refused to negotiate: the backend predates rtk 0.2.0 (backend interface version 1), "
                                "this core (rtk " RTK_VERSION_STRING ") speaks versions 2 to 2");
    expect_rejected(dev, "ancient", "answered backend interface version 0; the core speaks versions 2 to 2");
    expect_rejected(dev, "noentry", "missing entry point rtk_backend_noentry_negotiate");
    expect_rejected(dev, "smalldesc", "descriptor too small: 8 bytes");
    expect_rejected(dev, "nocpu", "this CPU lacks unknown(0x8000000000000000)");
    expect_rejected(dev, "noheader", "not an rtk backend: no symbol rtk_backend_noheader_header");
    expect_rejected(dev, "badmagic", "wrong magic");
    /* The CPU check comes before negotiation: no version was negotiated. */
    rtk_backend_info bi;
    assert_int_equal(find(dev, "nocpu", &bi)->interface_version, 0);
    /* The real backends load, and the best the CPU runs is active. */
    find(dev, "scalar", &bi);
    assert_true(bi.status != RTK_BACKEND_STATUS_REJECTED);
    assert_int_equal(bi.interface_version, RTK_BACKEND_INTERFACE_VERSION);
    const uint64_t cpu = rtk_cpu_features();
    const char *best = (cpu & RTK_CPU_AVX2) && (cpu & RTK_CPU_FMA) ? "avx2" : (cpu & RTK_CPU_AVX) ? "avx"
                       : (cpu & RTK_CPU_SSE41)                      ? "sse41"
                                                                    : "scalar";
    assert_string_equal(rtk_device_get_backend_name(dev), best);
    rtk_device_release(dev);
}

static void test_isa_selects_and_narrows(void **state)
{
    (void)state;
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new("isa=scalar", &dev), RTK_OK);
    assert_string_equal(rtk_device_get_backend_name(dev), "scalar");
    rtk_backend_info bi;
    find(dev, "sse41", &bi);
    assert_int_equal(bi.status, RTK_BACKEND_STATUS_USABLE);
    assert_string_equal(bi.reason, "not chosen: isa=scalar");
    rtk_device_release(dev);

    assert_int_equal(rtk_device_new("max_isa=sse41", &dev), RTK_OK);
    assert_string_equal(rtk_device_get_backend_name(dev), "sse41");
    rtk_device_release(dev);

    /* The environment narrows too, and may not contradict the config. */
    setenv("RTK_ISA", "scalar", 1);
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    assert_string_equal(rtk_device_get_backend_name(dev), "scalar");
    rtk_device_release(dev);
    dev = NULL;
    assert_int_equal(rtk_device_new("isa=sse41", &dev), RTK_ERROR_INVALID_CONFIG);
    assert_null(dev);
    assert_non_null(strstr(rtk_device_get_error_message(NULL), "isa=sse41 conflicts with RTK_ISA=scalar"));
    setenv("RTK_ISA", "", 1);
}

static void test_missing_isa_lists_what_is_there(void **state)
{
    (void)state;
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new("isa=neon", &dev), RTK_ERROR_NO_BACKEND);
    assert_null(dev);
    const char *msg = rtk_device_get_error_message(NULL);
    if (!strstr(msg, "isa=neon: no such usable backend; usable: ") || !strstr(msg, "scalar") ||
        !strstr(msg, "Searched: "))
        fail_msg("message: %s", msg);

    /* Asking for a backend whose CPU requirement is unmet is a CPU error. */
    assert_int_equal(rtk_device_new("isa=nocpu,backend_path=" RTK_TEST_FIXTURES, &dev), RTK_ERROR_UNSUPPORTED_CPU);
    msg = rtk_device_get_error_message(NULL);
    if (!strstr(msg, "librtk_backend_nocpu.so: this CPU lacks"))
        fail_msg("message: %s", msg);
}

static void test_empty_directory(void **state)
{
    (void)state;
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new("backend_path=" RTK_TEST_EMPTY_DIR, &dev), RTK_ERROR_NO_BACKEND);
    const char *msg = rtk_device_get_error_message(NULL);
    if (!strstr(msg, "no usable rtk backend. Searched: " RTK_TEST_EMPTY_DIR "; no librtk_backend_*.so files there"))
        fail_msg("message: %s", msg);
    /* Only broken backends: every rejection is listed. */
    assert_int_equal(rtk_device_new("backend_path=" RTK_TEST_FIXTURES, &dev), RTK_ERROR_NO_BACKEND);
    msg = rtk_device_get_error_message(NULL);
    if (!strstr(msg, "librtk_backend_future.so: refused to negotiate") ||
        !strstr(msg, "librtk_backend_smalldesc.so: descriptor too small"))
        fail_msg("message: %s", msg);
}

static void test_env_path_searched_first(void **state)
{
    (void)state;
    /* RTK_BACKEND_PATH comes before the directory next to librtk: the fixtures
     * are listed first and the real backends after them. */
    setenv("RTK_BACKEND_PATH", RTK_TEST_FIXTURES, 1);
    rtk_device dev = NULL;
    assert_int_equal(rtk_device_new(NULL, &dev), RTK_OK);
    const char *path = rtk_device_get_search_path(dev);
    assert_true(!strncmp(path, RTK_TEST_FIXTURES ":", strlen(RTK_TEST_FIXTURES) + 1));
    assert_non_null(strstr(path, RTK_TEST_BACKENDS));
    rtk_backend_info bi;
    find(dev, "future", &bi);
    assert_int_equal(bi.status, RTK_BACKEND_STATUS_REJECTED);
    rtk_device_release(dev);
    setenv("RTK_BACKEND_PATH", "", 1);
}

/* Damaged backend files, as an interrupted install or upgrade leaves
 * them: copies of a real backend cut at several lengths (dlopen took the
 * process down with SIGBUS on these before the loader checked the file),
 * and a whole one whose program header claims a segment past the end of
 * the file.  Each costs its backend only, with the reason; the real
 * backends after them load, through backend_path= and RTK_BACKEND_PATH. */
static void write_file(const char *path, const void *data, size_t n)
{
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite(data, 1, n, f), n);
    assert_int_equal(fclose(f), 0);
}

static void test_damaged_backend_files(void **state)
{
    (void)state;
    FILE *f = fopen(RTK_TEST_BACKENDS "/librtk_backend_scalar.so", "rb");
    assert_non_null(f);
    assert_int_equal(fseek(f, 0, SEEK_END), 0);
    const long size = ftell(f);
    assert_true(size > 4096);
    unsigned char *so = malloc((size_t)size);
    assert_non_null(so);
    rewind(f);
    assert_int_equal(fread(so, 1, (size_t)size, f), (size_t)size);
    fclose(f);
    char dir[] = "/tmp/rtk_test_loader.XXXXXX";
    assert_non_null(mkdtemp(dir));
    const long cuts[] = {1, 63, 64, 1000, 4096, 100000, size / 2, size - 1};
    char path[600], names[16][32];
    int n = 0;
    for (size_t i = 0; i < sizeof cuts / sizeof *cuts; i++) {
        if (cuts[i] >= size)
            continue;
        snprintf(names[n], sizeof names[n], "cut%ld", cuts[i]);
        snprintf(path, sizeof path, "%s/librtk_backend_%s.so", dir, names[n++]);
        write_file(path, so, (size_t)cuts[i]);
    }
    /* the whole file, its last program header's segment made to run past the end */
    const Elf64_Ehdr *eh = (const Elf64_Ehdr *)(const void *)so;
    assert_true(eh->e_phnum > 0);
    Elf64_Phdr *ph = (Elf64_Phdr *)(void *)(so + eh->e_phoff + (eh->e_phnum - 1) * sizeof(Elf64_Phdr));
    ph->p_type = PT_LOAD;
    ph->p_offset = (Elf64_Off)size - 16;
    ph->p_filesz = 4096;
    snprintf(names[n], sizeof names[n], "past");
    snprintf(path, sizeof path, "%s/librtk_backend_%s.so", dir, names[n++]);
    write_file(path, so, (size_t)size);

    for (int env = 0; env < 2; env++) {
        char config[400];
        snprintf(config, sizeof config, "backend_path=%s:%s", dir, RTK_TEST_BACKENDS);
        if (env)
            setenv("RTK_BACKEND_PATH", dir, 1);
        rtk_device dev = NULL;
        if (rtk_device_new(env ? NULL : config, &dev) != RTK_OK)
            fail_msg("%s", rtk_device_get_error_message(NULL));
        for (int i = 0; i < n; i++)
            expect_rejected(dev, names[i], i + 1 < n ? "truncated or damaged" : "segment");
        rtk_backend_info bi;
        assert_true(find(dev, "scalar", &bi)->status != RTK_BACKEND_STATUS_REJECTED);
        rtk_device_release(dev);
    }
    setenv("RTK_BACKEND_PATH", "", 1);
    for (int i = 0; i < n; i++) {
        snprintf(path, sizeof path, "%s/librtk_backend_%s.so", dir, names[i]);
        unlink(path);
    }
    rmdir(dir);
    free(so);
}

static void test_devices_on_different_backends(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    size_t n = test_backend_names(names, TEST_MAX_BACKENDS);
    assert_true(n >= 1);
    rtk_device devs[TEST_MAX_BACKENDS];
    for (size_t i = 0; i < n; i++)
        devs[i] = test_device(names[i]);
    for (size_t i = 0; i < n; i++) {
        assert_string_equal(rtk_device_get_backend_name(devs[i]), names[i]);
        rtk_device_release(devs[i]);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_fixtures_rejected_good_ones_load),
        cmocka_unit_test(test_isa_selects_and_narrows),
        cmocka_unit_test(test_missing_isa_lists_what_is_there),
        cmocka_unit_test(test_empty_directory),
        cmocka_unit_test(test_env_path_searched_first),
        cmocka_unit_test(test_damaged_backend_files),
        cmocka_unit_test(test_devices_on_different_backends),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
