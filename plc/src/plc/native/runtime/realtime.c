/*
 * realtime.c - the runtime's real-time rules, in one place (README, "Threads, priorities and locks").
 *
 *   - The scan thread: pinned to --cpu, the CPUs' idle exit latency held at
 *     --cpu-latency, SCHED_FIFO at --rt-priority P, memory locked.
 *   - Every other thread: a name (top -H, ps -L, /proc/PID/task/TID/comm) and a
 *     priority relative to the scan's: the watchdog P+1 (it must preempt a scan
 *     stuck in a loop), the remote I/O threads P-5, the Modbus server P-10; the
 *     log, monitor and retain writer threads stay SCHED_OTHER.
 *   - Every mutex the scan thread can wait for is priority-inheriting
 *     (rt_mutex_init): while the scan waits, the holder runs at the scan's
 *     priority, so a holder that a busy CPU preempted cannot keep the scan
 *     waiting.  The mutexes it only trylocks are initialised the same way.
 *   - The scan thread wakes other threads with rt_wake(), a POSIX semaphore
 *     (sem_post: an atomic add and, when somebody waits, a futex wake; no
 *     lock), never with a condition variable: glibc's pthread_cond_signal takes
 *     the condvar's internal lock and may wait there for earlier waiters, which
 *     can be SCHED_OTHER threads.
 *   - A scan stuck in run() is lowered to SCHED_IDLE by the watchdog (the
 *     threads below it, the Modbus server first, would otherwise never run on
 *     its CPU) and raises itself back to SCHED_FIFO when run() returns.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <sched.h>
#include <semaphore.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

#include "runtime.h"

/* ---------------------------------------------------------------- locks */

void rt_mutex_init(pthread_mutex_t *m)
{
    pthread_mutexattr_t a;

    pthread_mutexattr_init(&a);
    /* Linux has priority-inheriting futexes; were the protocol refused, a plain mutex stays correct, only
     * exposed to priority inversion again */
    (void)pthread_mutexattr_setprotocol(&a, PTHREAD_PRIO_INHERIT);
    pthread_mutex_init(m, &a);
    pthread_mutexattr_destroy(&a);
}

void rt_wake_init(rt_wake_t *w)
{
    sem_init(&w->sem, 0, 0);
}

void rt_wake_destroy(rt_wake_t *w)
{
    sem_destroy(&w->sem);
}

void rt_wake(rt_wake_t *w)
{
    (void)sem_post(&w->sem);      /* EOVERFLOW: a wake-up is pending anyway */
}

void rt_wake_wait(rt_wake_t *w, uint64_t until_ns)
{
    int rc;

    if (until_ns == RT_WAKE_NEVER) {
        while ((rc = sem_wait(&w->sem)) != 0 && errno == EINTR)
            ;
    } else {
        struct timespec ts = { .tv_sec = (time_t)(until_ns / 1000000000u),
                               .tv_nsec = (long)(until_ns % 1000000000u) };
        while ((rc = sem_clockwait(&w->sem, CLOCK_MONOTONIC, &ts)) != 0 && errno == EINTR)
            ;
    }
    /* Wake-ups given while nobody waited are one: the caller looks at its conditions again anyway. */
    while (sem_trywait(&w->sem) == 0)
        ;
}

/* -------------------------------------------------------------- threads */

void rt_thread_name(const char *name)
{
    (void)pthread_setname_np(pthread_self(), name);
}

static int clamp_priority(int p)
{
    return p < 1 ? 1 : p > 99 ? 99 : p;
}

int rt_thread_fifo(const runtime_t *rt, int offset)
{
    struct sched_param sp = { .sched_priority = clamp_priority(rt->opt.rt_priority + offset) };

    if (!rt->opt.realtime)
        return 0;
    int rc = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
    return rc != 0 ? -rc : sp.sched_priority;
}

/* ------------------------------------------------------ the scan thread */

/* --cpu: this thread only.  The other threads were started before and keep the
 * process's CPUs.  A failure is reported and the scan runs unpinned. */
