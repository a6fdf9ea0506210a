/*
 * Commits under stress: the progress callback (reports, and a cancel at
 * every step it reports, each leaving the previous tree as it was), a
 * second commit, an attach or a query from another thread while a commit
 * runs (an error each, the running commit unharmed), and several threads
 * joining one commit (rtk_scene_join_commit).  The threads' tests run
 * under ThreadSanitizer too (scripts/test: "quick").
 */
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "testlib.h"

static test_mesh ball, big;
static float *moved, *big_moved; /* the balls' vertices moved: the next commit's geometry */

static int setup(void **state)
{
    (void)state;
    ball = test_ball(test_sanitized() ? 60 : 120);
    big = test_ball(190); /* 72,200 triangles: the SAH builder's stages 1 and 2, node arenas */
    moved = malloc(ball.nv * 3 * sizeof *moved);
    big_moved = malloc(big.nv * 3 * sizeof *big_moved);
    if (!moved || !big_moved)
        return -1;
    for (size_t i = 0; i < ball.nv * 3; i++)
        moved[i] = ball.v[i] * 1.25f + (i % 3 == 0 ? 0.1f : 0.0f);
    for (size_t i = 0; i < big.nv * 3; i++)
        big_moved[i] = big.v[i] * 1.25f + (i % 3 == 0 ? 0.1f : 0.0f);
    return 0;
}

static int teardown(void **state)
{
    (void)state;
    free(ball.v);
    free(ball.idx);
    free(moved);
    free(big.v);
    free(big.idx);
    free(big_moved);
    return 0;
}

/* Rays from around the ball towards it. */
enum { NRAYS = 512 };
static void make_rays(rtk_rayhit *rh)
{
    rng r = {9};
    for (int i = 0; i < NRAYS; i++) {
        float o[3], d[3];
        for (int k = 0; k < 3; k++) {
            o[k] = 6.0f * rng_float(&r) - 3.0f;
            d[k] = 0.5f * rng_float(&r) - 0.25f - o[k];
        }
        rh[i] = (rtk_rayhit){.ray = test_ray(o[0], o[1], o[2], d[0], d[1], d[2], 0.0f, INFINITY)};
        rh[i].hit.geomID = rh[i].hit.primID = rh[i].hit.instID = RTK_INVALID_GEOMETRY_ID;
    }
}

/* The scene's answers to the rays. */
static void answers(rtk_scene s, rtk_rayhit *out)
{
    make_rays(out);
    for (int i = 0; i < NRAYS; i++)
        assert_int_equal(rtk_intersect1(s, &out[i]), RTK_OK);
}

/* The scene's answers to the rays, 1; or 0 when it has no tree (a failed
 * commit of a `drops` variation). */
static int answers_if_any(rtk_scene s, rtk_rayhit *out)
{
    make_rays(out);
    if (rtk_intersect1(s, &out[0]) == RTK_ERROR_INVALID_OPERATION)
        return 0;
    for (int i = 0; i < NRAYS; i++)
        assert_int_equal(rtk_intersect1(s, &out[i]), RTK_OK);
    return 1;
}

/* The scene's geometry 0 on vertices v (of `ball` or `big`, by which
 * array), committed (with the scene). */
static rtk_error recommit(rtk_scene s, const float *v)
{
    rtk_geometry g = rtk_scene_get_geometry(s, 0);
    const size_t nv = v == big.v || v == big_moved ? big.nv : ball.nv;
    assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v, 0, 12, nv), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    return rtk_scene_commit(s);
}

/* A progress callback that counts its calls and cancels from call
 * `cancel_at` on (never when negative); it checks the shares it sees lie
 * in [0, 1]. */
typedef struct counter {
    int calls, cancel_at, bad_share;
} counter;

static int count_progress(void *user, double done)
{
    counter *c = user;
    const int call = __atomic_fetch_add(&c->calls, 1, __ATOMIC_RELAXED);
    if (!(done >= 0.0 && done <= 1.0))
        __atomic_store_n(&c->bad_share, 1, __ATOMIC_RELAXED);
    return c->cancel_at < 0 || call < c->cancel_at;
}

/* The variations of commit whose every reported step is cancelled in
 * turn: the builders (Morton, binned SAH, spatial splits), the compact
 * and robust layouts, a dynamic scene, motion blur, and a refit. */
