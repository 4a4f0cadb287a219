/*
 * scan.c - the periodic scan loop.
 *
 * Period = the program's base tick (GCD of its task intervals).  Deadlines are
 * absolute on CLOCK_MONOTONIC: deadline k = start + k * period, so lateness
 * never accumulates.  The program's clock is virtual (docs/matiec.md): before
 * the scan of tick t, *clock_ns = t * base_tick_ns.
 *
 * A scan that ends after the next deadline is an overrun; the next scan then
 * starts at once.  If it ends more than a whole period late, the deadlines
 * already missed are skipped (counted, not run), so the loop realigns instead
 * of running a burst of back-to-back scans.
 *
 * The loop never waits on the network or the disk: it takes rt->lock only to
 * copy images, and hands retained data to a writer thread.  Every lock it takes
 * is priority-inheriting or only trylocked, and its log lines go into a
 * lock-free ring, time-stamped here and formatted by the log thread (README,
 * "Threads, priorities and locks"; realtime.c).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <inttypes.h>
#include <pthread.h>
#include <signal.h>
#include <string.h>
#include <time.h>

#include "runtime.h"
#include "monitor.h"

uint64_t now_ns(void)
{
    struct timespec ts;

    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

/* ------------------------------------------------------------ histogram */

static unsigned hist_index(uint64_t v)
{
    const uint64_t top = ((uint64_t)1 << (HIST_SUB_BITS + 1 + 33)) - 1;

    if (v < HIST_LINEAR)
        return (unsigned)v;
    if (v > top)
        v = top;
    unsigned e = 63u - (unsigned)__builtin_clzll(v);          /* >= HIST_SUB_BITS + 1 */
    unsigned sub = (unsigned)(v >> (e - HIST_SUB_BITS)) & ((1u << HIST_SUB_BITS) - 1);
    return HIST_LINEAR + (e - HIST_SUB_BITS - 1) * (1u << HIST_SUB_BITS) + sub;
}

/* Middle of the values that fall into bucket i. */
static uint64_t hist_value(unsigned i)
{
    if (i < HIST_LINEAR)
        return i;
    unsigned k = i - HIST_LINEAR;
    unsigned e = k / (1u << HIST_SUB_BITS) + HIST_SUB_BITS + 1;
    uint64_t sub = k % (1u << HIST_SUB_BITS);
    uint64_t width = (uint64_t)1 << (e - HIST_SUB_BITS);
    return ((uint64_t)1 << e) + sub * width + width / 2;
}

void hist_add(histogram_t *h, uint64_t ns)
{
    h->count[hist_index(ns)]++;
    if (h->n == 0 || ns < h->min_ns)
        h->min_ns = ns;
    if (ns > h->max_ns)
        h->max_ns = ns;
    h->n++;
    h->sum_ns += ns;
    h->last_ns = ns;
}

uint64_t hist_percentile(const histogram_t *h, double p)
{
    if (h->n == 0)
        return 0;
    uint64_t rank = (uint64_t)(p * (double)h->n + 0.5);
    uint64_t seen = 0;

    if (rank < 1)
        rank = 1;
    for (unsigned i = 0; i < HIST_BUCKETS; i++) {
        seen += h->count[i];
        if (seen >= rank) {
            uint64_t v = hist_value(i);
            /* A bucket's middle may lie outside what was actually seen. */
            return v < h->min_ns ? h->min_ns : v > h->max_ns ? h->max_ns : v;
        }
    }
    return h->max_ns;
}

/* ---------------------------------------------------------------- faults */

static const char *fault_name(int kind)
{
    switch (kind) {
    case PLC_FAULT_DIV_ZERO: return "integer division by zero";
    case PLC_FAULT_INDEX: return "array index out of bounds";
    case PLC_FAULT_SUBRANGE: return "value outside its subrange";
    case PLC_FAULT_ASSERT: return "assertion failed";
    case RT_FAULT_WATCHDOG: return "scan watchdog";
    default: return "program fault";
    }
}

