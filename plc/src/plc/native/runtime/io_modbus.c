/*
 * io_modbus.c - remote I/O modules over Modbus TCP and Modbus RTU (--io modbus).
 *
 * The runtime is the Modbus master of any number of devices (I/O couplers,
 * RS-485 boards).  Each TCP device, and each serial line (its units polled in
 * turn), has its own libmodbus context and its own poll thread; the scan never
 * talks to the network:
 *
 *   poll thread, every poll period:  read every input range, then write the
 *     outputs last handed over.  Inputs read completely become the device's
 *     snapshot, stamped with the time they were asked for -- provided the last
 *     output write succeeded too (a device that takes no outputs is not
 *     healthy).  Outputs handed over between two cycles are written at once.
 *   read_inputs (scan start):  copy each device's last complete snapshot into
 *     %IX/%IW.  A snapshot older than the device's max age (or none yet) means
 *     the device is lost: its inputs read 0/FALSE, its status input is TRUE.
 *   write_outputs (scan end):  hand %QX/%QW of each device's output ranges to
 *     its poll thread; a lost device, or a stopped program, gets the device's
 *     safe values instead.
 *   loss watch (one thread):  wakes when a device's snapshot passes its max
 *     age and declares it lost then -- safe values handed over, state and log
 *     line -- instead of at the next scan start, up to one task period later.
 *
 * A serial line shared by several units (RS-485 multi-drop) is one poll
 * thread, one transaction at a time, so a unit that does not answer holds the
 * line for a response time-out and the drain after it (2 time-outs) per try.
 * Its neighbours must still get their outputs, the program's reaction to the
 * loss above all, within the max age:
 *   - outputs handed over are written between any two transactions, to the
 *     units that answer (never to a silent one: its safe values go out when it
 *     answers again, before its inputs count as fresh);
 *   - a unit that did not answer is tried with one read per cycle, no write;
 *     once lost, it is probed only after its back-off (first wait doubling up
 *     to the maximum), never right after the loss: the outputs of the
 *     program's reaction go out first, and the others keep their poll rate;
 *   - a unit of a shared line is declared lost once its inputs are older than
 *     max age - line margin, the margin being what can still pass before the
 *     neighbours have the reaction: a failed transaction in flight (2
 *     time-outs), then the reacting scan and their write (1 time-out: a
 *     task period and a frame time).  So comm loss -> the program's next
 *     outputs at every answering unit of the line <= max age.
 *     `plc run` refuses a max age below the line's worst case (io_config.py).
 *
 * Both sides hold the device mutex (priority-inheriting) only to copy a few
 * words; the scan wakes a poll thread with rt_wake(), never a condition
 * variable (realtime.c).  The poll threads and the loss watch run SCHED_FIFO 5
 * levels below the scan when real-time scheduling is on.  A connection
 * that fails is reopened with a back-off (first period doubling up to the
 * maximum); a log line is written per state change, never per retry.
 *
 * One device per --io-device option, tokens separated by spaces (`plc run`
 * writes them from the checked run configuration):
 *
 *   name=NAME  tcp=HOST:PORT | rtu=PATH baud=N parity=N|E|O data=7|8 stop=1|2
 *   unit=N  poll=MS  timeout=MS  age=MS  backoff=MIN-MAX  status=BIT
 *   di=ADDR:COUNT:BIT   discrete inputs (FC2)           -> %IX from bit BIT
 *   co=ADDR:COUNT:BIT[:SAFE,...]  coils written (FC15)  <- %QX from bit BIT
 *   ir=ADDR:COUNT:WORD  input registers (FC4)           -> %IW from WORD
 *   hr=ADDR:COUNT:WORD  holding registers read (FC3)    -> %IW from WORD
 *   hw=ADDR:COUNT:WORD[:SAFE,...]  holding written (FC16) <- %QW from WORD
 *
 * BIT is the index of %IXa.b (8a+b), SAFE one value or one per address (0 if
 * absent).  Diagnostics per device: input registers IO_DIAG_BASE.. (runtime.h).
 *
 * Who checks what: `plc run` (io_config.py) validates the devices completely,
 * with positions in the run configuration: overlaps in the image and on a
 * device, a status input inside a di range, the settings and units of a shared
 * serial line, the line's worst case against max age, one of tcp/rtu, at least
 * one range.  This file does not check those again; it reads the text and
 * checks only what a C program must check anyway -- a token it can read
 * (KEY=VALUE, numbers), lengths against its buffers, a range's count within
 * libmodbus' limit of one request, a range inside the device's addresses and
 * the image, at most MAX_RANGES ranges -- and what only the target machine can
 * tell (the serial device opens, the host answers).  Devices on one serial
 * path share the first one's context and line settings.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <inttypes.h>
#include <modbus.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "runtime.h"

#define MAX_RANGES 32
#define IO_BELOW_SCAN (-5)   /* the poll threads' and the loss watch's SCHED_FIFO priority: the scan's - 5 */
#define STARTUP_WAIT_MAX_MS 3000u

typedef enum range_kind { RANGE_DI, RANGE_CO, RANGE_IR, RANGE_HR, RANGE_HW } range_kind_t;

static const struct range_rule {
    const char *key;
    bool output;
    bool bits;
    unsigned max_count;      /* libmodbus' limit for one request */
} rules[] = {
    [RANGE_DI] = { "di", false, true, MODBUS_MAX_READ_BITS },
    [RANGE_CO] = { "co", true, true, MODBUS_MAX_WRITE_BITS },
    [RANGE_IR] = { "ir", false, false, MODBUS_MAX_READ_REGISTERS },
    [RANGE_HR] = { "hr", false, false, MODBUS_MAX_READ_REGISTERS },
    [RANGE_HW] = { "hw", true, false, MODBUS_MAX_WRITE_REGISTERS },
};

