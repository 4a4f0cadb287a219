/*
 * watchdog.c - guards against a program that never returns from run().
 *
 * An endless loop in ST (WHILE TRUE, a FOR whose bound never comes) would
 * leave the last published outputs energised forever.  A watchdog thread
 * looks every 20 ms at how long the current run() call has lasted; beyond
 * --watchdog milliseconds it forces the outputs safe by itself (coils cleared
 * in the Modbus image, coils and words at zero at the I/O layer), reports the fault in
 * the diagnostic block and the log, and from then on answers SIGINT/SIGTERM
 * in place of the stuck scan thread: it flushes the log and exits 0 (retained
 * data stay as of the last completed save).  If run() does return, the scan
 * thread sees the trip and stops the program like any other fault.
 *
 * With real-time scheduling on, this thread runs SCHED_FIFO one level above
 * the scan: a scan spinning at SCHED_FIFO cannot keep it off the CPU, even
 * with one CPU.  On a trip it lowers the stuck scan thread to SCHED_IDLE, so
 * the threads below the scan (the Modbus server, the log) run again and the
 * host can read the fault; the scan thread raises itself back to SCHED_FIFO
 * if run() ever returns (realtime.c).  The locks it takes, rt->lock and
 * rt->io_lock, are priority-inheriting: a thread holding one when the scan
 * got stuck (the Modbus server, preempted by the scan on its CPU) is raised
 * to this thread's priority until it lets go.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <pthread.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "runtime.h"

struct watchdog {
    runtime_t *rt;
    pthread_t thread;
    pthread_mutex_t mu;
    pthread_cond_t cv;
    bool stopping;
};

static void force_outputs_safe(runtime_t *rt, uint64_t stuck_ns)
{
    static const plc_bool_t no_bits[MAP_BITS];
    static const uint16_t no_words[MAP_WORDS];
    bus_image_t *b = &rt->bimg;

    pthread_mutex_lock(&rt->lock);
    memset(b->coils, 0, sizeof b->coils);
    diag_put16(b, DIAG_STATE, PLC_STATE_FAULTED);
    diag_put16(b, DIAG_FAULT_KIND, RT_FAULT_WATCHDOG);
    diag_put16(b, DIAG_FAULT_LINE, 0);
    diag_put16(b, DIAG_FAULT_COL, 0);
    pthread_mutex_unlock(&rt->lock);

    pthread_mutex_lock(&rt->io_lock);
    rt->opt.io->write_outputs(rt->io_state, no_bits, no_words);
    pthread_mutex_unlock(&rt->io_lock);

    atomic_store(&rt->live.state, PLC_STATE_FAULTED);
    atomic_store(&rt->live.fault_kind, RT_FAULT_WATCHDOG);
    atomic_store(&rt->live.fault_line, 0);
    const bool lowered = scan_lower_stuck(rt);
    log_msg(rt->log, LOG_ERROR, "watchdog: the program has been inside run() for %.0f ms (limit %d ms); "
            "outputs forced safe, program stopped, Modbus still serving%s", stuck_ns / 1e6, rt->opt.watchdog_ms,
            lowered ? "; the stuck scan thread lowered to SCHED_IDLE" : "");
}

static void setup_priority(const runtime_t *rt)
{
    rt_thread_name("watchdog");
    int prio = rt_thread_fifo(rt, +1);
    if (prio > 0)
        log_msg(rt->log, LOG_INFO, "watchdog: thread is SCHED_FIFO priority %d, above the scan", prio);
    else if (prio < 0)
        log_msg(rt->log, LOG_WARN, "watchdog: thread at normal priority (SCHED_FIFO %d: %s): a scan stuck at "
                "SCHED_FIFO may keep it from running", rt->opt.rt_priority + 1, strerror(-prio));
}

static void *watchdog_thread(void *arg)
{
    watchdog_t *wd = arg;
    runtime_t *rt = wd->rt;
    const uint64_t limit = (uint64_t)rt->opt.watchdog_ms * 1000000u;
    sigset_t stop;
    struct timespec next;

    setup_priority(rt);
    sigemptyset(&stop);
    sigaddset(&stop, SIGINT);
    sigaddset(&stop, SIGTERM);
    clock_gettime(CLOCK_MONOTONIC, &next);

    pthread_mutex_lock(&wd->mu);
    while (!wd->stopping) {
        next.tv_nsec += 20000000;
        if (next.tv_nsec >= 1000000000) {
            next.tv_nsec -= 1000000000;
            next.tv_sec++;
        }
        if (pthread_cond_timedwait(&wd->cv, &wd->mu, &next) != ETIMEDOUT)
            continue;
        if (!atomic_load(&rt->watchdog_tripped)) {
            uint64_t started = atomic_load(&rt->run_started_ns);
            uint64_t now = now_ns();
            if (started != 0 && now > started && now - started > limit) {
                atomic_store(&rt->watchdog_tripped, true);
                force_outputs_safe(rt, now - started);
            }
            continue;
        }
        /* Tripped: the scan thread may never poll for signals again. */
        struct timespec zero = { 0, 0 };
        int sig = sigtimedwait(&stop, NULL, &zero);
        if (sig > 0 && atomic_load(&rt->run_started_ns) != 0) {
            log_msg(rt->log, LOG_INFO, "%s received while the program is stuck: exiting with outputs safe; "
                    "retained data as of the last completed save", sig == SIGINT ? "SIGINT" : "SIGTERM");
            log_close(rt->log);
            _exit(0);
        }
        if (sig > 0)                      /* the scan thread is alive again: let it stop in order */
            pthread_kill(rt->scan_thread, sig);
    }
    pthread_mutex_unlock(&wd->mu);
    return NULL;
}

int watchdog_start(runtime_t *rt, watchdog_t **out)
{
    watchdog_t *wd;
    pthread_condattr_t ca;

    *out = NULL;
    if (rt->opt.watchdog_ms <= 0) {
        log_msg(rt->log, LOG_WARN, "scan watchdog off (--watchdog 0): a program stuck in a loop keeps its "
                "outputs");
        return 0;
    }
    wd = calloc(1, sizeof *wd);
    if (!wd)
        return -1;
    wd->rt = rt;
    rt_mutex_init(&wd->mu);
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&wd->cv, &ca);
    pthread_condattr_destroy(&ca);
    if (pthread_create(&wd->thread, NULL, watchdog_thread, wd) != 0) {
        free(wd);
        return -1;
    }
    *out = wd;
    return 0;
}

void watchdog_stop(watchdog_t *wd)
{
    if (!wd)
        return;
    pthread_mutex_lock(&wd->mu);
    wd->stopping = true;
    pthread_cond_signal(&wd->cv);
    pthread_mutex_unlock(&wd->mu);
    pthread_join(wd->thread, NULL);
    pthread_mutex_destroy(&wd->mu);
    pthread_cond_destroy(&wd->cv);
    free(wd);
}
