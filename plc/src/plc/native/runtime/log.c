/*
 * log.c - log lines and the live status line, on stderr.
 *
 * Any thread may log; a line is formatted into a fixed ring under a short
 * lock and written by the log thread, so the scan thread never waits for a
 * terminal or a pipe (when the ring is full, lines are dropped and counted).
 *
 * On a terminal the log thread keeps a one-line live status (scan statistics,
 * clients, PLC state) redrawn four times a second below the log lines.
 * Otherwise the same status is written as a plain log line every
 * --status-interval seconds.
 *
 * When stderr is the systemd journal ($JOURNAL_STREAM names it), every line
 * starts with its syslog priority instead of a time stamp ("<3>" error,
 * "<4>" warning, "<6>" info): journald files it at that priority and adds
 * its own time.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "runtime.h"
#include "monitor.h"

#define LOG_SLOTS 256
#define LOG_LINE 512

struct log_sink {
    runtime_t *rt;
    pthread_mutex_t mu;
    pthread_cond_t cv;
    char ring[LOG_SLOTS][LOG_LINE];
    unsigned head, tail;          /* head: next free slot; tail: next to write */
    unsigned dropped;
    bool stopping;
    bool tty;                     /* live status line on a terminal */
    bool journal;                 /* stderr is the systemd journal: priority prefixes */
    double status_period_s;       /* 0: no status */
    bool status_shown;
    pthread_t thread;
};

static void write_fd(const char *s, size_t n)
{
    while (n > 0) {
        ssize_t w = write(STDERR_FILENO, s, n);
        if (w < 0) {
            if (errno == EINTR)
                continue;
            return;
        }
        s += w;
        n -= (size_t)w;
    }
}

static const char *state_name(unsigned s)
{
    switch (s) {
    case PLC_STATE_STARTING: return "START";
    case PLC_STATE_RUNNING: return "RUN";
    case PLC_STATE_FAULTED: return "FAULT";
    case PLC_STATE_STOPPING: return "STOP";
    default: return "?";
    }
}

static void compose_status(log_sink_t *ls, char *out, size_t n)
{
    runtime_t *rt = ls->rt;
    const bus_image_t *b = &rt->bimg;

    pthread_mutex_lock(&rt->lock);
    unsigned state = b->input_regs[DIAG_BASE + DIAG_STATE];
    unsigned long long scans = (unsigned long long)diag_get64(b, DIAG_SCAN_COUNT);
    unsigned scan_last = diag_get32(b, DIAG_SCAN_LAST_US), scan_p99 = diag_get32(b, DIAG_SCAN_P99_US);
    unsigned scan_max = diag_get32(b, DIAG_SCAN_MAX_US);
    unsigned wake_p99 = diag_get32(b, DIAG_WAKE_P99_US), wake_max = diag_get32(b, DIAG_WAKE_MAX_US);
    unsigned overruns = diag_get32(b, DIAG_OVERRUNS), clients = b->input_regs[DIAG_BASE + DIAG_CLIENTS];
    unsigned requests = diag_get32(b, DIAG_REQUESTS);
    unsigned fault = b->input_regs[DIAG_BASE + DIAG_FAULT_KIND], line = b->input_regs[DIAG_BASE + DIAG_FAULT_LINE];
    pthread_mutex_unlock(&rt->lock);

    char app[160];
    events_status(rt->events, app, sizeof app);
    int k = snprintf(out, n, "%s", state_name(state));
    if (state == PLC_STATE_FAULTED && k >= 0 && (size_t)k < n)
        k += snprintf(out + k, n - (size_t)k, " (fault %u, line %u)", fault, line);
    if (app[0] && k >= 0 && (size_t)k < n)
        k += snprintf(out + k, n - (size_t)k, "%s", app);
    if (k >= 0 && (size_t)k < n)
        snprintf(out + k, n - (size_t)k,
                 " | scans %llu | scan us last %u p99 %u max %u | wake-up us p99 %u max %u | overruns %u"
                 " | clients %u, requests %u",
                 scans, scan_last, scan_p99, scan_max, wake_p99, wake_max, overruns, clients, requests);
}