typedef struct io_range {
    range_kind_t kind;
    unsigned addr;           /* first device address */
    unsigned count;
    unsigned image;          /* first %IX/%QX bit or %IW/%QW word */
    unsigned at;             /* first value in the device's input or output buffer */
} io_range_t;

typedef struct io_device {
    runtime_t *rt;
    unsigned index;          /* 0-based; the program and the log say index + 1 */
    char name[32];
    char where[160];         /* "tcp 127.0.0.1:1502 unit 1" for log lines */
    bool rtu;
    char host[64];
    int port;
    char path[128];
    int baud, data_bits, stop_bits;
    char parity;
    int unit;
    unsigned poll_ms, timeout_ms, age_ms, backoff_min_ms, backoff_max_ms;
    bool age_given;          /* age= was given (else 2 polls + time-out, or the shared line's worst case) */
    unsigned loss_ms;        /* inputs older than this: lost (age_ms, less the line margin on a shared line) */
    int status_bit;          /* -1: none */
    io_range_t ranges[MAX_RANGES];
    unsigned n_ranges, n_in, n_out;
    uint16_t *safe;          /* n_out safe values */

    modbus_t *ctx;           /* the line's: devices on one serial line share their leader's */
    struct io_device *leader;    /* first device of this line (itself for TCP and a line's first) */
    struct io_device *next_member;   /* next device on the leader's line */
    unsigned line_poll_ms;   /* leader: the shortest poll period of its line */
    unsigned n_members;      /* leader: devices on its line (1: a TCP device or a serial line of its own) */
    _Atomic uint32_t line_seq;   /* leader: bumped when any device of the line gets new outputs */
    pthread_t thread;        /* leader only: polls every device of its line in turn */
    bool thread_started;

    pthread_mutex_t m;       /* guards the fields up to `stop` */
    rt_wake_t wake;          /* leader: new outputs handed over, or stop (the scan gives it without a lock) */
    uint16_t *in_snap;       /* last complete input cycle */
    uint64_t snap_ns;        /* when it began; 0: none yet */
    uint16_t *out_next;      /* outputs handed over by the scan */
    uint32_t out_seq;
    bool stop;

    /* poll thread only (connection fields: the leader's count) */
    uint32_t sent_seq;       /* out_seq last written */
    bool connected;
    bool link_up;            /* a complete cycle since the last connect; "link up" logged */
    bool announced;          /* a link state has been logged */
    bool outputs_ok;         /* the last output write succeeded (inputs count as fresh only then) */
    bool answering;          /* shared line: its last transaction was answered (else: not written to) */
    bool lost_seen;          /* shared line: the poll thread has seen it lost (probing with back-off) */
    uint64_t probe_at, probe_wait;   /* shared line, lost and silent: next probe, the back-off after it */
    uint16_t *in_work, *out_work;
    uint8_t bits[MODBUS_MAX_READ_BITS];
    uint32_t good;
    uint32_t timeouts, garbage, exceptions, reconnects;
    io_error_t last_error;
    uint64_t last_good_ns;

    /* scan side (scan thread; the watchdog reads `state`) */
    uint16_t *in_scan, *out_scan;
    _Atomic int state;       /* io_device_state_t */
} io_device_t;

typedef struct io_modbus {
    runtime_t *rt;
    unsigned n;
    io_device_t dev[IO_MAX_DEVICES];

    /* the loss watch: declares a device lost the moment its inputs pass the age limit, on its own clock
     * (the scan would notice only at its next start, up to one task period later) */
    pthread_t watch;
    bool watch_started;
    pthread_mutex_t wm;      /* guards wstop */
    pthread_cond_t wcv;
    bool wstop;
} io_modbus_t;

/* ------------------------------------------------------------- parsing */

static bool parse_uint(const char *s, unsigned long lo, unsigned long hi, unsigned *out, const char **end)
{
    char *e;
    errno = 0;
    unsigned long v = strtoul(s, &e, 10);
    if (errno || e == s || v < lo || v > hi || *s == '-' || *s == '+')
        return false;
    *out = (unsigned)v;
    if (end)
        *end = e;
    else if (*e)
        return false;
    return true;
}

static int bad(char *err, size_t errlen, const char *token, const char *why)
{
    snprintf(err, errlen, "--io-device: '%s': %s", token, why);
    return -1;
}

/* A range's text: ADDR:COUNT:IMAGE[:SAFE,...], bounded by libmodbus' limit of one request, the device's
 * addresses and the image (what the buffers below are sized by). */
static int parse_range(io_device_t *d, range_kind_t kind, const char *token, const char *v,
                       uint16_t *safe_tmp, char *err, size_t errlen)
{
    const struct range_rule *r = &rules[kind];
    const unsigned image_limit = r->bits ? MAP_BITS : MAP_WORDS;
    io_range_t *g;
    const char *p;
    unsigned addr, count, image, n = 0, value;

    if (d->n_ranges >= MAX_RANGES)
        return bad(err, errlen, token, "too many ranges (at most 32 per device)");
    if (!parse_uint(v, 0, 65535, &addr, &p) || *p != ':' || !parse_uint(p + 1, 1, r->max_count, &count, &p)
            || *p != ':' || !parse_uint(p + 1, 0, image_limit - 1, &image, &p) || (*p && !r->output)
            || addr + count > 65536u || image + count > image_limit)
        return bad(err, errlen, token, "not ADDR:COUNT:IMAGE[:SAFE,...] (SAFE on co and hw only) inside libmodbus' "
                   "limit of one request, the device's addresses and the image");
    while (*p == ':' || *p == ',') {
        if (n >= count || !parse_uint(p + 1, 0, r->bits ? 1 : 65535, &value, &p))
            return bad(err, errlen, token, "safe values: one value, or one per address (0/1 for coils)");
        safe_tmp[d->n_out + n++] = (uint16_t)value;
    }
    if (*p || (n > 1 && n != count))
        return bad(err, errlen, token, "safe values: one value, or one per address (0/1 for coils)");
    g = &d->ranges[d->n_ranges++];
    g->kind = kind;
    g->addr = addr;
    g->count = count;
    g->image = image;
    g->at = r->output ? d->n_out : d->n_in;
    if (r->output) {
        for (unsigned i = n; i < count; i++)
            safe_tmp[d->n_out + i] = n == 1 ? safe_tmp[d->n_out] : 0;
        d->n_out += count;
    } else {
        d->n_in += count;
    }
    return 0;
}

