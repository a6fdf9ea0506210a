/*
 * rtk's own thread pool: a device's worker threads, created at the first
 * build that can use them and joined when the device is released.
 *
 * The one operation is parallel_for (rtk_task_system): the caller publishes a
 * job, workers and the caller take its indices with an atomic counter, and
 * the caller returns when every index has run and no worker still holds
 * the job (it lives on the caller's stack).  Several jobs may be published
 * at once (scenes committed from several threads, or a task that runs a
 * parallel_for of its own): idle workers serve the oldest job first, and
 * each caller runs its own job's indices too, so a job always finishes even
 * when every worker is busy elsewhere.  A joinable pool has no workers of
 * its own: application threads join it (rtk_scene_join_commit) and serve
 * its jobs until told to stop.
 */
#ifndef _GNU_SOURCE
#define _GNU_SOURCE /* sched_getaffinity, CPU_COUNT */
#endif
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "internal.h"

typedef struct pool_job {
    rtk_task_fn fn;
    void *data;
    uint32_t count;
    atomic_uint next;      /* the next index to hand out */
    unsigned users;        /* workers running it (under the pool lock) */
    struct pool_job *link; /* the pool's list of jobs with indices left */
} pool_job;

struct rtk_pool {
    pthread_mutex_t lock;
    pthread_cond_t work;     /* a job was published, or stop */
    pthread_cond_t finished; /* a worker let go of a job */
    pool_job *jobs;          /* oldest first */
    int stop;
    unsigned thread_count; /* workers */
    pthread_t *threads;
    /* A pool that application threads join (rtk_pool_serve): its jobs are
     * published even with no worker, for threads that may join. */
    int joinable;
};

unsigned rtk_cpu_count(void)
{
    cpu_set_t set;
    if (sched_getaffinity(0, sizeof set, &set) == 0 && CPU_COUNT(&set) > 0)
        return (unsigned)CPU_COUNT(&set);
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n > 0 ? (unsigned)n : 1;
}

static void run_indices(pool_job *job)
{
    for (uint32_t i; (i = atomic_fetch_add_explicit(&job->next, 1, memory_order_relaxed)) < job->count;)
        job->fn(job->data, i);
}

/* Under the lock: drops exhausted jobs from the list. */
static void unlink_exhausted(rtk_pool *p)
{
    pool_job **at = &p->jobs;
    while (*at) {
        if (atomic_load_explicit(&(*at)->next, memory_order_relaxed) >= (*at)->count)
            *at = (*at)->link;
        else
            at = &(*at)->link;
    }
}

/* Runs the pool's jobs' indices on the calling thread until the pool stops
 * or *until is set (then rtk_pool_wake). */
static void serve(rtk_pool *p, atomic_int *until)
{
    pthread_mutex_lock(&p->lock);
    while (!p->stop && !(until && atomic_load(until))) {
        unlink_exhausted(p);
        pool_job *job = p->jobs;
        if (!job) {
            pthread_cond_wait(&p->work, &p->lock);
            continue;
        }
        job->users++;
        pthread_mutex_unlock(&p->lock);
        run_indices(job);
        pthread_mutex_lock(&p->lock);
        if (--job->users == 0)
            pthread_cond_broadcast(&p->finished);
    }
    pthread_mutex_unlock(&p->lock);
}

static void *worker(void *arg)
{
    serve(arg, NULL);
    return NULL;
}

void rtk_pool_serve(rtk_pool *p, atomic_int *until)
{
    serve(p, until);
}

void rtk_pool_wake(rtk_pool *p)
{
    pthread_mutex_lock(&p->lock);
    pthread_cond_broadcast(&p->work);
    pthread_mutex_unlock(&p->lock);
}

rtk_pool *rtk_pool_new_joinable(char *msg, size_t msg_size)
{
    rtk_pool *p = rtk_pool_new(1, msg, msg_size);
    if (p)
        p->joinable = 1;
    return p;
}

/* Every index has been handed out by the time the caller waits; it then
 * waits for the workers still running one.  Those hold the job as users,
 * so the job outlives every access to it. */
static void pool_parallel_for(void *user, uint32_t count, rtk_task_fn fn, void *data)
{
    rtk_pool *p = user;
    if (count == 1 || (p->thread_count == 0 && !p->joinable)) {
        for (uint32_t i = 0; i < count; i++)
            fn(data, i);
        return;
    }
    pool_job job = {.fn = fn, .data = data, .count = count};
    atomic_init(&job.next, 0);
    pthread_mutex_lock(&p->lock);
    pool_job **tail = &p->jobs;
    while (*tail)
        tail = &(*tail)->link;
    *tail = &job;
    pthread_cond_broadcast(&p->work);
    pthread_mutex_unlock(&p->lock);

    run_indices(&job);

    pthread_mutex_lock(&p->lock);
    unlink_exhausted(p); /* every index of job has been handed out */
    while (job.users)
        pthread_cond_wait(&p->finished, &p->lock);
    pthread_mutex_unlock(&p->lock);
}

/* Stops and joins the first `started` workers and frees the pool. */
static void pool_destroy(rtk_pool *p, unsigned started)
{
    pthread_mutex_lock(&p->lock);
    p->stop = 1;
    pthread_cond_broadcast(&p->work);
    pthread_mutex_unlock(&p->lock);
    for (unsigned i = 0; i < started; i++)
        pthread_join(p->threads[i], NULL);
    pthread_cond_destroy(&p->finished);
    pthread_cond_destroy(&p->work);
    pthread_mutex_destroy(&p->lock);
    free(p->threads);
    free(p);
}

rtk_pool *rtk_pool_new(unsigned threads, char *msg, size_t msg_size)
{
    rtk_pool *p = calloc(1, sizeof *p);
    const unsigned workers = threads > 1 ? threads - 1 : 0;
    if (!p || !(p->threads = calloc(workers ? workers : 1, sizeof *p->threads))) {
        free(p);
        snprintf(msg, msg_size, "out of memory for the thread pool");
        return NULL;
    }
    pthread_mutex_init(&p->lock, NULL);
    pthread_cond_init(&p->work, NULL);
    pthread_cond_init(&p->finished, NULL);
    for (unsigned i = 0; i < workers; i++) {
        int rc = pthread_create(&p->threads[i], NULL, worker, p);
        if (rc) {
            snprintf(msg, msg_size, "could not start worker thread %u of %u: %s", i + 1, workers, strerror(rc));
            pool_destroy(p, i);
            return NULL;
        }
    }
    p->thread_count = workers;
    return p;
}

void rtk_pool_free(rtk_pool *p)
{
    if (p)
        pool_destroy(p, p->thread_count);
}

rtk_task_system rtk_pool_tasks(rtk_pool *p)
{
    return (rtk_task_system){.struct_size = sizeof(rtk_task_system),
                             .threads = p->thread_count + 1,
                             .user = p,
                             .parallel_for = pool_parallel_for};
}