typedef struct variation {
    const char *name;
    rtk_build_quality quality;
    unsigned flags;
    int motion, refit, threads, big;
    /* a dynamic scene with a REFIT geometry: a commit that fails after its
     * tree's refit in place leaves the scene without a tree (rtk.h, build
     * progress) */
    int drops;
} variation;

static const variation variations[] = {
    {.name = "low", .quality = RTK_BUILD_QUALITY_LOW, .threads = 2},
    {.name = "medium", .quality = RTK_BUILD_QUALITY_MEDIUM, .threads = 2},
    {.name = "medium, 1 thread", .quality = RTK_BUILD_QUALITY_MEDIUM, .threads = 1},
    {.name = "high", .quality = RTK_BUILD_QUALITY_HIGH, .threads = 2},
    {.name = "compact", .quality = RTK_BUILD_QUALITY_MEDIUM, .flags = RTK_SCENE_FLAG_COMPACT, .threads = 2},
    {.name = "robust", .quality = RTK_BUILD_QUALITY_MEDIUM, .flags = RTK_SCENE_FLAG_ROBUST, .threads = 2},
    {.name = "dynamic", .quality = RTK_BUILD_QUALITY_MEDIUM, .flags = RTK_SCENE_FLAG_DYNAMIC, .threads = 2},
    /* (a REFIT geometry: its tree and the top level refitted) */
    {.name = "dynamic, refit", .quality = RTK_BUILD_QUALITY_MEDIUM, .flags = RTK_SCENE_FLAG_DYNAMIC, .refit = 1,
     .threads = 2, .drops = 1},
    {.name = "motion", .quality = RTK_BUILD_QUALITY_MEDIUM, .motion = 1, .threads = 2},
    {.name = "refit", .quality = RTK_BUILD_QUALITY_MEDIUM, .refit = 1, .threads = 2},
    {.name = "medium, 72K triangles", .quality = RTK_BUILD_QUALITY_MEDIUM, .threads = 2, .big = 1},
    {.name = "high, 72K triangles", .quality = RTK_BUILD_QUALITY_HIGH, .threads = 2, .big = 1},
    {.name = "low, 72K triangles", .quality = RTK_BUILD_QUALITY_LOW, .threads = 2, .big = 1},
};

/* The variation's mesh and its moved vertices. */
static const test_mesh *v_mesh(const variation *v)
{
    return v->big ? &big : &ball;
}
static const float *v_moved(const variation *v)
{
    return v->big ? big_moved : moved;
}

static rtk_scene variation_scene(rtk_device dev, const variation *v)
{
    const test_mesh *mesh = v_mesh(v);
    rtk_scene s = test_scene_uncommitted(dev, mesh->v, mesh->nv, mesh->idx, mesh->nt, v->flags);
    assert_int_equal(rtk_scene_set_build_quality(s, v->quality), RTK_OK);
    rtk_geometry g = rtk_scene_get_geometry(s, 0);
    if (v->motion) {
        assert_int_equal(rtk_geometry_set_time_step_count(g, 2), RTK_OK);
        assert_int_equal(rtk_geometry_set_shared_buffer_slot(g, RTK_BUFFER_TYPE_VERTEX, 1, moved, 0, 12, ball.nv),
                         RTK_OK);
    }
    if (v->refit)
        assert_int_equal(rtk_geometry_set_build_quality(g, RTK_BUILD_QUALITY_REFIT), RTK_OK);
    assert_int_equal(rtk_geometry_commit(g), RTK_OK);
    assert_int_equal(rtk_scene_commit(s), RTK_OK);
    return s;
}