/* $JOURNAL_STREAM is "device:inode" of the journal's stream, when stderr may be it. */
static bool stderr_is_journal(void)
{
    const char *js = getenv("JOURNAL_STREAM");
    unsigned long long dev, ino;
    struct stat st;

    if (!js || sscanf(js, "%llu:%llu", &dev, &ino) != 2 || fstat(STDERR_FILENO, &st) != 0)
        return false;
    return (unsigned long long)st.st_dev == dev && (unsigned long long)st.st_ino == ino;
}

/* syslog priorities: LOG_ERR 3, LOG_WARNING 4, LOG_INFO 6 */
static int journal_priority(log_level_t level)
{
    return level == LOG_ERROR ? 3 : level == LOG_WARN ? 4 : 6;
}

static void format_line(char *out, size_t n, bool journal, log_level_t level, const char *fmt, va_list ap)
{
    struct timespec ts;
    struct tm tm;
    const char *tag = level == LOG_ERROR ? "error: " : level == LOG_WARN ? "warning: " : "";

    if (journal) {
        int k = snprintf(out, n, "<%d>%s", journal_priority(level), tag);
        vsnprintf(out + k, n - (size_t)k, fmt, ap);
        return;
    }
    clock_gettime(CLOCK_REALTIME, &ts);
    localtime_r(&ts.tv_sec, &tm);
    int k = snprintf(out, n, "%02d:%02d:%02d.%03ld " RT_NAME ": %s", tm.tm_hour, tm.tm_min, tm.tm_sec,
                     ts.tv_nsec / 1000000, tag);
    if (k < 0 || (size_t)k >= n)
        k = 0;
    vsnprintf(out + k, n - (size_t)k, fmt, ap);
}

static void *log_thread(void *arg)
{
    log_sink_t *ls = arg;
    char batch[16][LOG_LINE];
    char status[LOG_LINE];
    struct timespec next;

    clock_gettime(CLOCK_MONOTONIC, &next);
    if (!ls->tty && ls->status_period_s > 0) {     /* log lines: the first one after a period */
        uint64_t t = (uint64_t)next.tv_sec * 1000000000u + (uint64_t)next.tv_nsec
                     + (uint64_t)(ls->status_period_s * 1e9);
        next.tv_sec = (time_t)(t / 1000000000u);
        next.tv_nsec = (long)(t % 1000000000u);
    }
    pthread_mutex_lock(&ls->mu);
    for (;;) {
        bool status_due = false;

        while (ls->head == ls->tail && !ls->stopping) {
            if (ls->status_period_s <= 0) {
                pthread_cond_wait(&ls->cv, &ls->mu);
                continue;
            }
            if (pthread_cond_timedwait(&ls->cv, &ls->mu, &next) == ETIMEDOUT) {
                status_due = true;
                break;
            }
        }
        unsigned n = 0, dropped = ls->dropped;
        while (ls->tail != ls->head && n < 16) {
            memcpy(batch[n++], ls->ring[ls->tail % LOG_SLOTS], LOG_LINE);
            ls->tail++;
        }
        ls->dropped = 0;
        bool stopping = ls->stopping && ls->head == ls->tail;
        pthread_mutex_unlock(&ls->mu);

        if (ls->tty && ls->status_shown && (n > 0 || stopping))
            write_fd("\r\033[K", 4);
        for (unsigned i = 0; i < n; i++) {
            write_fd(batch[i], strlen(batch[i]));
            write_fd("\n", 1);
        }
        if (dropped) {
            char msg[96];
            int k = snprintf(msg, sizeof msg, "%s" RT_NAME ": warning: %u log lines dropped (log output too "
                             "slow)\n", ls->journal ? "<4>" : "", dropped);
            write_fd(msg, (size_t)k);
        }
        if (stopping)
            break;
        if (ls->status_period_s > 0 && !status_due) {
            struct timespec now;
            clock_gettime(CLOCK_MONOTONIC, &now);
            status_due = now.tv_sec > next.tv_sec || (now.tv_sec == next.tv_sec && now.tv_nsec >= next.tv_nsec);
        }
        if (status_due) {
            uint64_t step = (uint64_t)(ls->status_period_s * 1e9);
            uint64_t t = (uint64_t)next.tv_sec * 1000000000u + (uint64_t)next.tv_nsec + step;
            next.tv_sec = (time_t)(t / 1000000000u);
            next.tv_nsec = (long)(t % 1000000000u);
        }
        if (ls->status_period_s > 0 && (status_due || (ls->tty && n > 0))) {
            compose_status(ls, status, sizeof status);
            if (ls->tty) {
                write_fd("\r\033[K", 4);
                write_fd(status, strlen(status));
                ls->status_shown = true;
            } else if (status_due) {
                char line[LOG_LINE + 64];
                struct timespec ts;
                struct tm tm;
                int k;
                clock_gettime(CLOCK_REALTIME, &ts);
                localtime_r(&ts.tv_sec, &tm);
                if (ls->journal)
                    k = snprintf(line, sizeof line, "<6>status %s\n", status);
                else
                    k = snprintf(line, sizeof line, "%02d:%02d:%02d.%03ld " RT_NAME ": status %s\n", tm.tm_hour,
                                 tm.tm_min, tm.tm_sec, ts.tv_nsec / 1000000, status);
                write_fd(line, k > 0 && (size_t)k < sizeof line ? (size_t)k : strlen(line));
            }
        }
        pthread_mutex_lock(&ls->mu);
    }
    if (ls->tty && ls->status_shown) {
        compose_status(ls, status, sizeof status);
        write_fd(status, strlen(status));
        write_fd("\n", 1);
    }
    return NULL;
}