static void enter_fault(runtime_t *rt, int rc, uint64_t tick)
{
    const plc_fault_t *f = rt->prog->fault;
    int kind = rc == RT_FAULT_WATCHDOG ? rc : (f && f->kind) ? f->kind : rc;

    atomic_store(&rt->state, PLC_STATE_FAULTED);
    if (kind == RT_FAULT_WATCHDOG) {
        rt->fault_kind = kind;
        rt->fault_line = rt->fault_col = 0;
        log_msg(rt->log, LOG_ERROR, "program returned from run() after the watchdog fired at tick %" PRIu64
                "; it stays stopped", tick);
        return;
    }
    rt->fault_kind = (kind >= PLC_FAULT_DIV_ZERO && kind <= PLC_FAULT_ASSERT) ? kind : RT_FAULT_UNKNOWN;
    rt->fault_line = f ? f->line : 0;
    rt->fault_col = f ? f->col : 0;
    log_msg(rt->log, LOG_ERROR, "program fault at tick %" PRIu64 ": %s (kind %d) in %s at %s:%d:%d; "
            "program stopped, outputs safe, Modbus still serving",
            tick, fault_name(kind), kind, (f && f->pou) ? f->pou : "?", (f && f->file) ? f->file : "?",
            rt->fault_line, rt->fault_col);
}

/* ------------------------------------------------------------ statistics */

static uint32_t us32(uint64_t ns)
{
    uint64_t us = (ns + 500) / 1000;
    return us > UINT32_MAX ? UINT32_MAX : (uint32_t)us;
}

/* The status line's figures of this scan (log.c reads them without a lock). */
static void publish_live(runtime_t *rt)
{
    live_status_t *l = &rt->live;
    const scan_stats_t *s = &rt->stats;

    atomic_store_explicit(&l->state, (unsigned)atomic_load(&rt->state), memory_order_relaxed);
    atomic_store_explicit(&l->fault_kind, (unsigned)rt->fault_kind, memory_order_relaxed);
    atomic_store_explicit(&l->fault_line, (unsigned)rt->fault_line, memory_order_relaxed);
    atomic_store_explicit(&l->scans, s->scans, memory_order_relaxed);
    atomic_store_explicit(&l->scan_last_us, us32(s->scan.last_ns), memory_order_relaxed);
    atomic_store_explicit(&l->scan_p99_us, us32(s->p99_scan_ns), memory_order_relaxed);
    atomic_store_explicit(&l->scan_max_us, us32(s->scan.max_ns), memory_order_relaxed);
    atomic_store_explicit(&l->wake_p99_us, us32(s->p99_wake_ns), memory_order_relaxed);
    atomic_store_explicit(&l->wake_max_us, us32(s->wake.max_ns), memory_order_relaxed);
    atomic_store_explicit(&l->overruns, s->overruns, memory_order_relaxed);
}