static void pin_scan_thread(runtime_t *rt)
{
    cpu_set_t set;
    int rc;

    if (rt->opt.cpu < 0)
        return;
    CPU_ZERO(&set);
    CPU_SET(rt->opt.cpu, &set);
    rc = pthread_setaffinity_np(pthread_self(), sizeof set, &set);
    if (rc != 0)
        log_msg(rt->log, LOG_WARN, "cannot pin the scan thread to CPU %d (%s); it runs on any CPU the "
                "process may use", rt->opt.cpu, strerror(rc));
    else
        log_msg(rt->log, LOG_INFO, "scan thread pinned to CPU %d", rt->opt.cpu);
}

/* --cpu-latency: a PM QoS request, in force while the file stays open (the
 * kernel takes the lowest of all open requests; closing withdraws ours).  On a
 * CPU that sleeps between scans the wake-up waits for the idle state's exit: 0
 * keeps idle CPUs polling, as cyclictest does while it measures.  A failure is
 * reported and the scan runs with the kernel's idle states. */
static void hold_cpu_latency(runtime_t *rt)
{
    int32_t us = rt->opt.cpu_latency_us;
    int fd;

    if (us < 0)
        return;
    fd = open("/dev/cpu_dma_latency", O_WRONLY | O_CLOEXEC);
    if (fd < 0) {
        log_msg(rt->log, LOG_WARN, "cannot limit the CPUs' idle exit latency to %d us (/dev/cpu_dma_latency: %s); "
                "wake-up jitter will be higher", (int)us, strerror(errno));
        return;
    }
    if (write(fd, &us, sizeof us) != (ssize_t)sizeof us) {
        log_msg(rt->log, LOG_WARN, "cannot limit the CPUs' idle exit latency to %d us (writing "
                "/dev/cpu_dma_latency: %s); wake-up jitter will be higher", (int)us, strerror(errno));
        close(fd);
        return;
    }
    rt->cpu_latency_fd = fd;
    log_msg(rt->log, LOG_INFO, "CPU idle exit latency limited to %d us while running (PM QoS)%s", (int)us,
            us == 0 ? ": idle CPUs poll" : "");
}

void scan_release_realtime(runtime_t *rt)
{
    if (rt->cpu_latency_fd >= 0)
        close(rt->cpu_latency_fd);
    rt->cpu_latency_fd = -1;
}

void scan_setup_realtime(runtime_t *rt)
{
    pin_scan_thread(rt);
    hold_cpu_latency(rt);
    if (!rt->opt.realtime) {
        log_msg(rt->log, LOG_INFO, "real-time scheduling off (--no-rt)");
        return;
    }
    int prio = rt_thread_fifo(rt, 0);
    if (prio < 0) {
        log_msg(rt->log, LOG_WARN, "real-time scheduling not permitted (%s); the scan runs at normal "
                "priority and wake-up jitter will be higher", strerror(-prio));
        return;
    }
    rt->flags |= DIAG_FLAG_REALTIME;
    if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0)
        log_msg(rt->log, LOG_WARN, "scan thread is SCHED_FIFO %d but memory could not be locked (%s)", prio,
                strerror(errno));
    else
        log_msg(rt->log, LOG_INFO, "scan thread is SCHED_FIFO priority %d, memory locked", prio);
}

bool scan_lower_stuck(runtime_t *rt)
{
    struct sched_param sp;
    int policy;

    if (pthread_getschedparam(rt->scan_thread, &policy, &sp) != 0 || policy != SCHED_FIFO)
        return false;
    memset(&sp, 0, sizeof sp);
    if (pthread_setschedparam(rt->scan_thread, SCHED_IDLE, &sp) != 0)
        return false;
    /* after the change: the scan raises itself again only once it has been lowered */
    atomic_store(&rt->scan_lowered, true);
    return true;
}

void scan_raise_again(runtime_t *rt)
{
    if (!atomic_exchange(&rt->scan_lowered, false))
        return;
    int prio = rt_thread_fifo(rt, 0);
    if (prio < 0)
        log_msg(rt->log, LOG_WARN, "the scan thread cannot return to SCHED_FIFO after the watchdog (%s); it "
                "goes on at SCHED_IDLE", strerror(-prio));
    else
        log_msg(rt->log, LOG_INFO, "run() returned: the scan thread is SCHED_FIFO priority %d again", prio);
}