static int parse_device(io_device_t *d, const char *spec, char *err, size_t errlen)
{
    static uint16_t safe_tmp[MAX_RANGES * MODBUS_MAX_WRITE_BITS];
    char buf[2048];
    char *save = NULL;

    if (strlen(spec) >= sizeof buf)
        return bad(err, errlen, "...", "device description too long");
    snprintf(buf, sizeof buf, "%s", spec);
    snprintf(d->name, sizeof d->name, "device%u", d->index + 1);
    d->unit = 1;
    d->poll_ms = 10;
    d->timeout_ms = 50;
    d->age_ms = 0;
    d->backoff_min_ms = 100;
    d->backoff_max_ms = 2000;
    d->status_bit = -1;
    d->baud = 19200;
    d->parity = 'N';
    d->data_bits = 8;
    d->stop_bits = 1;
    d->port = -1;

    for (char *tok = strtok_r(buf, " ", &save); tok; tok = strtok_r(NULL, " ", &save)) {
        char *eq = strchr(tok, '=');
        unsigned u;
        if (!eq)
            return bad(err, errlen, tok, "expected KEY=VALUE");
        *eq = 0;
        const char *k = tok, *v = eq + 1;
        bool done = false;
        for (range_kind_t kind = RANGE_DI; kind <= RANGE_HW; kind++)
            if (strcmp(k, rules[kind].key) == 0) {
                *eq = '=';
                if (parse_range(d, kind, tok, v, safe_tmp, err, errlen) != 0)
                    return -1;
                done = true;
            }
        if (done)
            continue;
        if (strcmp(k, "name") == 0) {
            snprintf(d->name, sizeof d->name, "%s", v);
        } else if (strcmp(k, "tcp") == 0) {
            const char *colon = strrchr(v, ':');
            if (!colon || colon == v || (size_t)(colon - v) >= sizeof d->host
                    || !parse_uint(colon + 1, 1, 65535, &u, NULL))
                return bad(err, errlen, v, "expected tcp=HOST:PORT");
            memcpy(d->host, v, (size_t)(colon - v));
            d->host[colon - v] = 0;
            d->port = (int)u;
        } else if (strcmp(k, "rtu") == 0) {
            if (!*v || strlen(v) >= sizeof d->path)
                return bad(err, errlen, v, "expected rtu=SERIAL_DEVICE");
            snprintf(d->path, sizeof d->path, "%s", v);
            d->rtu = true;
        } else if (strcmp(k, "baud") == 0 && parse_uint(v, 50, 4000000, &u, NULL)) {
            d->baud = (int)u;
        } else if (strcmp(k, "parity") == 0 && strlen(v) == 1 && strchr("NEO", v[0])) {
            d->parity = v[0];
        } else if (strcmp(k, "data") == 0 && parse_uint(v, 5, 8, &u, NULL)) {
            d->data_bits = (int)u;
        } else if (strcmp(k, "stop") == 0 && parse_uint(v, 1, 2, &u, NULL)) {
            d->stop_bits = (int)u;
        } else if (strcmp(k, "unit") == 0 && parse_uint(v, 0, 255, &u, NULL)) {
            d->unit = (int)u;
        } else if (strcmp(k, "poll") == 0 && parse_uint(v, 1, 60000, &u, NULL)) {
            d->poll_ms = u;
        } else if (strcmp(k, "timeout") == 0 && parse_uint(v, 1, 60000, &u, NULL)) {
            d->timeout_ms = u;
        } else if (strcmp(k, "age") == 0 && parse_uint(v, 1, 600000, &u, NULL)) {
            d->age_ms = u;
            d->age_given = true;
        } else if (strcmp(k, "status") == 0 && parse_uint(v, 0, MAP_BITS - 1, &u, NULL)) {
            d->status_bit = (int)u;
        } else if (strcmp(k, "backoff") == 0) {
            const char *p;
            if (!parse_uint(v, 1, 600000, &d->backoff_min_ms, &p) || *p != '-'
                    || !parse_uint(p + 1, d->backoff_min_ms, 600000, &d->backoff_max_ms, NULL))
                return bad(err, errlen, v, "expected backoff=MIN-MAX (ms, MIN <= MAX)");
        } else {
            *eq = '=';
            return bad(err, errlen, tok, "unknown key or value out of range");
        }
    }
    if (d->rtu == (d->port > 0))
        return bad(err, errlen, spec, "give exactly one of tcp=HOST:PORT and rtu=PATH");
    if (d->age_ms == 0)
        d->age_ms = 2 * d->poll_ms + d->timeout_ms;
    if (d->rtu)
        snprintf(d->where, sizeof d->where, "rtu %s %d %d%c%d unit %d", d->path, d->baud, d->data_bits,
                 d->parity, d->stop_bits, d->unit);
    else
        snprintf(d->where, sizeof d->where, "tcp %s:%d unit %d", d->host, d->port, d->unit);

    d->safe = calloc(d->n_out + 1, sizeof *d->safe);
    d->out_next = calloc(d->n_out + 1, sizeof *d->out_next);
    d->out_work = calloc(d->n_out + 1, sizeof *d->out_work);
    d->out_scan = calloc(d->n_out + 1, sizeof *d->out_scan);
    d->in_snap = calloc(d->n_in + 1, sizeof *d->in_snap);
    d->in_work = calloc(d->n_in + 1, sizeof *d->in_work);
    d->in_scan = calloc(d->n_in + 1, sizeof *d->in_scan);
    if (!d->safe || !d->out_next || !d->out_work || !d->out_scan || !d->in_snap || !d->in_work || !d->in_scan)
        return bad(err, errlen, d->name, "out of memory");
    memcpy(d->safe, safe_tmp, d->n_out * sizeof *d->safe);
    memcpy(d->out_next, d->safe, d->n_out * sizeof *d->safe);
    return 0;
}

