/*
 * audit.c - the audit file (--audit): who wrote what, one line each.
 *
 * Two threads write there: the monitor (writes, forces, refused tokens:
 * monitor.c) and the Modbus server (every write request, served or refused,
 * at a bounded rate: modbus_server.c).  Neither waits for the disk: a line is
 * copied into a queue of AUDIT_QUEUE lines under a short priority-inheriting
 * lock, and the audit thread (SCHED_OTHER) appends it with its UTC time and
 * flushes.  With the queue full a line is dropped and counted, and the count
 * is written as a line of its own when there is room again: a stalled disk
 * costs audit lines, never a Modbus answer or a scan.
 *
 * Line: "2026-12-05T01:02:03.456Z TEXT".
 */
#define _GNU_SOURCE
#include <errno.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "runtime.h"

#define AUDIT_QUEUE 256
#define AUDIT_LINE 512

typedef struct audit_item {
    uint64_t realtime_ns;
    char text[AUDIT_LINE];
} audit_item_t;

struct audit {
    runtime_t *rt;
    FILE *file;
    pthread_mutex_t lock;           /* guards the queue and the counts */
    audit_item_t queue[AUDIT_QUEUE];
    unsigned head, count;           /* oldest line, lines queued */
    unsigned dropped;               /* lines lost to a full queue, not reported yet */
    bool stopping;
    rt_wake_t wake;
    pthread_t thread;
};

static uint64_t realtime_now(void)
{
    struct timespec ts;

    clock_gettime(CLOCK_REALTIME, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

static void append(audit_t *a, uint64_t when_ns, const char *text)
{
    time_t sec = (time_t)(when_ns / 1000000000u);
    struct tm tm;
    char stamp[40];

    gmtime_r(&sec, &tm);
    strftime(stamp, sizeof stamp, "%Y-%m-%dT%H:%M:%S", &tm);
    fprintf(a->file, "%s.%03uZ %s\n", stamp, (unsigned)(when_ns % 1000000000u / 1000000u), text);
}

static void *audit_thread(void *arg)
{
    audit_t *a = arg;
    audit_item_t item;

    rt_thread_name("audit");
    for (;;) {
        unsigned written = 0;
        for (;;) {
            pthread_mutex_lock(&a->lock);
            bool have = a->count > 0;
            unsigned dropped = 0;
            if (have) {
                item = a->queue[a->head];
                a->head = (a->head + 1) % AUDIT_QUEUE;
                a->count--;
            } else {
                dropped = a->dropped;
                a->dropped = 0;
            }
            bool stopping = a->stopping;
            pthread_mutex_unlock(&a->lock);
            if (have) {
                append(a, item.realtime_ns, item.text);
                written++;
                continue;
            }
            if (dropped) {
                char text[96];
                snprintf(text, sizeof text, "audit: %u lines lost (the audit file was written too slowly)",
                         dropped);
                append(a, realtime_now(), text);
                written++;
            }
            if (written)
                fflush(a->file);
            if (stopping)
                return NULL;
            break;
        }
        rt_wake_wait(&a->wake, RT_WAKE_NEVER);
    }
}

int audit_open(runtime_t *rt, audit_t **out)
{
    *out = NULL;
    if (!rt->opt.audit_path)
        return 0;
    audit_t *a = calloc(1, sizeof *a);
    if (!a)
        return -1;
    a->rt = rt;
    a->file = fopen(rt->opt.audit_path, "a");
    if (!a->file) {
        log_msg(rt->log, LOG_ERROR, "audit: cannot open the audit file %s: %s", rt->opt.audit_path, strerror(errno));
        free(a);
        return -1;
    }
    rt_mutex_init(&a->lock);
    rt_wake_init(&a->wake);
    if (pthread_create(&a->thread, NULL, audit_thread, a) != 0) {
        log_msg(rt->log, LOG_ERROR, "audit: cannot start the audit thread");
        rt_wake_destroy(&a->wake);
        pthread_mutex_destroy(&a->lock);
        fclose(a->file);
        free(a);
        return -1;
    }
    *out = a;
    return 0;
}

void audit_close(audit_t *a)
{
    if (!a)
        return;
    pthread_mutex_lock(&a->lock);
    a->stopping = true;
    pthread_mutex_unlock(&a->lock);
    rt_wake(&a->wake);
    pthread_join(a->thread, NULL);           /* it writes every queued line before it ends */
    rt_wake_destroy(&a->wake);
    pthread_mutex_destroy(&a->lock);
    fclose(a->file);
    free(a);
}

void audit_line(audit_t *a, const char *fmt, ...)
{
    char text[AUDIT_LINE];
    va_list ap;

    if (!a)
        return;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    const uint64_t when = realtime_now();
    pthread_mutex_lock(&a->lock);
    if (a->count == AUDIT_QUEUE) {
        a->dropped++;
    } else {
        audit_item_t *item = &a->queue[(a->head + a->count) % AUDIT_QUEUE];
        item->realtime_ns = when;
        memcpy(item->text, text, sizeof text);
        a->count++;
    }
    pthread_mutex_unlock(&a->lock);
    rt_wake(&a->wake);
}