/* Caller holds rt->lock. */
static void publish_diag(runtime_t *rt, uint64_t started)
{
    bus_image_t *b = &rt->bimg;
    const scan_stats_t *s = &rt->stats;

    diag_put16(b, DIAG_VERSION, 1);
    diag_put16(b, DIAG_STATE, (uint16_t)atomic_load(&rt->state));
    diag_put16(b, DIAG_FAULT_KIND, (uint16_t)rt->fault_kind);
    diag_put16(b, DIAG_FAULT_LINE, (uint16_t)(rt->fault_line > 65535 ? 65535 : rt->fault_line < 0 ? 0 : rt->fault_line));
    diag_put16(b, DIAG_FAULT_COL, (uint16_t)(rt->fault_col > 65535 ? 65535 : rt->fault_col < 0 ? 0 : rt->fault_col));
    uint16_t flags = rt->flags;
    if (rt->retain && retain_last_failed(rt->retain))
        flags |= DIAG_FLAG_RETAIN_ERROR;
    diag_put16(b, DIAG_FLAGS, flags);
    diag_put32(b, DIAG_BASE_TICK_US, us32(rt->period_ns));
    diag_put64(b, DIAG_SCAN_COUNT, s->scans);
    diag_put32(b, DIAG_SCAN_LAST_US, us32(s->scan.last_ns));
    diag_put32(b, DIAG_SCAN_MIN_US, us32(s->scan.min_ns));
    diag_put32(b, DIAG_SCAN_MAX_US, us32(s->scan.max_ns));
    diag_put32(b, DIAG_SCAN_MEAN_US, us32(s->scan.n ? s->scan.sum_ns / s->scan.n : 0));
    diag_put32(b, DIAG_SCAN_P99_US, us32(s->p99_scan_ns));
    diag_put32(b, DIAG_SCAN_P50_US, us32(s->p50_scan_ns));
    diag_put32(b, DIAG_WAKE_LAST_US, us32(s->wake.last_ns));
    diag_put32(b, DIAG_WAKE_MIN_US, us32(s->wake.min_ns));
    diag_put32(b, DIAG_WAKE_MAX_US, us32(s->wake.max_ns));
    diag_put32(b, DIAG_WAKE_MEAN_US, us32(s->wake.n ? s->wake.sum_ns / s->wake.n : 0));
    diag_put32(b, DIAG_WAKE_P99_US, us32(s->p99_wake_ns));
    diag_put32(b, DIAG_WAKE_P50_US, us32(s->p50_wake_ns));
    diag_put32(b, DIAG_OVERRUNS, s->overruns);
    diag_put32(b, DIAG_SKIPPED, s->skipped);
    diag_put32(b, DIAG_RETAIN_SAVES, rt->retain ? retain_saves(rt->retain) : 0);
    diag_put32(b, DIAG_UPTIME_S, (uint32_t)((now_ns() - started) / 1000000000u));
    int app_fault = events_fault(rt->events);
    diag_put16(b, DIAG_APP_FAULT, (uint16_t)(int16_t)(app_fault < -32768 ? -32768 : app_fault > 32767 ? 32767
                                                                                     : app_fault));
}

static void refresh_percentiles(scan_stats_t *s)
{
    s->p50_scan_ns = hist_percentile(&s->scan, 0.50);
    s->p99_scan_ns = hist_percentile(&s->scan, 0.99);
    s->p50_wake_ns = hist_percentile(&s->wake, 0.50);
    s->p99_wake_ns = hist_percentile(&s->wake, 0.99);
}

static void log_summary(runtime_t *rt)
{
    scan_stats_t *s = &rt->stats;

    refresh_percentiles(s);
    log_msg(rt->log, LOG_INFO,
            "stats scans=%" PRIu64 " overruns=%u skipped=%u period_us=%.1f"
            " scan_us_p50=%.1f scan_us_p99=%.1f scan_us_max=%.1f scan_us_mean=%.1f"
            " wake_us_p50=%.1f wake_us_p99=%.1f wake_us_max=%.1f wake_us_mean=%.1f"
            " core_us_p50=%.2f core_us_p99=%.2f run_us_p50=%.2f run_us_p99=%.2f",
            s->scans, s->overruns, s->skipped, rt->period_ns / 1e3,
            s->p50_scan_ns / 1e3, s->p99_scan_ns / 1e3, s->scan.max_ns / 1e3,
            s->scan.n ? (double)s->scan.sum_ns / (double)s->scan.n / 1e3 : 0.0,
            s->p50_wake_ns / 1e3, s->p99_wake_ns / 1e3, s->wake.max_ns / 1e3,
            s->wake.n ? (double)s->wake.sum_ns / (double)s->wake.n / 1e3 : 0.0,
            hist_percentile(&s->core, 0.50) / 1e3, hist_percentile(&s->core, 0.99) / 1e3,
            hist_percentile(&s->run, 0.50) / 1e3, hist_percentile(&s->run, 0.99) / 1e3);
}

/* ------------------------------------------------------------- the loop */

static void sleep_until(uint64_t t)
{
    struct timespec ts = { .tv_sec = (time_t)(t / 1000000000u), .tv_nsec = (long)(t % 1000000000u) };

    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR)
        ;
}

/* SIGINT/SIGTERM are blocked in every thread (main.c); poll for them here. */
static int stop_signal(const sigset_t *stop)
{
    struct timespec zero = { 0, 0 };
    int sig = sigtimedwait(stop, NULL, &zero);

    return sig > 0 ? sig : 0;
}