int log_open(runtime_t *rt, log_sink_t **out)
{
    log_sink_t *ls = calloc(1, sizeof *ls);

    if (!ls)
        return -1;
    ls->rt = rt;
    pthread_mutex_init(&ls->mu, NULL);
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&ls->cv, &ca);
    pthread_condattr_destroy(&ca);

    bool on_tty = isatty(STDERR_FILENO);
    ls->journal = stderr_is_journal();
    switch (rt->opt.status) {
    case STATUS_AUTO: ls->tty = on_tty; break;
    case STATUS_TTY: ls->tty = true; break;
    default: ls->tty = false; break;
    }
    if (rt->opt.status == STATUS_OFF)
        ls->status_period_s = 0;
    else
        ls->status_period_s = ls->tty ? 0.25 : rt->opt.status_interval_s;

    if (pthread_create(&ls->thread, NULL, log_thread, ls) != 0) {
        free(ls);
        return -1;
    }
    *out = ls;
    return 0;
}

void log_close(log_sink_t *ls)
{
    if (!ls)
        return;
    pthread_mutex_lock(&ls->mu);
    ls->stopping = true;
    pthread_cond_signal(&ls->cv);
    pthread_mutex_unlock(&ls->mu);
    pthread_join(ls->thread, NULL);
    pthread_mutex_destroy(&ls->mu);
    pthread_cond_destroy(&ls->cv);
    free(ls);
}

void log_msg(log_sink_t *ls, log_level_t level, const char *fmt, ...)
{
    va_list ap;

    va_start(ap, fmt);
    if (!ls) {           /* before the log thread exists */
        char line[LOG_LINE];
        format_line(line, sizeof line, stderr_is_journal(), level, fmt, ap);
        va_end(ap);
        write_fd(line, strlen(line));
        write_fd("\n", 1);
        return;
    }
    pthread_mutex_lock(&ls->mu);
    if (ls->head - ls->tail >= LOG_SLOTS) {
        ls->dropped++;
    } else {
        format_line(ls->ring[ls->head % LOG_SLOTS], LOG_LINE, ls->journal, level, fmt, ap);
        ls->head++;
        pthread_cond_signal(&ls->cv);
    }
    pthread_mutex_unlock(&ls->mu);
    va_end(ap);
}
