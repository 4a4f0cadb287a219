/*
 * retain.c - RETAIN variables and retained holding registers, saved
 * atomically and restored at start.
 *
 * What is saved: the bytes of every variable the program's table marks
 * RETAIN (and not CONSTANT), in table order, then the retained holding
 * registers (--retain-registers), ascending, two bytes each, big-endian.
 *
 * File layout (integers little-endian):
 *   0  8  magic "ATCPLCR1"
 *   8  4  format version (1)
 *  12  4  layout hash: the program's layout_hash folded with the path, type
 *         and size of each retained variable and the retained register list
 *  16  8  generation (counts saves since the runtime started)
 *  24  4  payload length N
 *  28  N  payload
 *  28+N 4 CRC-32 (IEEE) of bytes 0 .. 28+N-1
 *
 * One runtime per file: <file>.lock carries a POSIX record lock for as long
 * as the store is open (the kernel drops it when the process dies, kill -9
 * included) and the holder's pid; a second runtime given the same file stops
 * at start-up naming that pid.
 *
 * Saving: <file>.tmp is written, fsync'ed, renamed over <file>, and the
 * directory is fsync'ed, so the file on disk is always one complete save,
 * whatever instant the process is killed at.  The scan thread only compares
 * and copies bytes; a writer thread does the file work.  Saves happen when
 * the data changed after a successful scan, at most once per
 * --retain-interval, and at shutdown.  A file that is unreadable, corrupt or
 * made by a different layout is reported, renamed to <file>.rejected and not
 * applied at all.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <libgen.h>
#include <limits.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "runtime.h"

#define RETAIN_MAGIC "ATCPLCR1"
#define RETAIN_VERSION 1u
#define RETAIN_HEADER 28u
#define RETAIN_TRAILER 4u

struct retain_store {
    runtime_t *rt;
    char path[PATH_MAX];
    char tmp_path[PATH_MAX + 8];
    char dir[PATH_MAX];
    int lock_fd;                  /* holds the lock on <file>.lock; -1: none */
    uint32_t layout;
    size_t size;                  /* payload bytes */

    /* scan thread only */
    uint8_t *gather;              /* payload of the scan just run */
    uint8_t *seen;                /* payload of the last successful scan */
    bool dirty;                   /* seen differs from what was handed over */
    uint64_t last_handoff_ns;
    bool handed_once;             /* the first save is not rate-limited */

    /* shared with the writer, under mu */
    pthread_mutex_t mu;
    pthread_cond_t cv;
    uint8_t *outbox;
    bool outbox_full;
    bool stopping;
    uint64_t generation;

    /* writer only */
    uint8_t *file_buf;
    bool failing;

    pthread_t writer;
    atomic_uint saves;
    atomic_bool last_failed;
};

/* ----------------------------------------------------------------- crc32 */

