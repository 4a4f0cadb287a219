/*
 * log.c - log lines and the live status line, on stderr.
 *
 * Any thread may log, the scan thread included, without ever waiting: a line
 * is formatted (vsnprintf, no lock) into a lock-free ring with its
 * CLOCK_REALTIME time, and the log thread formats the time (localtime_r, which
 * takes glibc's time-zone lock) and writes it, so no logging thread waits for
 * a lock, a terminal or a pipe.  When the ring is full, lines are dropped and
 * counted, and the count is logged.  The log thread stays SCHED_OTHER and
 * takes none of the scan's locks: the status line's figures are atomics
 * (runtime.h, live_status_t).
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

#define LOG_SLOTS 256       /* a power of two: position % LOG_SLOTS stays continuous across the 32-bit wrap */
#define LOG_LINE 512
#define LOG_OUT (LOG_LINE + 64)   /* a line with its time stamp or priority, level tag and newline */

/*
 * The ring: a bounded queue of LOG_SLOTS slots, many producers, one consumer (the log thread), without a
 * lock.  Each slot's `seq` says whose turn it is: equal to the position p that maps to it, it is free for
 * the producer that claims p (a compare-and-swap on `head`); p + 1, it holds p's line for the log thread,
 * which gives it back as p + LOG_SLOTS.  A producer never waits: with the ring full the line is dropped and
 * counted.  A producer preempted between its claim and its store only delays the lines after it.
 */
typedef struct log_slot {
    atomic_uint seq;
    log_level_t level;
    uint64_t realtime_ns;         /* CLOCK_REALTIME when logged (a vDSO read): the log thread formats it */
    char text[LOG_LINE];          /* the message, without time stamp or level */
} log_slot_t;