/* ------------------------------------------------------------ poll side */

static void publish_diag(io_device_t *d)
{
    uint16_t *w = &d->rt->bimg.input_regs[IO_DIAG_BASE + d->index * IO_DIAG_WORDS];
    const uint32_t sat = 65535u;

    pthread_mutex_lock(&d->rt->lock);
    w[IO_DIAG_STATE] = (uint16_t)atomic_load(&d->state);
    w[IO_DIAG_LAST_ERROR] = (uint16_t)d->last_error;
    w[IO_DIAG_GOOD] = (uint16_t)(d->good >> 16);
    w[IO_DIAG_GOOD + 1] = (uint16_t)d->good;
    w[IO_DIAG_TIMEOUTS] = (uint16_t)(d->timeouts > sat ? sat : d->timeouts);
    w[IO_DIAG_GARBAGE] = (uint16_t)(d->garbage > sat ? sat : d->garbage);
    w[IO_DIAG_EXCEPTIONS] = (uint16_t)(d->exceptions > sat ? sat : d->exceptions);
    w[IO_DIAG_RECONNECTS] = (uint16_t)(d->reconnects > sat ? sat : d->reconnects);
    pthread_mutex_unlock(&d->rt->lock);
}

static int write_outputs_now(io_device_t *d, const uint16_t *out)
{
    for (unsigned i = 0; i < d->n_ranges; i++) {
        const io_range_t *r = &d->ranges[i];
        int rc;
        if (r->kind == RANGE_CO) {
            for (unsigned k = 0; k < r->count; k++)
                d->bits[k] = out[r->at + k] ? 1 : 0;
            rc = modbus_write_bits(d->ctx, (int)r->addr, (int)r->count, d->bits);
        } else if (r->kind == RANGE_HW) {
            rc = modbus_write_registers(d->ctx, (int)r->addr, (int)r->count, &out[r->at]);
        } else {
            continue;
        }
        if (rc != (int)r->count)
            return -1;
    }
    return 0;
}

static int read_inputs_now(io_device_t *d, uint16_t *in)
{
    for (unsigned i = 0; i < d->n_ranges; i++) {
        const io_range_t *r = &d->ranges[i];
        int rc;
        switch (r->kind) {
        case RANGE_DI:
            rc = modbus_read_input_bits(d->ctx, (int)r->addr, (int)r->count, d->bits);
            for (unsigned k = 0; rc == (int)r->count && k < r->count; k++)
                in[r->at + k] = d->bits[k];
            break;
        case RANGE_IR:
            rc = modbus_read_input_registers(d->ctx, (int)r->addr, (int)r->count, &in[r->at]);
            break;
        case RANGE_HR:
            rc = modbus_read_registers(d->ctx, (int)r->addr, (int)r->count, &in[r->at]);
            break;
        default:
            continue;
        }
        if (rc != (int)r->count)
            return -1;
    }
    return 0;
}

/* Wait until `until` (monotonic ns) or a stop; TRUE when stopping. */
static bool wait_or_stop(io_device_t *d, uint64_t until)
{
    for (;;) {
        pthread_mutex_lock(&d->m);
        bool stop = d->stop;
        pthread_mutex_unlock(&d->m);
        if (stop || now_ns() >= until)
            return stop;
        rt_wake_wait(&d->wake, until);
    }
}

/* The link goes down: logged once, when it was up (or never announced). */
static void link_down(io_device_t *d, const char *why)
{
    if (d->link_up || !d->announced)
        log_msg(d->rt->log, LOG_WARN, "I/O device %u (%s): link down: %s; reconnecting with back-off %u..%u ms",
                d->index + 1, d->name, why, d->backoff_min_ms, d->backoff_max_ms);
    d->link_up = false;
    d->announced = true;
}

static void disconnect(io_device_t *d, const char *why)
{
    modbus_close(d->ctx);
    d->leader->connected = false;
    link_down(d->leader, why);
}

/* A failed transaction: count it by kind; a broken connection, or answers
 * missing for longer than the input age limit (TCP), closes the connection. */
static void transaction_failed(io_device_t *d, int e, uint64_t now)
{
    char why[160];

    if (e > MODBUS_ENOBASE && e <= EMBXGTAR) {
        d->exceptions++;
        d->last_error = IO_ERROR_EXCEPTION;
    } else if (e == ETIMEDOUT) {
        d->timeouts++;
        d->last_error = IO_ERROR_TIMEOUT;
    } else if (e >= EMBBADCRC && e <= EMBBADSLAVE) {
        d->garbage++;
        d->last_error = IO_ERROR_GARBAGE;
    } else {
        d->last_error = IO_ERROR_CONNECTION;
        snprintf(why, sizeof why, "connection lost (%s)", modbus_strerror(e));
        disconnect(d, why);
        return;
    }
    /* A late or partial answer must not be taken for the next request's: let it
     * arrive (one response time-out), then drop it. */
    if (d->last_error != IO_ERROR_EXCEPTION)
        wait_or_stop(d, now + (uint64_t)d->timeout_ms * 1000000u);
    modbus_flush(d->ctx);
    if (!d->rtu && now - d->last_good_ns > (uint64_t)d->age_ms * 1000000u) {
        snprintf(why, sizeof why, "no valid answer for %.0f ms (last: %s)", (now - d->last_good_ns) / 1e6,
                 modbus_strerror(e));
        disconnect(d, why);
    }
}

static bool on_shared_line(const io_device_t *d)
{
    return d->leader->n_members > 1;
}