uint32_t crc32_update(uint32_t crc, const void *data, size_t len)
{
    const uint8_t *p = data;

    crc = ~crc;
    while (len--) {
        crc ^= *p++;
        for (int k = 0; k < 8; k++)
            crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    return ~crc;
}

static void put32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

static uint32_t get32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* --------------------------------------------------------------- layout */

static bool is_retained(const plc_var_t *v)
{
    return v->retain && !v->constant && v->addr != NULL && v->size > 0;
}

static void compute_layout(retain_store_t *rs)
{
    const plc_program_t *prog = rs->rt->prog;
    const rt_options_t *opt = &rs->rt->opt;
    uint8_t word[4];
    uint32_t h = 0;
    size_t size = 0;

    put32(word, prog->layout_hash);
    h = crc32_update(h, word, 4);
    for (uint32_t i = 0; i < prog->n_vars; i++) {
        const plc_var_t *v = &prog->vars[i];
        if (!is_retained(v))
            continue;
        h = crc32_update(h, v->path, strlen(v->path) + 1);
        put32(word, v->type);
        h = crc32_update(h, word, 4);
        put32(word, v->size);
        h = crc32_update(h, word, 4);
        size += v->size;
    }
    for (unsigned a = 0; a < MAP_HOLDING; a++) {
        if (!addr_set_has(&opt->retain_registers, a))
            continue;
        put32(word, a);
        h = crc32_update(h, word, 4);
        size += 2;
    }
    rs->layout = h;
    rs->size = size;
}

static void gather(retain_store_t *rs, uint8_t *out)
{
    const plc_program_t *prog = rs->rt->prog;
    const rt_options_t *opt = &rs->rt->opt;
    size_t at = 0;

    for (uint32_t i = 0; i < prog->n_vars; i++) {
        const plc_var_t *v = &prog->vars[i];
        if (!is_retained(v))
            continue;
        memcpy(out + at, v->addr, v->size);
        at += v->size;
    }
    if (!opt->have_retain_registers)
        return;
    for (unsigned a = 0; a < MAP_HOLDING; a++) {
        if (!addr_set_has(&opt->retain_registers, a))
            continue;
        uint16_t r = image_prog_holding(&rs->rt->pimg, a);
        out[at++] = (uint8_t)(r >> 8);
        out[at++] = (uint8_t)r;
    }
}

static void scatter(retain_store_t *rs, const uint8_t *in)
{
    const plc_program_t *prog = rs->rt->prog;
    const rt_options_t *opt = &rs->rt->opt;
    size_t at = 0;

    for (uint32_t i = 0; i < prog->n_vars; i++) {
        const plc_var_t *v = &prog->vars[i];
        if (!is_retained(v))
            continue;
        memcpy(v->addr, in + at, v->size);
        at += v->size;
    }
    if (!opt->have_retain_registers)
        return;
    for (unsigned a = 0; a < MAP_HOLDING; a++) {
        if (!addr_set_has(&opt->retain_registers, a))
            continue;
        image_prog_set_holding(&rs->rt->pimg, a, (uint16_t)(in[at] << 8 | in[at + 1]));
        at += 2;
    }
}

/* ------------------------------------------------------------------ lock */

/* The pid holding the lock on fd: the kernel's answer, else the pid the holder
 * wrote into the file (another pid namespace), else 0. */
static long lock_holder(int fd)
{
    struct flock who = { .l_type = F_WRLCK, .l_whence = SEEK_SET };
    char text[24] = "";

    if (fcntl(fd, F_GETLK, &who) == 0 && who.l_type != F_UNLCK && who.l_pid > 0)
        return (long)who.l_pid;
    ssize_t n = pread(fd, text, sizeof text - 1, 0);
    return n > 0 ? strtol(text, NULL, 10) : 0;
}

/* Take <file>.lock for this runtime, or say who has it.  Returns 0 or -1. */
static int lock_store(retain_store_t *rs)
{
    char lock_path[PATH_MAX + 8], pid_text[24];
    struct flock fl = { .l_type = F_WRLCK, .l_whence = SEEK_SET };

    snprintf(lock_path, sizeof lock_path, "%s.lock", rs->path);
    int fd = open(lock_path, O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (fd < 0) {
        log_msg(rs->rt->log, LOG_ERROR, "retain: cannot open the lock file %s: %s", lock_path, strerror(errno));
        return -1;
    }
    if (fcntl(fd, F_SETLK, &fl) != 0) {
        if (errno == EACCES || errno == EAGAIN)
            log_msg(rs->rt->log, LOG_ERROR, "retain: %s is in use by another runtime (pid %ld holds %s); give "
                    "each runtime its own retain file", rs->path, lock_holder(fd), lock_path);
        else
            log_msg(rs->rt->log, LOG_ERROR, "retain: cannot lock %s: %s", lock_path, strerror(errno));
        close(fd);
        return -1;
    }
    int n = snprintf(pid_text, sizeof pid_text, "%ld\n", (long)getpid());
    if (ftruncate(fd, 0) != 0 || pwrite(fd, pid_text, (size_t)n, 0) != n)
        log_msg(rs->rt->log, LOG_WARN, "retain: cannot write the pid into %s: %s", lock_path, strerror(errno));
    rs->lock_fd = fd;
    return 0;
}

/* The file stays (removing it would let two runtimes lock two different inodes). */
static void unlock_store(retain_store_t *rs)
{
    if (rs->lock_fd >= 0)
        close(rs->lock_fd);
    rs->lock_fd = -1;
}

/* ------------------------------------------------------------- restore */

static void reject(retain_store_t *rs, const char *why)
{
    char aside[PATH_MAX + 16];

    rs->rt->flags |= DIAG_FLAG_RETAIN_REJECTED;
    snprintf(aside, sizeof aside, "%s.rejected", rs->path);
    if (rename(rs->path, aside) == 0)
        log_msg(rs->rt->log, LOG_WARN, "retain: %s rejected (%s); kept as %s; RETAIN variables start from "
                "their initial values", rs->path, why, aside);
    else
        log_msg(rs->rt->log, LOG_WARN, "retain: %s rejected (%s); RETAIN variables start from their initial "
                "values", rs->path, why);
}

static void restore(retain_store_t *rs)
{
    const size_t want = RETAIN_HEADER + rs->size + RETAIN_TRAILER;
    uint8_t *buf;
    struct stat st;
    int fd = open(rs->path, O_RDONLY | O_CLOEXEC);

    if (fd < 0) {
        if (errno == ENOENT)
            log_msg(rs->rt->log, LOG_INFO, "retain: %s does not exist yet; RETAIN variables start from their "
                    "initial values", rs->path);
        else
            reject(rs, strerror(errno));
        return;
    }
    if (fstat(fd, &st) != 0 || (size_t)st.st_size != want) {
        char why[96];
        snprintf(why, sizeof why, "size %lld bytes, expected %zu", (long long)st.st_size, want);
        close(fd);
        reject(rs, why);
        return;
    }
    buf = malloc(want);
    if (!buf) {
        close(fd);
        reject(rs, "out of memory");
        return;
    }
    size_t got = 0;
    while (got < want) {
        ssize_t n = read(fd, buf + got, want - got);
        if (n <= 0)
            break;
        got += (size_t)n;
    }
    close(fd);

    const char *why = NULL;
    if (got != want)
        why = "short read";
    else if (memcmp(buf, RETAIN_MAGIC, 8) != 0)
        why = "not a retain file";
    else if (get32(buf + 8) != RETAIN_VERSION)
        why = "unknown format version";
    else if (get32(buf + 24) != rs->size)
        why = "payload size differs from this program's retained data";
    else if (crc32_update(0, buf, want - RETAIN_TRAILER) != get32(buf + want - RETAIN_TRAILER))
        why = "CRC mismatch: the file is corrupt";
    else if (get32(buf + 12) != rs->layout)
        why = "layout hash differs: saved by a different program";
    if (why) {
        free(buf);
        reject(rs, why);
        return;
    }
    scatter(rs, buf + RETAIN_HEADER);
    rs->rt->flags |= DIAG_FLAG_RETAIN_RESTORED;
    log_msg(rs->rt->log, LOG_INFO, "retain: restored %zu bytes from %s", rs->size, rs->path);
    free(buf);
}

/* ---------------------------------------------------------------- saving */

static int write_all(int fd, const uint8_t *p, size_t n)
{
    while (n > 0) {
        ssize_t w = write(fd, p, n);
        if (w < 0) {
            if (errno == EINTR)
                continue;
            return -1;
        }
        p += w;
        n -= (size_t)w;
    }
    return 0;
}

/* A rename is durable only once the directory holding it is on disk. */
static int sync_directory(const retain_store_t *rs)
{
    int dfd = open(rs->dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);

    if (dfd < 0)
        return -1;
    int rc = fsync(dfd), saved = errno;
    close(dfd);
    errno = saved;
    return rc;
}

static int save_file(retain_store_t *rs, uint64_t generation)
{
    uint8_t *f = rs->file_buf;
    const size_t total = RETAIN_HEADER + rs->size + RETAIN_TRAILER;
    const char *step = "open";
    int fd;

    memcpy(f, RETAIN_MAGIC, 8);
    put32(f + 8, RETAIN_VERSION);
    put32(f + 12, rs->layout);
    put32(f + 16, (uint32_t)generation);
    put32(f + 20, (uint32_t)(generation >> 32));
    put32(f + 24, (uint32_t)rs->size);
    put32(f + RETAIN_HEADER + rs->size, crc32_update(0, f, RETAIN_HEADER + rs->size));

    fd = open(rs->tmp_path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0)
        goto fail;
    step = "write";
    if (write_all(fd, f, total) != 0) {
        close(fd);
        goto fail;
    }
    step = "fsync";
    if (fsync(fd) != 0) {
        close(fd);
        goto fail;
    }
    close(fd);
    step = "rename";
    if (rename(rs->tmp_path, rs->path) != 0)
        goto fail;
    step = "directory fsync";
    if (sync_directory(rs) != 0)
        goto fail;
    if (rs->failing)
        log_msg(rs->rt->log, LOG_INFO, "retain: saving to %s works again", rs->path);
    rs->failing = false;
    atomic_store(&rs->last_failed, false);
    atomic_fetch_add(&rs->saves, 1);
    return 0;
fail:
    if (!rs->failing)   /* one line per failure streak */
        log_msg(rs->rt->log, LOG_ERROR, "retain: cannot save %s (%s: %s)", rs->path, step, strerror(errno));
    rs->failing = true;
    atomic_store(&rs->last_failed, true);
    return -1;
}

static void *writer_thread(void *arg)
{
    retain_store_t *rs = arg;

    pthread_mutex_lock(&rs->mu);
    for (;;) {
        while (!rs->outbox_full && !rs->stopping)
            pthread_cond_wait(&rs->cv, &rs->mu);
        if (!rs->outbox_full)
            break;                                 /* stopping, nothing left */
        uint64_t generation = rs->generation;
        memcpy(rs->file_buf + RETAIN_HEADER, rs->outbox, rs->size);
        rs->outbox_full = false;
        pthread_mutex_unlock(&rs->mu);
        save_file(rs, generation);
        pthread_mutex_lock(&rs->mu);
    }
    pthread_mutex_unlock(&rs->mu);
    return NULL;
}

/* ------------------------------------------------------------- interface */

int retain_open(runtime_t *rt, retain_store_t **out)
{
    retain_store_t *rs;
    char dircopy[PATH_MAX];
    struct stat st;

    *out = NULL;
    if (!rt->opt.retain_path) {
        log_msg(rt->log, LOG_INFO, "retain: no retain file given; RETAIN values will not survive a restart");
        return 0;
    }
    rs = calloc(1, sizeof *rs);
    if (!rs)
        return -1;
    rs->rt = rt;
    if (snprintf(rs->path, sizeof rs->path, "%s", rt->opt.retain_path) >= (int)sizeof rs->path) {
        log_msg(rt->log, LOG_ERROR, "retain: path too long");
        free(rs);
        return -1;
    }
    snprintf(rs->tmp_path, sizeof rs->tmp_path, "%s.tmp", rs->path);
    snprintf(dircopy, sizeof dircopy, "%s", rs->path);
    snprintf(rs->dir, sizeof rs->dir, "%s", dirname(dircopy));
    if (stat(rs->dir, &st) != 0 || !S_ISDIR(st.st_mode) || access(rs->dir, W_OK) != 0) {
        log_msg(rt->log, LOG_ERROR, "retain: directory %s of the retain file does not exist or is not writable",
                rs->dir);
        free(rs);
        return -1;
    }
    rs->lock_fd = -1;
    if (lock_store(rs) != 0) {
        free(rs);
        return -1;
    }

    compute_layout(rs);
    size_t n = rs->size ? rs->size : 1;
    rs->gather = calloc(1, n);
    rs->seen = calloc(1, n);
    rs->outbox = calloc(1, n);
    rs->file_buf = calloc(1, RETAIN_HEADER + n + RETAIN_TRAILER);
    if (!rs->gather || !rs->seen || !rs->outbox || !rs->file_buf) {
        free(rs->gather); free(rs->seen); free(rs->outbox); free(rs->file_buf);
        unlock_store(rs);
        free(rs);
        return -1;
    }
    pthread_mutex_init(&rs->mu, NULL);
    pthread_cond_init(&rs->cv, NULL);

    if (rs->size > 0)
        restore(rs);
    gather(rs, rs->seen);

    if (pthread_create(&rs->writer, NULL, writer_thread, rs) != 0) {
        log_msg(rt->log, LOG_ERROR, "retain: cannot start the writer thread");
        free(rs->gather); free(rs->seen); free(rs->outbox); free(rs->file_buf);
        unlock_store(rs);
        free(rs);
        return -1;
    }
    if (rs->size == 0)
        log_msg(rt->log, LOG_INFO, "retain: the program has no RETAIN data; %s stays as it is", rs->path);
    else
        log_msg(rt->log, LOG_INFO, "retain: %zu bytes retained, saved to %s at most every %d ms and at shutdown",
                rs->size, rs->path, rt->opt.retain_interval_ms);
    *out = rs;
    return 0;
}

void retain_capture(runtime_t *rt)
{
    retain_store_t *rs = rt->retain;

    if (!rs || rs->size == 0)
        return;
    gather(rs, rs->gather);
    if (memcmp(rs->gather, rs->seen, rs->size) != 0) {
        memcpy(rs->seen, rs->gather, rs->size);
        rs->dirty = true;
    }
}

void retain_after_scan(runtime_t *rt, uint64_t now)
{
    retain_store_t *rs = rt->retain;

    if (!rs || rs->size == 0)
        return;
    retain_capture(rt);
    if (!rs->dirty)
        return;
    if (rs->handed_once && now - rs->last_handoff_ns < (uint64_t)rt->opt.retain_interval_ms * 1000000u)
        return;
    /* Never wait for the writer: if it is busy, try again next scan. */
    if (pthread_mutex_trylock(&rs->mu) != 0)
        return;
    if (!rs->outbox_full) {
        memcpy(rs->outbox, rs->seen, rs->size);
        rs->outbox_full = true;
        rs->generation++;
        rs->dirty = false;
        rs->last_handoff_ns = now;
        rs->handed_once = true;
        pthread_cond_signal(&rs->cv);
    }
    pthread_mutex_unlock(&rs->mu);
}

void retain_close(runtime_t *rt)
{
    retain_store_t *rs = rt->retain;

    if (!rs)
        return;
    pthread_mutex_lock(&rs->mu);
    if (rs->dirty) {
        memcpy(rs->outbox, rs->seen, rs->size);
        rs->outbox_full = true;
        rs->generation++;
        rs->dirty = false;
    }
    rs->stopping = true;
    pthread_cond_signal(&rs->cv);
    pthread_mutex_unlock(&rs->mu);
    pthread_join(rs->writer, NULL);
    log_msg(rt->log, LOG_INFO, "retain: %s up to date (%u saves this run%s)", rs->path,
            atomic_load(&rs->saves), atomic_load(&rs->last_failed) ? ", the last one FAILED" : "");
    pthread_mutex_destroy(&rs->mu);
    pthread_cond_destroy(&rs->cv);
    free(rs->gather); free(rs->seen); free(rs->outbox); free(rs->file_buf);
    unlock_store(rs);
    free(rs);
    rt->retain = NULL;
}

uint32_t retain_saves(const retain_store_t *rs)
{
    return atomic_load(&((retain_store_t *)rs)->saves);
}

bool retain_last_failed(const retain_store_t *rs)
{
    return atomic_load(&((retain_store_t *)rs)->last_failed);
}