/* What the I/O layer gets for %QW while the program is stopped. */
static const uint16_t no_words[MAP_WORDS];

/* ------------------------------------------------- the core's connections */

/* Input latch, the world's side: the I/O layer's inputs, then the host writes
 * queued since the last scan, in that order. */
static int rt_read_inputs(void *ctx, plc_image_t *image)
{
    runtime_t *rt = ctx;
    bool host_wrote;

    pthread_mutex_lock(&rt->io_lock);
    rt->opt.io->read_inputs(rt->io_state, image->ix, image->iw);
    pthread_mutex_unlock(&rt->io_lock);
    pthread_mutex_lock(&rt->lock);
    host_wrote = rt->bimg.any_dirty;
    image_take_host_writes(rt);
    pthread_mutex_unlock(&rt->lock);
    return host_wrote;
}

/* Tasks due: run() under the watchdog's eye, timed for the statistics. */
static int rt_run_tasks(void *ctx, uint64_t tick)
{
    runtime_t *rt = ctx;
    const uint64_t t0 = now_ns();

    atomic_store(&rt->run_started_ns, t0);
    int rc = rt->prog->run(tick);
    atomic_store(&rt->run_started_ns, 0);
    hist_add(&rt->stats.run, now_ns() - t0);
    if (atomic_load(&rt->watchdog_tripped))
        rc = RT_FAULT_WATCHDOG;
    if (rc != 0)
        enter_fault(rt, rc, tick);
    return rc;
}

/* Output publication, the world's side: the Modbus image (with the
 * diagnostic block of this scan), then the I/O layer. */
static void rt_write_outputs(void *ctx, plc_image_t *image, int running)
{
    runtime_t *rt = ctx;
    scan_stats_t *s = &rt->stats;

    s->scans++;
    if (s->scans % rt->refresh_every == 0)
        refresh_percentiles(s);
    pthread_mutex_lock(&rt->lock);
    image_publish(rt);
    publish_diag(rt, rt->started_ns);
    pthread_mutex_unlock(&rt->lock);
    publish_live(rt);

    pthread_mutex_lock(&rt->io_lock);
    rt->opt.io->write_outputs(rt->io_state, image->qx, running ? image->qw : no_words);
    pthread_mutex_unlock(&rt->io_lock);
}

/* The monitor's three points of the scan (each does nothing without a monitor). */
static void hook_after_inputs(void *ctx)
{
    runtime_t *rt = ctx;

    monitor_after_inputs(rt);
    const plc_bool_t forced = rt->force && force_count(rt->force) > 0;
    /* ForcesActive last, so not even a force of it can hide the others */
    rt->pimg.ix[FORCES_ACTIVE_BIT] = forced;
    if (rt->forces_flag)
        *rt->forces_flag = forced;
    if (forced)                                     /* forced inputs in the image too: hosts see them */
        plc_scan_reflect_inputs(&rt->core);
}

/* The program's variable at FORCES_ACTIVE_BIT (a bound input), or NULL. */
static plc_bool_t *forces_flag_var(const plc_scan_t *core, const prog_image_t *image)
{
    for (uint32_t i = 0; i < core->n_inputs; i++)
        if (core->bindings[i].slot == &image->ix[FORCES_ACTIVE_BIT])
            return core->bindings[i].var;
    return NULL;
}
static void hook_before_outputs(void *ctx) { monitor_before_outputs(ctx); }
static void hook_scan_done(void *ctx, uint64_t scan_no) { (void)scan_no; monitor_scan_done(ctx); }