/* Shared line: a lost unit that does not answer is probed only when its back-off has passed; the first time the
 * poll thread sees it lost, the probe is put off by one back-off, so the outputs of the program's reaction to
 * the loss reach its neighbours before the line is held by it again. */
static bool probe_due(io_device_t *m, uint64_t now)
{
    if (!on_shared_line(m) || m->answering || atomic_load(&m->state) != IO_DEVICE_LOST)
        return true;
    if (!m->lost_seen) {
        m->lost_seen = true;
        m->probe_wait = (uint64_t)m->backoff_min_ms * 1000000u;
        m->probe_at = now + m->probe_wait;
    }
    return now >= m->probe_at;
}

/* Shared line: a unit that did not answer gets no more transactions this cycle, a lost one its next probe time;
 * its outputs count as not delivered, so when it answers again its inputs become fresh only after the outputs
 * last handed over (safe ones, when it was lost) have been written. */
static void not_answering(io_device_t *m)
{
    const uint64_t max = (uint64_t)m->backoff_max_ms * 1000000u;

    m->answering = false;
    m->outputs_ok = false;
    if (m->lost_seen) {
        m->probe_at = now_ns() + m->probe_wait;
        m->probe_wait = m->probe_wait * 2 > max ? max : m->probe_wait * 2;
    }
}

/* One device's cycle on its line: inputs first (stamped when asked for), then its outputs. */
static void poll_device(io_device_t *L, io_device_t *m, uint64_t *backoff)
{
    runtime_t *rt = m->rt;
    const uint64_t start = now_ns();

    if (!probe_due(m, start))
        return;
    modbus_set_slave(m->ctx, m->unit);
    if (read_inputs_now(m, m->in_work) == 0) {
        pthread_mutex_lock(&m->m);
        memcpy(m->in_snap, m->in_work, m->n_in * sizeof *m->in_snap);
        if (m->outputs_ok)            /* fresh only while the outputs reach the device too */
            m->snap_ns = start;
        pthread_mutex_unlock(&m->m);
        m->good++;
        m->last_good_ns = start;
        *backoff = (uint64_t)L->backoff_min_ms * 1000000u;
        if (!L->link_up)
            log_msg(rt->log, LOG_INFO, "I/O device %u (%s): link up (%s)", L->index + 1, L->name, L->where);
        L->link_up = true;
        L->announced = true;
        m->answering = true;
        m->lost_seen = false;
    } else {
        transaction_failed(m, errno, now_ns());
        if (on_shared_line(m)) {     /* a write would hold the line for its time-out once more */
            not_answering(m);
            return;
        }
    }
    if (!L->connected)
        return;
    /* Then the outputs last handed over (written again every cycle: levels, like mb2hal). */
    pthread_mutex_lock(&m->m);
    memcpy(m->out_work, m->out_next, m->n_out * sizeof *m->out_work);
    m->sent_seq = m->out_seq;
    pthread_mutex_unlock(&m->m);
    m->outputs_ok = write_outputs_now(m, m->out_work) == 0;
    if (!m->outputs_ok) {
        transaction_failed(m, errno, now_ns());
        if (on_shared_line(m))
            not_answering(m);
    }
}

/* Outputs handed over since they were last written go out now, device by device (on a shared line to the units
 * that answer: a silent one gets its outputs with its next answered read). */
static void write_changed(io_device_t *L)
{
    for (io_device_t *m = L; m && L->connected; m = m->next_member) {
        if (on_shared_line(m) && !m->answering)
            continue;
        pthread_mutex_lock(&m->m);
        const bool changed = m->out_seq != m->sent_seq;
        if (changed) {
            memcpy(m->out_work, m->out_next, m->n_out * sizeof *m->out_work);
            m->sent_seq = m->out_seq;
        }
        pthread_mutex_unlock(&m->m);
        if (!changed)
            continue;
        modbus_set_slave(m->ctx, m->unit);
        m->outputs_ok = write_outputs_now(m, m->out_work) == 0;
        if (!m->outputs_ok) {
            transaction_failed(m, errno, now_ns());
            if (on_shared_line(m))
                not_answering(m);
            publish_diag(m);
        }
    }
}

/* The poll thread of a line (a TCP device, or the devices of one serial line in turn). */
static void *poll_thread(void *arg)
{
    io_device_t *L = arg;
    runtime_t *rt = L->rt;
    const uint64_t period = (uint64_t)L->line_poll_ms * 1000000u;
    uint64_t backoff = (uint64_t)L->backoff_min_ms * 1000000u;
    uint64_t next = now_ns();
    uint32_t seen = 0;

    rt_thread_name("io-poll");
    /* Below the scan, above the Modbus server: inputs are what the scan waits for. */
    (void)rt_thread_fifo(rt, IO_BELOW_SCAN);
    for (;;) {
        if (!L->connected) {
            /* After a failure, wait the back-off first (doubling until a good cycle). */
            if (L->announced || L->reconnects > 0) {
                if (wait_or_stop(L, now_ns() + backoff))
                    break;
                backoff = backoff * 2 > (uint64_t)L->backoff_max_ms * 1000000u
                          ? (uint64_t)L->backoff_max_ms * 1000000u : backoff * 2;
            }
            if (modbus_connect(L->ctx) != 0) {
                char why[sizeof L->where + 96];
                snprintf(why, sizeof why, "cannot connect (%s: %s)", L->where, modbus_strerror(errno));
                for (io_device_t *m = L; m; m = m->next_member) {
                    m->last_error = IO_ERROR_CONNECTION;
                    publish_diag(m);
                }
                link_down(L, why);
                continue;
            }
            L->connected = true;
            L->reconnects++;
            for (io_device_t *m = L; m; m = m->next_member) {
                m->outputs_ok = false;
                m->answering = true;
                m->lost_seen = false;
                m->last_good_ns = now_ns();
            }
            next = now_ns();
        }

        seen = atomic_load(&L->line_seq);
        for (io_device_t *m = L; m && L->connected; m = m->next_member) {
            if (atomic_load(&L->line_seq) != seen) {    /* handed over during the last transaction: out first */
                seen = atomic_load(&L->line_seq);
                write_changed(L);
            }
            poll_device(L, m, &backoff);
        }
        for (io_device_t *m = L; m; m = m->next_member)
            publish_diag(m);

        next += period;
        const uint64_t now = now_ns();
        if (next < now)
            next = now;       /* a late cycle: poll again at once, do not catch up */

        /* Until the next cycle: outputs handed over meanwhile go out at once. */
        bool stop = false;
        for (;;) {
            pthread_mutex_lock(&L->m);
            stop = L->stop;
            pthread_mutex_unlock(&L->m);
            if (stop || !L->connected)
                break;
            if (atomic_load(&L->line_seq) != seen) {
                seen = atomic_load(&L->line_seq);
                write_changed(L);
                continue;
            }
            if (now_ns() >= next)
                break;
            rt_wake_wait(&L->wake, next);
        }
        if (stop)
            break;
    }
    return NULL;
}