struct log_sink {
    runtime_t *rt;
    log_slot_t ring[LOG_SLOTS];
    atomic_uint head;             /* next position to claim (producers) */
    unsigned tail;                /* next position to write (log thread) */
    atomic_uint dropped;          /* lines lost to a full ring since the last report */
    atomic_bool stopping;
    rt_wake_t wake;               /* a line was stored, or log_close() */
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

static uint64_t realtime_ns(void)
{
    struct timespec ts;

    clock_gettime(CLOCK_REALTIME, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
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
    live_status_t *l = &rt->live;
#define LIVE(field) atomic_load_explicit(&l->field, memory_order_relaxed)
    unsigned state = LIVE(state), fault = LIVE(fault_kind), line = LIVE(fault_line);
    unsigned long long scans = LIVE(scans);
    unsigned scan_last = LIVE(scan_last_us), scan_p99 = LIVE(scan_p99_us), scan_max = LIVE(scan_max_us);
    unsigned wake_p99 = LIVE(wake_p99_us), wake_max = LIVE(wake_max_us), overruns = LIVE(overruns);
    unsigned clients = LIVE(clients), requests = LIVE(requests);
#undef LIVE

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

static const char *level_tag(log_level_t level)
{
    return level == LOG_ERROR ? "error: " : level == LOG_WARN ? "warning: " : "";
}

/* One output line: time stamp (or journald priority), level tag, text, newline.  Local time is formatted
 * here, on the thread that writes, never on the one that logged (localtime_r takes glibc's time-zone lock). */
static size_t format_out(char *out, size_t n, bool journal, log_level_t level, uint64_t when_ns, const char *text)
{
    int k;

    if (journal) {
        k = snprintf(out, n, "<%d>%s%s\n", journal_priority(level), level_tag(level), text);
    } else {
        time_t sec = (time_t)(when_ns / 1000000000u);
        struct tm tm;
        localtime_r(&sec, &tm);
        k = snprintf(out, n, "%02d:%02d:%02d.%03u " RT_NAME ": %s%s\n", tm.tm_hour, tm.tm_min, tm.tm_sec,
                     (unsigned)(when_ns % 1000000000u / 1000000u), level_tag(level), text);
    }
    if (k < 0)
        return 0;
    if ((size_t)k >= n) {             /* cut: still one line */
        out[n - 2] = '\n';
        return n - 1;
    }
    return (size_t)k;
}

/* The log thread's: the next stored line, or false.  The slot is free again on return. */
static bool take_line(log_sink_t *ls, log_level_t *level, uint64_t *when_ns, char text[LOG_LINE])
{
    log_slot_t *s = &ls->ring[ls->tail % LOG_SLOTS];

    if (atomic_load_explicit(&s->seq, memory_order_acquire) != ls->tail + 1)
        return false;
    *level = s->level;
    *when_ns = s->realtime_ns;
    memcpy(text, s->text, LOG_LINE);
    atomic_store_explicit(&s->seq, ls->tail + LOG_SLOTS, memory_order_release);
    ls->tail++;
    return true;
}

/* Writes every line stored so far; returns how many. */
static unsigned write_lines(log_sink_t *ls)
{
    char text[LOG_LINE], out[LOG_OUT];
    log_level_t level;
    uint64_t when;
    unsigned n = 0;

    while (take_line(ls, &level, &when, text)) {
        if (n++ == 0 && ls->tty && ls->status_shown)
            write_fd("\r\033[K", 4);
        write_fd(out, format_out(out, sizeof out, ls->journal, level, when, text));
    }
    unsigned dropped = atomic_exchange(&ls->dropped, 0);
    if (dropped) {
        char msg[96];
        snprintf(msg, sizeof msg, "%u log lines dropped (log output too slow)", dropped);
        write_fd(out, format_out(out, sizeof out, ls->journal, LOG_WARN, realtime_ns(), msg));
    }
    return n;
}

static void write_status(log_sink_t *ls, bool due)
{
    char status[LOG_LINE], out[LOG_OUT + 16];

    compose_status(ls, status, sizeof status);
    if (ls->tty) {
        write_fd("\r\033[K", 4);
        write_fd(status, strlen(status));
        ls->status_shown = true;
    } else if (due) {
        char text[LOG_LINE + 8];
        snprintf(text, sizeof text, "status %s", status);
        write_fd(out, format_out(out, sizeof out, ls->journal, LOG_INFO, realtime_ns(), text));
    }
}

static void *log_thread(void *arg)
{
    log_sink_t *ls = arg;
    const uint64_t step = (uint64_t)(ls->status_period_s * 1e9);
    /* log lines: the first status after a period; a terminal's line at once */
    uint64_t next = now_ns() + (ls->tty ? 0 : step);

    rt_thread_name("log");
    for (;;) {
        const bool stopping = atomic_load(&ls->stopping);   /* before the last lines: none is left behind */
        const unsigned n = write_lines(ls);

        if (stopping)
            break;
        bool due = false;
        if (step > 0 && now_ns() >= next) {
            due = true;
            next += step;
            if (next < now_ns())          /* the machine held this thread back: no burst of status lines */
                next = now_ns() + step;
        }
        if (step > 0 && (due || (ls->tty && n > 0)))
            write_status(ls, due);
        rt_wake_wait(&ls->wake, step > 0 ? next : RT_WAKE_NEVER);
    }
    if (ls->tty && ls->status_shown) {
        char status[LOG_LINE];
        compose_status(ls, status, sizeof status);
        write_fd("\r\033[K", 4);
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
    for (unsigned i = 0; i < LOG_SLOTS; i++)
        atomic_init(&ls->ring[i].seq, i);
    rt_wake_init(&ls->wake);

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
        rt_wake_destroy(&ls->wake);
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
    atomic_store(&ls->stopping, true);
    rt_wake(&ls->wake);
    pthread_join(ls->thread, NULL);
    rt_wake_destroy(&ls->wake);
    free(ls);
}

/* A free slot of the ring, claimed at *pos; NULL when the ring is full. */
static log_slot_t *claim_slot(log_sink_t *ls, unsigned *pos)
{
    unsigned p = atomic_load_explicit(&ls->head, memory_order_relaxed);

    for (;;) {
        log_slot_t *s = &ls->ring[p % LOG_SLOTS];
        const int turn = (int)(atomic_load_explicit(&s->seq, memory_order_acquire) - p);
        if (turn == 0) {
            if (atomic_compare_exchange_weak_explicit(&ls->head, &p, p + 1, memory_order_relaxed,
                                                      memory_order_relaxed)) {
                *pos = p;
                return s;
            }
        } else if (turn < 0) {
            return NULL;              /* the slot still holds the line LOG_SLOTS positions back */
        } else {
            p = atomic_load_explicit(&ls->head, memory_order_relaxed);   /* another producer took p */
        }
    }
}

void log_msg(log_sink_t *ls, log_level_t level, const char *fmt, ...)
{
    va_list ap;
    unsigned pos;

    va_start(ap, fmt);
    if (!ls) {           /* before the log thread exists (start-up, one thread) */
        char text[LOG_LINE], out[LOG_OUT];
        vsnprintf(text, sizeof text, fmt, ap);
        va_end(ap);
        write_fd(out, format_out(out, sizeof out, stderr_is_journal(), level, realtime_ns(), text));
        return;
    }
    log_slot_t *s = claim_slot(ls, &pos);
    if (!s) {
        va_end(ap);
        atomic_fetch_add(&ls->dropped, 1);
        return;
    }
    s->level = level;
    s->realtime_ns = realtime_ns();
    vsnprintf(s->text, sizeof s->text, fmt, ap);
    va_end(ap);
    atomic_store_explicit(&s->seq, pos + 1, memory_order_release);
    rt_wake(&ls->wake);
}