int scan_run(runtime_t *rt)
{
    const plc_program_t *prog = rt->prog;
    const uint64_t period = rt->period_ns;
    const uint64_t started = now_ns();
    uint64_t deadline = started;          /* the first scan runs at once */
    sigset_t stop;
    int sig = 0;

    sigemptyset(&stop);
    sigaddset(&stop, SIGINT);
    sigaddset(&stop, SIGTERM);

    rt->started_ns = started;
    rt->refresh_every = period >= 100000000u ? 1 : 100000000u / period;
    rt->core.io = (plc_scan_io_t){ .ctx = rt, .read_inputs = rt_read_inputs, .write_outputs = rt_write_outputs };
    rt->core.run = rt_run_tasks;
    rt->core.run_ctx = rt;
    /* Forcing and monitoring (monitor.c): forced inputs after the latch, forced outputs before
     * publication, the snapshot and the application's events once the scan is published. */
    rt->core.hooks = (plc_scan_hooks_t){ .ctx = rt, .after_inputs = hook_after_inputs,
                                         .before_outputs = hook_before_outputs, .scan_done = hook_scan_done };

    rt->forces_flag = forces_flag_var(&rt->core, &rt->pimg);

    atomic_store(&rt->state, PLC_STATE_RUNNING);
    pthread_mutex_lock(&rt->lock);
    publish_diag(rt, started);
    pthread_mutex_unlock(&rt->lock);
    publish_live(rt);
    log_msg(rt->log, LOG_INFO, "running %s: scan period %.3f ms", prog->config_name ? prog->config_name : "program",
            period / 1e6);

    for (;;) {
        sleep_until(deadline);
        const uint64_t woke = now_ns();
        scan_stats_t *s = &rt->stats;

        sig = stop_signal(&stop);
        if (sig)
            break;
        if (rt->opt.duration_s > 0 && (double)(woke - started) >= rt->opt.duration_s * 1e9)
            break;

        hist_add(&s->wake, woke - deadline);

        /* The scan proper starts here, after the loop's own housekeeping (signals, run time). */
        const uint64_t begun = now_ns();
        /* The program's clock is virtual: tick t runs at t base ticks. */
        plc_scan_step(&rt->core, (int64_t)(rt->core.tick * prog->base_tick_ns));
        const uint64_t scanned = now_ns();
        hist_add(&s->core, scanned - begun);
        if (atomic_load_explicit(&rt->scan_lowered, memory_order_relaxed))
            scan_raise_again(rt);       /* run() returned after the watchdog had lowered this thread */

        if (atomic_load(&rt->state) == PLC_STATE_RUNNING)
            retain_after_scan(rt, woke);

        const uint64_t done = now_ns();
        if (s->scans == 1)      /* upgrades measure the switch-over up to this line (monotonic clock) */
            log_msg(rt->log, LOG_INFO, "first scan done at monotonic %.6f s", done / 1e9);
        notify_after_scan(rt->notify, rt, done);
        hist_add(&s->scan, done - begun);
        deadline += period;
        if (done > deadline) {
            s->overruns++;
            uint64_t missed = (done - deadline) / period;
            if (missed > 0) {
                s->skipped += (uint32_t)missed;
                deadline += missed * period;
            }
        }
    }

    if (sig)
        log_msg(rt->log, LOG_INFO, "%s received: stopping", sig == SIGINT ? "SIGINT" : "SIGTERM");
    else
        log_msg(rt->log, LOG_INFO, "run time of %.1f s reached: stopping", rt->opt.duration_s);

    /* Program stopped, outputs safe, in the image and at the I/O.  Host writes
     * acknowledged since the last scan still reach memory and retained data
     * (unless the program had faulted: then the last good scan's values stay). */
    notify_send(rt->notify, "STOPPING=1\nSTATUS=stopping: outputs going safe, saving retained data");
    const bool was_running = atomic_load(&rt->state) == PLC_STATE_RUNNING;
    atomic_store(&rt->state, PLC_STATE_STOPPING);
    pthread_mutex_lock(&rt->lock);
    image_take_host_writes(rt);
    image_make_outputs_safe(&rt->pimg);
    image_publish(rt);
    publish_diag(rt, started);
    pthread_mutex_unlock(&rt->lock);
    publish_live(rt);
    pthread_mutex_lock(&rt->io_lock);
    rt->opt.io->write_outputs(rt->io_state, rt->pimg.qx, no_words);
    pthread_mutex_unlock(&rt->io_lock);
    log_msg(rt->log, LOG_INFO, "outputs safe (all coils cleared, I/O outputs at zero) at monotonic %.6f s",
            now_ns() / 1e9);
    if (was_running)
        retain_capture(rt);
    log_summary(rt);
    return 0;
}