/* ------------------------------------------------------------ scan side */

static void set_state(io_device_t *d, io_device_state_t s, uint64_t now, uint64_t age)
{
    io_device_state_t old = (io_device_state_t)atomic_load(&d->state);

    if (old == s)
        return;
    atomic_store(&d->state, (int)s);
    /* The host sees the new state at once (the poll thread may be waiting out a back-off). */
    pthread_mutex_lock(&d->rt->lock);
    d->rt->bimg.input_regs[IO_DIAG_BASE + d->index * IO_DIAG_WORDS + IO_DIAG_STATE] = (uint16_t)s;
    pthread_mutex_unlock(&d->rt->lock);
    if (s == IO_DEVICE_LOST)
        log_msg(d->rt->log, LOG_ERROR, "I/O device %u (%s): lost: no complete input for %.1f ms (limit %u ms); "
                "status input TRUE, inputs 0, outputs safe at monotonic %.6f s",
                d->index + 1, d->name, age / 1e6, d->loss_ms, now / 1e9);
    else if (s == IO_DEVICE_OK)
        log_msg(d->rt->log, LOG_INFO, "I/O device %u (%s): inputs fresh%s at monotonic %.6f s", d->index + 1,
                d->name, old == IO_DEVICE_LOST ? " again (the program decides when its outputs return)" : "",
                now / 1e9);
}

/* Hands `out` (n_out values) to the device's line: its poll thread writes them at once if they changed. */
static void hand_over(io_device_t *d, const uint16_t *out)
{
    pthread_mutex_lock(&d->m);
    const bool changed = memcmp(d->out_next, out, d->n_out * sizeof *out) != 0;
    if (changed) {
        memcpy(d->out_next, out, d->n_out * sizeof *out);
        d->out_seq++;
    }
    pthread_mutex_unlock(&d->m);
    if (changed) {
        io_device_t *L = d->leader;
        atomic_fetch_add(&L->line_seq, 1);
        rt_wake(&L->wake);
    }
}

/* How old a snapshot stamped `snap` is at `now`; 0 when it was taken after `now` was read (the poll thread
 * stamps a cycle with the time it began, which may follow the reader's clock reading). */
static uint64_t snap_age(uint64_t now, uint64_t snap)
{
    return now > snap ? now - snap : 0;
}

/* A device whose inputs are older than its age limit is lost now: its outputs get their safe values at once
 * (handed to its poll thread), its state and log line change; the scan's input latch agrees at its next start
 * (it judges the same snapshot by the same limit).  Only the OK -> LOST transition is made here. */
static void declare_lost_if_stale(io_device_t *d, uint64_t now, uint64_t snap)
{
    const bool stale = snap != 0 && snap_age(now, snap) > (uint64_t)d->loss_ms * 1000000u;
    if (!stale || atomic_load(&d->state) != IO_DEVICE_OK)
        return;
    hand_over(d, d->safe);
    set_state(d, IO_DEVICE_LOST, now, snap_age(now, snap));
}

static void *loss_watch(void *arg)
{
    io_modbus_t *io = arg;

    rt_thread_name("io-loss-watch");
    (void)rt_thread_fifo(io->rt, IO_BELOW_SCAN);    /* it declares losses: outputs safe, as the poll threads */

    for (;;) {
        const uint64_t now = now_ns();
        uint64_t next = now + 1000000000u;
        for (unsigned i = 0; i < io->n; i++) {
            io_device_t *d = &io->dev[i];
            const uint64_t age = (uint64_t)d->loss_ms * 1000000u;
            pthread_mutex_lock(&d->m);
            const uint64_t snap = d->snap_ns;
            pthread_mutex_unlock(&d->m);
            declare_lost_if_stale(d, now, snap);
            /* next look: when this device's inputs pass the limit, or one limit from now if they already did */
            const uint64_t due = (snap != 0 && snap + age > now) ? snap + age + 1 : now + age;
            if (due < next)
                next = due;
        }
        struct timespec ts = { .tv_sec = (time_t)(next / 1000000000u), .tv_nsec = (long)(next % 1000000000u) };
        pthread_mutex_lock(&io->wm);
        while (!io->wstop && now_ns() < next)
            if (pthread_cond_timedwait(&io->wcv, &io->wm, &ts) == ETIMEDOUT)
                break;
        const bool stop = io->wstop;
        pthread_mutex_unlock(&io->wm);
        if (stop)
            return NULL;
    }
}