static void test_progress_and_cancel_at_every_step(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    rtk_rayhit *before = malloc(NRAYS * sizeof *before), *after = malloc(NRAYS * sizeof *after),
               *now = malloc(NRAYS * sizeof *now);
    assert_true(before && after && now);
    for (size_t vi = 0; vi < sizeof variations / sizeof *variations; vi++) {
        const variation *v = &variations[vi];
        rtk_device dev = test_device_threads(names[nb - 1], v->threads);
        rtk_scene s = variation_scene(dev, v);
        answers(s, before);
        /* a full commit of the moved ball: its steps counted, its answers */
        counter full = {.cancel_at = -1};
        assert_int_equal(rtk_scene_set_progress_monitor(s, count_progress, &full), RTK_OK);
        assert_int_equal(recommit(s, v_moved(v)), RTK_OK);
        answers(s, after);
        assert_int_equal(full.bad_share, 0);
        if (full.calls < 1)
            fail_msg("%s: no progress reported", v->name);
        /* back to the ball, then each step cancelled in turn */
        assert_int_equal(rtk_scene_set_progress_monitor(s, NULL, NULL), RTK_OK);
        assert_int_equal(recommit(s, v_mesh(v)->v), RTK_OK);
        int dropped = 0;
        for (int k = 0; k < full.calls; k++) {
            counter c = {.cancel_at = k};
            assert_int_equal(rtk_scene_set_progress_monitor(s, count_progress, &c), RTK_OK);
            const rtk_error e = recommit(s, v_moved(v));
            if (e != RTK_ERROR_CANCELLED)
                fail_msg("%s: cancelled at step %d of %d: the commit returned %s", v->name, k, full.calls,
                         rtk_error_name(e));
            assert_non_null(strstr(rtk_device_get_error_message(dev), "cancelled"));
            if (!answers_if_any(s, now)) {
                if (!v->drops || k == 0)
                    fail_msg("%s: cancelled at step %d of %d: the scene has no tree", v->name, k, full.calls);
                dropped++;
            } else if (memcmp(now, before, NRAYS * sizeof *now))
                fail_msg("%s: cancelled at step %d of %d: the previous tree is not what it was", v->name, k,
                         full.calls);
            /* (the geometry is the moved ball now: put the ball back for the next round) */
            rtk_geometry g = rtk_scene_get_geometry(s, 0);
            assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, v_mesh(v)->v, 0, 12,
                                                            v_mesh(v)->nv),
                             RTK_OK);
            assert_int_equal(rtk_geometry_commit(g), RTK_OK);
        }
        /* and uncancelled, the moved ball's answers as the first time */
        counter go = {.cancel_at = -1};
        assert_int_equal(rtk_scene_set_progress_monitor(s, count_progress, &go), RTK_OK);
        assert_int_equal(recommit(s, v_moved(v)), RTK_OK);
        answers(s, now);
        assert_memory_equal(now, after, NRAYS * sizeof *now);
        print_message("%s: %d progress steps, each cancelled in turn (%d left no tree)\n", v->name, full.calls,
                      dropped);
        rtk_scene_release(s);
        rtk_device_release(dev);
    }
    free(before);
    free(after);
    free(now);
}

/* ---- the memory monitor ----
 * It counts the bytes held (taken minus given back) and the allocations
 * it sees, and refuses allocation number `refuse_at` (none when negative). */
typedef struct monitor {
    int64_t held;
    int calls, refuse_at, bad;
} monitor;

static int count_memory(void *user, int64_t bytes, int post)
{
    monitor *m = user;
    if (!bytes || (bytes > 0) == (post != 0))
        __atomic_store_n(&m->bad, 1, __ATOMIC_RELAXED); /* before taking, after giving back */
    if (bytes > 0 && __atomic_fetch_add(&m->calls, 1, __ATOMIC_RELAXED) == m->refuse_at)
        return 0;
    __atomic_add_fetch(&m->held, bytes, __ATOMIC_RELAXED);
    return 1;
}