static void modbus_read_inputs(void *state, plc_bool_t ix[MAP_BITS], uint16_t iw[MAP_WORDS])
{
    io_modbus_t *io = state;
    const uint64_t now = now_ns();

    for (unsigned i = 0; i < io->n; i++) {
        io_device_t *d = &io->dev[i];
        uint64_t snap;

        pthread_mutex_lock(&d->m);
        snap = d->snap_ns;
        const bool fresh = snap != 0 && snap_age(now, snap) <= (uint64_t)d->loss_ms * 1000000u;
        if (fresh)
            memcpy(d->in_scan, d->in_snap, d->n_in * sizeof *d->in_scan);
        pthread_mutex_unlock(&d->m);

        for (unsigned k = 0; k < d->n_ranges; k++) {
            const io_range_t *r = &d->ranges[k];
            if (rules[r->kind].output)
                continue;
            for (unsigned j = 0; j < r->count; j++) {
                uint16_t v = fresh ? d->in_scan[r->at + j] : 0;
                if (rules[r->kind].bits)
                    ix[r->image + j] = v ? 1 : 0;
                else
                    iw[r->image + j] = v;
            }
        }
        if (d->status_bit >= 0)
            ix[d->status_bit] = fresh ? 0 : 1;
        if (fresh)
            set_state(d, IO_DEVICE_OK, now, 0);
        else if (atomic_load(&d->state) == IO_DEVICE_OK)
            set_state(d, IO_DEVICE_LOST, now, snap_age(now, snap));
    }
}

static void modbus_write_outputs(void *state, const plc_bool_t qx[MAP_BITS], const uint16_t qw[MAP_WORDS])
{
    io_modbus_t *io = state;
    runtime_t *rt = io->rt;
    const bool on_scan = pthread_equal(pthread_self(), rt->scan_thread);
    const bool stopped = atomic_load(&rt->watchdog_tripped) || !on_scan || atomic_load(&rt->state) != PLC_STATE_RUNNING;

    for (unsigned i = 0; i < io->n; i++) {
        io_device_t *d = &io->dev[i];
        uint16_t *out = d->out_scan;

        if (stopped || atomic_load(&d->state) != IO_DEVICE_OK) {
            out = d->safe;
        } else {
            for (unsigned k = 0; k < d->n_ranges; k++) {
                const io_range_t *r = &d->ranges[k];
                if (!rules[r->kind].output)
                    continue;
                for (unsigned j = 0; j < r->count; j++)
                    out[r->at + j] = rules[r->kind].bits ? (qx[r->image + j] ? 1 : 0) : qw[r->image + j];
            }
        }
        hand_over(d, out);
    }
}

/* ------------------------------------------------------------ open/close */

static void free_device(io_device_t *d)
{
    free(d->safe);
    free(d->out_next);
    free(d->out_work);
    free(d->out_scan);
    free(d->in_snap);
    free(d->in_work);
    free(d->in_scan);
}

static void modbus_close_layer(void *state)
{
    io_modbus_t *io = state;

    if (!io)
        return;
    if (io->watch_started) {
        pthread_mutex_lock(&io->wm);
        io->wstop = true;
        pthread_cond_broadcast(&io->wcv);
        pthread_mutex_unlock(&io->wm);
        pthread_join(io->watch, NULL);
    }
    for (unsigned i = 0; i < io->n; i++) {
        io_device_t *d = &io->dev[i];
        pthread_mutex_lock(&d->m);
        d->stop = true;
        pthread_mutex_unlock(&d->m);
        rt_wake(&d->wake);
    }
    for (unsigned i = 0; i < io->n; i++)
        if (io->dev[i].thread_started)
            pthread_join(io->dev[i].thread, NULL);
    /* The poll threads are gone: leave every device with its safe values, once. */
    for (unsigned i = 0; i < io->n; i++) {
        io_device_t *d = &io->dev[i];
        if (d->ctx && d->leader && d->leader->connected) {
            modbus_set_slave(d->ctx, d->unit);
            bool sent = write_outputs_now(d, d->safe) == 0;
            log_msg(io->rt->log, sent ? LOG_INFO : LOG_WARN, "I/O device %u (%s): %s", d->index + 1, d->name,
                    sent ? "safe values written" : "safe values could not be written");
        }
    }
    for (unsigned i = 0; i < io->n; i++) {
        io_device_t *d = &io->dev[i];
        if (d->ctx && d->leader == d) {
            modbus_close(d->ctx);
            modbus_free(d->ctx);
        }
        rt_wake_destroy(&d->wake);
        pthread_mutex_destroy(&d->m);
        free_device(d);
    }
    pthread_cond_destroy(&io->wcv);
    pthread_mutex_destroy(&io->wm);
    free(io);
}

/* The age at which a device counts as lost.  On a shared line it is the max age less the line margin (the same
 * as io_config.py's LINE_MARGIN_TIMEOUTS): a failed transaction in flight (2 time-outs), then the reacting scan
 * and the write to a neighbour (1 time-out, which holds a task period and a frame time; a warning says when the
 * task period is longer) can still pass before the neighbours have the program's reaction to the loss.  Without age= there, the max age is the line's worst
 * case between two polls of a unit (every other unit failing once: 2 time-outs each, its own read and write
 * 2 more, the line's poll period) plus that margin. */
static void set_loss_limit(io_device_t *d)
{
    const io_device_t *L = d->leader;
    const unsigned period_ms = (unsigned)((d->rt->period_ns + 999999u) / 1000000u);
    const unsigned margin = 3 * d->timeout_ms;
    const unsigned worst_gap = L->line_poll_ms + 2 * d->timeout_ms * L->n_members;

    d->loss_ms = d->age_ms;
    if (L->n_members < 2)
        return;
    if (period_ms >= d->timeout_ms)
        log_msg(d->rt->log, LOG_WARN, "I/O device %u (%s): the task period (%u ms) is not shorter than the response "
                "time-out (%u ms): after a loss on serial line %s the program's reaction can reach the other units "
                "later than max age", d->index + 1, d->name, period_ms, d->timeout_ms, d->path);
    if (!d->age_given)
        d->age_ms = worst_gap + margin;
    d->loss_ms = d->age_ms > margin ? d->age_ms - margin : 1;   /* plc run refuses an age_ms below worst_gap + margin */
}

/* Devices on one serial path (RS-485 multi-drop) share one context and one poll thread: the first one's, with its
 * line settings (plc run has checked that they are the same, and the units distinct). */