static void test_memory_monitor_refuses_each_allocation(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    rtk_rayhit *before = malloc(NRAYS * sizeof *before), *after = malloc(NRAYS * sizeof *after),
               *now = malloc(NRAYS * sizeof *now);
    assert_true(before && after && now);
    for (size_t vi = 0; vi < sizeof variations / sizeof *variations; vi++) {
        const variation *v = &variations[vi];
        rtk_device dev = test_device_threads(names[nb - 1], v->threads);
        monitor m = {.refuse_at = -1};
        assert_int_equal(rtk_device_set_memory_monitor(dev, count_memory, &m), RTK_OK);
        rtk_scene s = variation_scene(dev, v);
        assert_true(m.held > 0);
        answers(s, before);
        const int64_t held_before = m.held;
        /* a whole commit of the moved ball: its allocations counted */
        m.calls = 0;
        assert_int_equal(recommit(s, v_moved(v)), RTK_OK);
        const int total = m.calls;
        answers(s, after);
        assert_int_equal(recommit(s, v_mesh(v)->v), RTK_OK);
        int refused = 0;
        for (int n = 0; n < total; n++) {
            m.calls = 0;
            m.refuse_at = n;
            const rtk_error e = recommit(s, v_moved(v));
            m.refuse_at = -1;
            const int has_tree = answers_if_any(s, now);
            if (e == RTK_ERROR_MEMORY_REFUSED) {
                /* the previous tree kept, to the bit (or none: drops) */
                refused++;
                assert_non_null(strstr(rtk_device_get_error_message(dev), "refused"));
                if (!has_tree && !v->drops)
                    fail_msg("%s: allocation %d of %d refused: the scene has no tree", v->name, n, total);
                if (has_tree && memcmp(now, before, NRAYS * sizeof *now))
                    fail_msg("%s: allocation %d of %d refused: the previous tree is not what it was", v->name, n,
                             total);
            } else if (e == RTK_OK) {
                /* a builder that tried again smaller, or went without */
                assert_true(has_tree);
                assert_memory_equal(now, after, NRAYS * sizeof *now);
            } else {
                fail_msg("%s: allocation %d of %d refused: the commit returned %s", v->name, n, total,
                         rtk_error_name(e));
            }
            /* back to the ball (whatever happened) */
            assert_int_equal(recommit(s, v_mesh(v)->v), RTK_OK);
            answers(s, now);
            assert_memory_equal(now, before, NRAYS * sizeof *now);
            if (m.held != held_before)
                fail_msg("%s: after allocation %d of %d refused and the ball committed again, the monitor sees %lld "
                         "bytes held, %lld before",
                         v->name, n, total, (long long)m.held, (long long)held_before);
        }
        assert_true(refused > 0);
        assert_int_equal(m.bad, 0);
        print_message("%s: %d allocations seen by the monitor, each refused in turn (%d refusals failed the commit)\n",
                      v->name, total, refused);
        rtk_scene_release(s);
        assert_true(m.held == 0 || v->flags & RTK_SCENE_FLAG_COMPACT); /* (test_scene's shared buffers: none held) */
        rtk_device_release(dev);
    }
    /* a top level over instances: each of its allocations refused in turn
     * (the commit fails, or goes on without what was refused), and all the
     * memory given back with the scenes */
    {
        rtk_device dev = test_device_threads(names[nb - 1], 2);
        monitor m = {.refuse_at = -1};
        assert_int_equal(rtk_device_set_memory_monitor(dev, count_memory, &m), RTK_OK);
        rtk_scene inner = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
        const int64_t inner_held = m.held;
        rtk_scene outer = test_instancing_scene(dev, inner);
        m.calls = 0;
        assert_int_equal(rtk_scene_commit(outer), RTK_OK);
        const int total = m.calls;
        assert_true(total >= 1);
        for (int n = 0; n < total; n++) {
            rtk_scene again = test_instancing_scene(dev, inner);
            m.calls = 0;
            m.refuse_at = n;
            const rtk_error e = rtk_scene_commit(again);
            m.refuse_at = -1;
            assert_true(e == RTK_ERROR_MEMORY_REFUSED || e == RTK_OK);
            rtk_scene_release(again);
        }
        rtk_scene_release(outer);
        assert_int_equal(m.held, inner_held);
        rtk_scene_release(inner);
        assert_int_equal(m.held, 0);
        assert_int_equal(m.bad, 0);
        rtk_device_release(dev);
    }
    /* a geometry buffer rtk would allocate, refused */
    rtk_device dev = test_device_threads("scalar", 1);
    monitor m = {.refuse_at = 0};
    assert_int_equal(rtk_device_set_memory_monitor(dev, count_memory, &m), RTK_OK);
    rtk_geometry g;
    assert_int_equal(rtk_geometry_new(dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    void *buf = (void *)1;
    assert_int_equal(rtk_geometry_set_new_buffer(g, RTK_BUFFER_TYPE_VERTEX, 12, 1000, &buf), RTK_ERROR_MEMORY_REFUSED);
    assert_null(buf);
    assert_int_equal(rtk_geometry_set_new_buffer(g, RTK_BUFFER_TYPE_VERTEX, 12, 1000, &buf), RTK_OK);
    assert_true(m.held >= 12000);
    rtk_geometry_release(g);
    assert_int_equal(m.held, 0);
    rtk_device_release(dev);
    free(before);
    free(after);
    free(now);
}

/* ---- another thread while a commit runs ----
 * The commit's progress callback, at its first call, lets the other thread
 * try what it must not do, and waits until it has: each try fails, and the
 * commit goes on unharmed. */
typedef struct meddler {
    rtk_scene scene;
    rtk_device dev;
    pthread_mutex_t lock;
    pthread_cond_t cond;
    int go, done, joined;
    rtk_error commit, join, query, attach, flags, info, packet, stream;
    int message_ok;
} meddler;

static int meddle_progress(void *user, double done)
{
    (void)done;
    meddler *m = user;
    pthread_mutex_lock(&m->lock);
    if (!m->go) {
        m->go = 1;
        pthread_cond_broadcast(&m->cond);
        while (!m->done)
            pthread_cond_wait(&m->cond, &m->lock);
    }
    pthread_mutex_unlock(&m->lock);
    return 1;
}

static void *meddle(void *arg)
{
    meddler *m = arg;
    pthread_mutex_lock(&m->lock);
    while (!m->go)
        pthread_cond_wait(&m->cond, &m->lock);
    pthread_mutex_unlock(&m->lock);
    m->commit = rtk_scene_commit(m->scene);
    m->message_ok = strstr(rtk_device_get_error_message(m->dev), "being committed by another thread") != NULL;
    /* (joining a joined commit is what join is for: only against a plain one) */
    m->join = m->joined ? RTK_ERROR_INVALID_OPERATION : rtk_scene_join_commit(m->scene);
    rtk_rayhit rh[NRAYS];
    make_rays(rh);
    m->query = rtk_intersect1(m->scene, &rh[0]);
    m->stream = rtk_intersect1M(m->scene, rh, NRAYS, sizeof rh[0]);
    _Alignas(32) rtk_rayhit8 pk;
    memset(&pk, 0, sizeof pk);
    m->packet = rtk_intersect8(m->scene, NULL, &pk);
    rtk_geometry g;
    assert_int_equal(rtk_geometry_new(m->dev, RTK_GEOMETRY_TYPE_TRIANGLE, &g), RTK_OK);
    m->attach = rtk_scene_attach_geometry(m->scene, g, NULL);
    rtk_geometry_release(g);
    m->flags = rtk_scene_set_flags(m->scene, RTK_SCENE_FLAG_COMPACT);
    rtk_scene_info info = {.struct_size = sizeof info};
    m->info = rtk_scene_get_info(m->scene, &info);
    pthread_mutex_lock(&m->lock);
    m->done = 1;
    pthread_cond_broadcast(&m->cond);
    pthread_mutex_unlock(&m->lock);
    return NULL;
}

static void test_meddling_while_committed(void **state)
{
    (void)state;
    rtk_device dev = test_device_threads("scalar", 2);
    rtk_scene s = test_scene(dev, ball.v, ball.nv, ball.idx, ball.nt);
    rtk_rayhit *before = malloc(NRAYS * sizeof *before), *now = malloc(NRAYS * sizeof *now);
    assert_true(before && now);
    for (int join = 0; join < 2; join++) {
        meddler m = {.scene = s, .dev = dev, .joined = join};
        pthread_mutex_init(&m.lock, NULL);
        pthread_cond_init(&m.cond, NULL);
        assert_int_equal(rtk_scene_set_progress_monitor(s, meddle_progress, &m), RTK_OK);
        pthread_t t;
        assert_int_equal(pthread_create(&t, NULL, meddle, &m), 0);
        rtk_geometry g = rtk_scene_get_geometry(s, 0);
        assert_int_equal(rtk_geometry_set_shared_buffer(g, RTK_BUFFER_TYPE_VERTEX, join ? ball.v : moved, 0, 12,
                                                        ball.nv),
                         RTK_OK);
        assert_int_equal(rtk_geometry_commit(g), RTK_OK);
        assert_int_equal(join ? rtk_scene_join_commit(s) : rtk_scene_commit(s), RTK_OK);
        pthread_join(t, NULL);
        assert_int_equal(m.commit, RTK_ERROR_INVALID_OPERATION);
        assert_true(m.message_ok);
        assert_int_equal(m.join, RTK_ERROR_INVALID_OPERATION);
        assert_int_equal(m.query, RTK_ERROR_INVALID_OPERATION);
        assert_int_equal(m.stream, RTK_ERROR_INVALID_OPERATION);
        assert_int_equal(m.packet, RTK_ERROR_INVALID_OPERATION);
        assert_int_equal(m.attach, RTK_ERROR_INVALID_OPERATION);
        assert_int_equal(m.flags, RTK_ERROR_INVALID_OPERATION);
        assert_int_equal(m.info, RTK_ERROR_INVALID_OPERATION);
        pthread_cond_destroy(&m.cond);
        pthread_mutex_destroy(&m.lock);
        assert_int_equal(rtk_scene_set_progress_monitor(s, NULL, NULL), RTK_OK);
        /* the running commit was unharmed: the scene answers as a fresh one */
        rtk_scene fresh = test_scene(dev, join ? ball.v : moved, ball.nv, ball.idx, ball.nt);
        answers(fresh, before);
        answers(s, now);
        assert_memory_equal(now, before, NRAYS * sizeof *now);
        rtk_scene_info info = {.struct_size = sizeof info}, fresh_info = {.struct_size = sizeof info};
        assert_int_equal(rtk_scene_get_info(s, &info), RTK_OK);
        assert_int_equal(rtk_scene_get_info(fresh, &fresh_info), RTK_OK);
        assert_int_equal(info.triangles, fresh_info.triangles);
        assert_int_equal(info.nodes, fresh_info.nodes);
        rtk_scene_release(fresh);
    }
    free(before);
    free(now);
    rtk_scene_release(s);
    rtk_device_release(dev);
}

/* ---- threads joining one commit ---- */
typedef struct joiner {
    rtk_scene scene;
    pthread_barrier_t *start;
    rtk_error result;
} joiner;

static void *join_thread(void *arg)
{
    joiner *j = arg;
    pthread_barrier_wait(j->start);
    j->result = rtk_scene_join_commit(j->scene);
    return NULL;
}

static void test_join_commit(void **state)
{
    (void)state;
    char names[TEST_MAX_BACKENDS][32];
    const size_t nb = test_backend_names(names, TEST_MAX_BACKENDS);
    rtk_device dev = test_device_threads(names[nb - 1], 1); /* (its own pool is never used: the joiners build) */
    rtk_scene ref = test_scene(dev, moved, ball.nv, ball.idx, ball.nt);
    rtk_bvh want = {.struct_size = sizeof want};
    assert_int_equal(rtk_scene_get_bvh(ref, &want), RTK_OK);
    enum { T = 4 };
    for (int round = 0; round < (test_sanitized() ? 2 : 6); round++) {
        rtk_scene s = test_scene_uncommitted(dev, moved, ball.nv, ball.idx, ball.nt, 0);
        pthread_barrier_t start;
        pthread_barrier_init(&start, NULL, T);
        joiner j[T];
        pthread_t tid[T];
        for (int t = 0; t < T; t++) {
            j[t] = (joiner){s, &start, RTK_ERROR_UNKNOWN};
            assert_int_equal(pthread_create(&tid[t], NULL, join_thread, &j[t]), 0);
        }
        for (int t = 0; t < T; t++) {
            pthread_join(tid[t], NULL);
            assert_int_equal(j[t].result, RTK_OK);
        }
        pthread_barrier_destroy(&start);
        /* the same tree as a commit on one thread, byte for byte */
        rtk_bvh got = {.struct_size = sizeof got};
        assert_int_equal(rtk_scene_get_bvh(s, &got), RTK_OK);
        test_assert_same_tree(&want, &got);
        rtk_bvh_free(&got);
        /* and a join alone is a commit */
        assert_int_equal(rtk_scene_join_commit(s), RTK_OK);
        rtk_scene_release(s);
    }
    rtk_bvh_free(&want);
    rtk_scene_release(ref);
    rtk_device_release(dev);
}

int main(int argc, char **argv)
{
    const int quick = argc > 1 && !strcmp(argv[1], "quick"); /* the threads' tests, for ThreadSanitizer */
    const struct CMUnitTest all[] = {
        cmocka_unit_test(test_progress_and_cancel_at_every_step),
        cmocka_unit_test(test_memory_monitor_refuses_each_allocation),
        cmocka_unit_test(test_meddling_while_committed),
        cmocka_unit_test(test_join_commit),
    };
    const struct CMUnitTest threads[] = {cmocka_unit_test(test_meddling_while_committed),
                                         cmocka_unit_test(test_join_commit)};
    return quick ? cmocka_run_group_tests(threads, setup, teardown) : cmocka_run_group_tests(all, setup, teardown);
}