static void group_lines(io_modbus_t *io)
{
    for (unsigned i = 0; i < io->n; i++) {
        io_device_t *d = &io->dev[i];
        d->leader = d;
        d->line_poll_ms = d->poll_ms;
        d->n_members = 1;
        for (unsigned j = 0; d->rtu && j < i; j++) {
            io_device_t *o = &io->dev[j];
            if (!o->rtu || o->leader != o || strcmp(o->path, d->path) != 0)
                continue;
            io_device_t *tail = o;
            while (tail->next_member)
                tail = tail->next_member;
            tail->next_member = d;
            d->leader = o;
            o->n_members++;
            if (d->poll_ms < o->line_poll_ms)
                o->line_poll_ms = d->poll_ms;
            break;
        }
    }
    for (unsigned i = 0; i < io->n; i++)
        set_loss_limit(&io->dev[i]);
}

static int open_device(io_device_t *d, char *err, size_t errlen)
{
    rt_wake_init(&d->wake);
    rt_mutex_init(&d->m);
    atomic_store(&d->state, IO_DEVICE_WAITING);

    if (d->leader != d) {           /* a further device on a serial line: its leader's context */
        d->ctx = d->leader->ctx;
        return 0;
    }
    if (d->rtu)
        d->ctx = modbus_new_rtu(d->path, d->baud, d->parity, d->data_bits, d->stop_bits);
    else
        d->ctx = modbus_new_tcp(d->host, d->port);
    if (!d->ctx) {
        snprintf(err, errlen, "device %u (%s): %s: %s", d->index + 1, d->name, d->where, modbus_strerror(errno));
        return -1;
    }
    if (modbus_set_slave(d->ctx, d->unit) != 0) {
        snprintf(err, errlen, "device %u (%s): unit %d: %s", d->index + 1, d->name, d->unit, modbus_strerror(errno));
        return -1;
    }
    modbus_set_response_timeout(d->ctx, d->timeout_ms / 1000u, (d->timeout_ms % 1000u) * 1000u);
    modbus_set_byte_timeout(d->ctx, d->timeout_ms / 1000u, (d->timeout_ms % 1000u) * 1000u);
    modbus_set_error_recovery(d->ctx, MODBUS_ERROR_RECOVERY_NONE);
    return 0;
}

static int modbus_open_layer(runtime_t *rt, void **state, char *err, size_t errlen)
{
    io_modbus_t *io = calloc(1, sizeof *io);
    unsigned wait_ms = 0;
    int rc;

    *state = NULL;
    if (!io) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    io->rt = rt;
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&io->wcv, &ca);
    pthread_condattr_destroy(&ca);
    rt_mutex_init(&io->wm);
    for (int i = 0; i < rt->opt.n_io_devices; i++) {
        io_device_t *d = &io->dev[io->n];
        d->rt = rt;
        d->index = io->n;
        io->n++;
        if (parse_device(d, rt->opt.io_devices[i], err, errlen) != 0) {
            for (unsigned k = 0; k < io->n; k++)
                free_device(&io->dev[k]);
            free(io);
            return -1;
        }
    }
    group_lines(io);
    for (unsigned i = 0; i < io->n; i++) {
        io_device_t *d = &io->dev[i];
        if (open_device(d, err, errlen) != 0) {
            for (unsigned k = i + 1; k < io->n; k++)
                free_device(&io->dev[k]);
            io->n = i + 1;
            modbus_close_layer(io);
            return -1;
        }
        log_msg(rt->log, LOG_INFO, "I/O device %u (%s): %s, poll %u ms, response timeout %u ms, inputs lost "
                "after %u ms%s, %u input and %u output values, status input %d", i + 1, d->name, d->where,
                d->poll_ms, d->timeout_ms, d->loss_ms,
                d->loss_ms != d->age_ms ? " (max age less the shared line's margin)" : "", d->n_in, d->n_out,
                d->status_bit);
        unsigned need = 2 * d->timeout_ms + d->poll_ms + 200;
        if (need > wait_ms)
            wait_ms = need;
    }
    for (unsigned i = 0; i < io->n; i++) {
        io_device_t *d = &io->dev[i];
        if (d->leader != d)
            continue;
        rc = pthread_create(&d->thread, NULL, poll_thread, d);
        if (rc != 0) {
            snprintf(err, errlen, "cannot start the poll thread of device %u: %s", i + 1, strerror(rc));
            modbus_close_layer(io);
            return -1;
        }
        d->thread_started = true;
    }

    /* Give every device the chance of a first complete cycle, so that a
     * healthy machine does not start with its modules reported lost. */
    if (wait_ms > STARTUP_WAIT_MAX_MS)
        wait_ms = STARTUP_WAIT_MAX_MS;
    const uint64_t until = now_ns() + (uint64_t)wait_ms * 1000000u;
    for (;;) {
        unsigned ready = 0;
        for (unsigned i = 0; i < io->n; i++) {
            pthread_mutex_lock(&io->dev[i].m);
            ready += io->dev[i].snap_ns != 0;
            pthread_mutex_unlock(&io->dev[i].m);
        }
        if (ready == io->n || now_ns() >= until)
            break;
        struct timespec ms = { 0, 1000000 };
        nanosleep(&ms, NULL);
    }
    rc = pthread_create(&io->watch, NULL, loss_watch, io);
    if (rc != 0) {
        snprintf(err, errlen, "cannot start the loss watch of the I/O devices: %s", strerror(rc));
        modbus_close_layer(io);
        return -1;
    }
    io->watch_started = true;
    *state = io;
    return 0;
}

const io_layer_t io_modbus_layer = {
    .name = "modbus",
    .description = "remote I/O devices over Modbus TCP/RTU, polled by their own threads (--io-device)",
    .open = modbus_open_layer,
    .read_inputs = modbus_read_inputs,
    .write_outputs = modbus_write_outputs,
    .close = modbus_close_layer,
};
