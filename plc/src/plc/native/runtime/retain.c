/*
 * retain.c - RETAIN data, kept value by value across restarts and program
 * upgrades, saved atomically.
 *
 * What is kept: one entry per retained item, named and typed, so a new
 * program version gets back every value whose name and type it kept:
 *   - every variable the program's table marks RETAIN (and not CONSTANT),
 *     named by its path, typed by its full type_name;
 *   - the retained holding registers: those of --retain-registers and those
 *     of every located variable declared RETAIN (%QW %MW %MD %ML).  A located
 *     variable whose registers are all retained is one entry named by its
 *     path and located at its address ("%MW0"); any other retained register
 *     is an entry of its own, named by its address ("%MW5", "HR2049").
 *
 * At start each saved entry is matched to this program's entries by name and
 * type (a located entry whose name is gone may also match by address and
 * type: a renamed signal keeps its register).  Matched values are restored;
 * new entries start from their initial values; saved entries that match
 * nothing (gone, or type changed) are named in the log one by one and kept
 * aside: they stay in the file, flagged, through every later save, so going
 * back to the earlier program version finds them again.
 *
 * File layout (integers little-endian):
 *   0  8  magic "ATCPLCR1"
 *   8  4  format version (2)
 *  12  4  number of entries
 *  16  8  generation (counts saves since the runtime started)
 *  24  4  body length N
 *  28  N  entries, each:
 *           1  flags (ENTRY_KEPT_ASIDE: saved by an earlier program, unused now)
 *           1  0
 *           2  path length P    2  type length T    2  location length L
 *           4  value size S
 *           P path, T type, L location ("" for a variable), S value bytes
 *           (a variable's bytes in native order; registers high byte first)
 *  28+N 4 CRC-32 (IEEE) of bytes 0 .. 28+N-1
 * A file of format version 1 (the values of one whole program in one block)
 * is still read when it was saved by the same retained layout.
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
 * --retain-interval, and at shutdown.  A file that is unreadable or corrupt
 * is reported, renamed to <file>.rejected and not applied at all.
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
#define RETAIN_VERSION 2u
#define RETAIN_VERSION_BLOCK 1u       /* one block per program: read, never written */
#define RETAIN_HEADER 28u
#define RETAIN_TRAILER 4u
#define ENTRY_HEAD 12u
#define ENTRY_KEPT_ASIDE 0x01u
#define ENTRY_NAME 24u                /* "%MW1023", "HR8191" */

/* One retained item of this program. */
typedef struct retain_entry {
    const char *path;             /* variable path, or name[] */
    const char *type;             /* type signature */
    char name[ENTRY_NAME];        /* a register's own name when no located variable covers it */
    char where[ENTRY_NAME];       /* "%MW0" for registers, "" for a variable */
    void *addr;                   /* variable storage; NULL for registers */
    unsigned reg, nregs;          /* first holding register and how many */
    uint32_t size;                /* value bytes */
    size_t offset;                /* of the value in the payload */
    bool restored;
    bool announced;               /* its start from the initial value is already explained */
} retain_entry_t;

/* A piece of text inside a file being read (not NUL-terminated). */
typedef struct text_ref {
    const char *p;
    int n;
} text_ref_t;

/* One entry of a file being read (pointers into the file's buffer). */
typedef struct saved_entry {
    const uint8_t *raw;           /* the whole entry, head included */
    size_t raw_len;
    uint8_t flags;
    text_ref_t path, type, where;
    const uint8_t *value;
    uint32_t size;
    bool used;
} saved_entry_t;

struct retain_store {
    runtime_t *rt;
    char path[PATH_MAX];
    char tmp_path[PATH_MAX + 8];
    char dir[PATH_MAX];
    int lock_fd;                  /* holds the lock on <file>.lock; -1: none */
    retain_entry_t *entries;
    size_t n_entries;
    size_t size;                  /* payload bytes: the values of all entries */
    uint8_t *kept;                /* entries kept aside, as they go into the file */
    size_t kept_len;
    uint32_t n_kept;
    size_t file_size;

    /* scan thread only */
    uint8_t *gather;              /* payload of the scan just run */
    uint8_t *seen;                /* payload of the last successful scan */
    bool dirty;                   /* seen differs from what was handed over */
    uint64_t last_handoff_ns;
    bool handed_once;             /* the first save is not rate-limited */

    /* shared with the writer, under mu (the scan thread only trylocks it) */
    pthread_mutex_t mu;
    rt_wake_t wake;               /* the outbox was filled, or stopping (never blocks the scan) */
    uint8_t *outbox;
    bool outbox_full;
    bool stopping;
    uint64_t generation;

    /* writer only */
    uint8_t *values;              /* the payload being saved */
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

static void put16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

static void put32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

static uint16_t get16(const uint8_t *p)
{
    return (uint16_t)(p[0] | p[1] << 8);
}

static uint32_t get32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* --------------------------------------------------------------- entries */

static bool is_retained(const plc_var_t *v)
{
    return v->retain && !v->constant && v->addr != NULL && v->size > 0;
}

const char *plc_type_name(unsigned type)
{
    static const char *const names[] = {
        [PLC_T_OTHER] = "?", [PLC_T_BOOL] = "BOOL", [PLC_T_SINT] = "SINT", [PLC_T_INT] = "INT",
        [PLC_T_DINT] = "DINT", [PLC_T_LINT] = "LINT", [PLC_T_USINT] = "USINT", [PLC_T_UINT] = "UINT",
        [PLC_T_UDINT] = "UDINT", [PLC_T_ULINT] = "ULINT", [PLC_T_BYTE] = "BYTE", [PLC_T_WORD] = "WORD",
        [PLC_T_DWORD] = "DWORD", [PLC_T_LWORD] = "LWORD", [PLC_T_REAL] = "REAL", [PLC_T_LREAL] = "LREAL",
        [PLC_T_TIME] = "TIME", [PLC_T_DATE] = "DATE", [PLC_T_TOD] = "TOD", [PLC_T_DT] = "DT",
        [PLC_T_STRING] = "STRING", [PLC_T_ENUM] = "ENUM",
    };
    return type < sizeof names / sizeof names[0] && names[type] ? names[type] : "?";
}

/* The holding registers of a located variable: 0 when it has none. */
static unsigned located_registers(const plc_located_t *l, unsigned *first)
{
    if (l->index >= MAP_WORDS)
        return 0;
    if (l->size == 'W' && l->area == 'Q') {
        *first = MAP_HOLD_QW + l->index;
        return 1;
    }
    if (l->area != 'M')
        return 0;
    switch (l->size) {
    case 'W': *first = MAP_HOLD_MW + l->index; return 1;
    case 'D': *first = MAP_HOLD_MD + 2 * l->index; return 2;
    case 'L': *first = MAP_HOLD_ML + 4 * l->index; return 4;
    default: return 0;
    }
}

static void register_name(char *out, size_t n, unsigned a)
{
    if (a < MAP_HOLD_MW)
        snprintf(out, n, "%%QW%u", a);
    else if (a < MAP_HOLD_MD)
        snprintf(out, n, "%%MW%u", a - MAP_HOLD_MW);
    else
        snprintf(out, n, "HR%u", a);
}

/* The retained holding registers: --retain-registers and the located RETAIN variables'. */
static void retained_registers(const runtime_t *rt, addr_set_t *set, log_sink_t *log)
{
    const plc_program_t *prog = rt->prog;

    *set = rt->opt.retain_registers;
    for (uint32_t i = 0; i < prog->n_located; i++) {
        const plc_located_t *l = &prog->located[i];
        unsigned first, n;
        if (!l->retain)
            continue;
        n = located_registers(l, &first);
        if (n == 0) {
            if (log)
                log_msg(log, LOG_WARN, "retain: %s AT %s is declared RETAIN, but only holding registers (%%QW "
                        "%%MW %%MD %%ML) are kept: it starts from its initial value after a restart", l->var,
                        l->address);
            continue;
        }
        for (unsigned k = 0; k < n; k++)
            addr_set_add(set, first + k);
    }
}

/* The located variable whose registers start at a and are all retained, or NULL. */
static const plc_located_t *located_at(const plc_program_t *prog, const addr_set_t *set, unsigned a,
                                       unsigned *n)
{
    for (uint32_t i = 0; i < prog->n_located; i++) {
        const plc_located_t *l = &prog->located[i];
        unsigned first, count = located_registers(l, &first);
        if (count == 0 || first != a || a + count > MAP_HOLDING)
            continue;
        bool all = true;
        for (unsigned k = 0; k < count; k++)
            all = all && addr_set_has(set, a + k);
        if (all) {
            *n = count;
            return l;
        }
    }
    return NULL;
}

/* This program's entries, in payload order: variables in table order, then
 * registers ascending (the order of format version 1). */
static int build_entries(const runtime_t *rt, log_sink_t *log, retain_entry_t **out, size_t *count,
                         size_t *size)
{
    const plc_program_t *prog = rt->prog;
    addr_set_t set;
    size_t n = 0, at = 0;
    retain_entry_t *e;

    retained_registers(rt, &set, log);
    for (uint32_t i = 0; i < prog->n_vars; i++)
        n += is_retained(&prog->vars[i]);
    for (unsigned a = 0; a < MAP_HOLDING; a++)
        n += addr_set_has(&set, a);              /* an upper bound: a located entry takes several */
    e = calloc(n ? n : 1, sizeof *e);
    if (!e)
        return -1;
    n = 0;
    for (uint32_t i = 0; i < prog->n_vars; i++) {
        const plc_var_t *v = &prog->vars[i];
        if (!is_retained(v))
            continue;
        e[n].path = v->path;
        e[n].type = v->type_name ? v->type_name : plc_type_name(v->type);
        e[n].addr = v->addr;
        e[n].size = v->size;
        e[n].offset = at;
        at += v->size;
        n++;
    }
    for (unsigned a = 0; a < MAP_HOLDING; a++) {
        if (!addr_set_has(&set, a))
            continue;
        unsigned regs = 1;
        const plc_located_t *l = located_at(prog, &set, a, &regs);
        retain_entry_t *r = &e[n++];
        register_name(r->name, sizeof r->name, a);
        if (l) {
            r->path = l->var;
            r->type = plc_type_name(l->type);
            snprintf(r->where, sizeof r->where, "%s", l->address);
        } else {
            r->path = r->name;
            r->type = "WORD";
            snprintf(r->where, sizeof r->where, "%s", r->name);
        }
        r->reg = a;
        r->nregs = regs;
        r->size = 2 * regs;
        r->offset = at;
        at += r->size;
        a += regs - 1;
    }
    *out = e;
    *count = n;
    *size = at;
    return 0;
}

static size_t entry_head_len(const retain_entry_t *e)
{
    return ENTRY_HEAD + strlen(e->path) + strlen(e->type) + strlen(e->where);
}

static void gather(retain_store_t *rs, uint8_t *out)
{
    for (size_t i = 0; i < rs->n_entries; i++) {
        const retain_entry_t *e = &rs->entries[i];
        uint8_t *p = out + e->offset;
        if (e->addr) {
            memcpy(p, e->addr, e->size);
            continue;
        }
        for (unsigned k = 0; k < e->nregs; k++) {
            uint16_t r = image_prog_holding(&rs->rt->pimg, e->reg + k);
            p[2 * k] = (uint8_t)(r >> 8);
            p[2 * k + 1] = (uint8_t)r;
        }
    }
}

static void apply(retain_store_t *rs, retain_entry_t *e, const uint8_t *value)
{
    if (e->addr) {
        memcpy(e->addr, value, e->size);
    } else {
        for (unsigned k = 0; k < e->nregs; k++)
            image_prog_set_holding(&rs->rt->pimg, e->reg + k, (uint16_t)(value[2 * k] << 8 | value[2 * k + 1]));
    }
    e->restored = true;
}

int retain_describe(runtime_t *rt, FILE *out)
{
    const plc_program_t *prog = rt->prog;
    retain_entry_t *e;
    size_t n, size;

    if (build_entries(rt, NULL, &e, &n, &size) != 0)
        return -1;
    for (size_t i = 0; i < n; i++)
        fprintf(out, "retain\t%s\t%s\t%s\t%u\n", e[i].path, e[i].type, e[i].where[0] ? e[i].where : "-",
                e[i].size);
    for (uint32_t i = 0; i < prog->n_located; i++) {
        const plc_located_t *l = &prog->located[i];
        fprintf(out, "located\t%s\t%s\t%s\t%s\n", l->address, l->var, plc_type_name(l->type),
                l->retain ? "RETAIN" : "-");
    }
    free(e);
    return 0;
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

static bool same(text_ref_t t, const char *s)
{
    return strlen(s) == (size_t)t.n && memcmp(t.p, s, (size_t)t.n) == 0;
}

static text_ref_t text_at(const uint8_t *p, size_t n)
{
    return (text_ref_t){ (const char *)p, (int)n };
}

/* Split the body of a version 2 file into entries; NULL when it is malformed. */
static saved_entry_t *parse_entries(const uint8_t *body, size_t len, uint32_t count, const char **why)
{
    saved_entry_t *out = calloc(count ? count : 1, sizeof *out);
    size_t at = 0;

    if (!out) {
        *why = "out of memory";
        return NULL;
    }
    for (uint32_t i = 0; i < count; i++) {
        saved_entry_t *s = &out[i];
        if (len - at < ENTRY_HEAD)
            goto bad;
        const uint8_t *h = body + at;
        size_t p = get16(h + 2), t = get16(h + 4), w = get16(h + 6);
        uint32_t size = get32(h + 8);
        if (len - at - ENTRY_HEAD < p + t + w || len - at - ENTRY_HEAD - p - t - w < size)
            goto bad;
        const uint8_t *text = h + ENTRY_HEAD;
        if (p == 0 || memchr(text, 0, p + t + w))
            goto bad;
        s->path = text_at(text, p);
        s->type = text_at(text + p, t);
        s->where = text_at(text + p + t, w);
        s->raw = h;
        s->raw_len = ENTRY_HEAD + p + t + w + size;
        s->flags = h[0];
        s->value = text + p + t + w;
        s->size = size;
        at += s->raw_len;
    }
    if (at != len)
        goto bad;
    return out;
bad:
    free(out);
    *why = "malformed entry table: the file is corrupt";
    return NULL;
}

static retain_entry_t *entry_named(retain_store_t *rs, text_ref_t path)
{
    for (size_t i = 0; i < rs->n_entries; i++)
        if (same(path, rs->entries[i].path))
            return &rs->entries[i];
    return NULL;
}

/* Keep a saved entry that matches nothing: it goes into every later save, flagged. */
static void keep_aside(retain_store_t *rs, const saved_entry_t *s)
{
    memcpy(rs->kept + rs->kept_len, s->raw, s->raw_len);
    rs->kept[rs->kept_len] |= ENTRY_KEPT_ASIDE;
    rs->kept_len += s->raw_len;
    rs->n_kept++;
}

static void match_entries(retain_store_t *rs, saved_entry_t *saved, uint32_t n_saved)
{
    log_sink_t *log = rs->rt->log;
    size_t restored = 0, lost = 0, still = 0;

    /* By name and type. */
    for (size_t i = 0; i < rs->n_entries; i++) {
        retain_entry_t *e = &rs->entries[i];
        for (uint32_t k = 0; k < n_saved && !e->restored; k++) {
            saved_entry_t *s = &saved[k];
            if (s->used || s->size != e->size || !same(s->path, e->path) || !same(s->type, e->type))
                continue;
            apply(rs, e, s->value);
            s->used = true;
            restored++;
            if (e->where[0] && !same(s->where, e->where))
                log_msg(log, LOG_INFO, "retain: %s (%s) restored; it moved from %.*s to %s", e->path, e->type,
                        s->where.n ? s->where.n : 6, s->where.n ? s->where.p : "memory", e->where);
        }
    }
    /* A register whose name is gone, by address and type (a renamed signal). */
    for (size_t i = 0; i < rs->n_entries; i++) {
        retain_entry_t *e = &rs->entries[i];
        if (e->restored || !e->where[0])
            continue;
        for (uint32_t k = 0; k < n_saved && !e->restored; k++) {
            saved_entry_t *s = &saved[k];
            if (s->used || s->size != e->size || !same(s->where, e->where) || !same(s->type, e->type)
                || entry_named(rs, s->path))
                continue;
            apply(rs, e, s->value);
            s->used = true;
            restored++;
            log_msg(log, LOG_WARN, "retain: %s (%s) restored by address %s, where %.*s was saved (renamed?)",
                    e->path, e->type, e->where, s->path.n, s->path.p);
        }
    }
    /* The rest of the file is kept aside, each value named. */
    for (uint32_t k = 0; k < n_saved; k++) {
        saved_entry_t *s = &saved[k];
        if (s->used)
            continue;
        keep_aside(rs, s);
        retain_entry_t *e = entry_named(rs, s->path);
        if (s->flags & ENTRY_KEPT_ASIDE) {
            still++;
            log_msg(log, LOG_INFO, "retain: %.*s (%.*s) still kept aside from an earlier program version",
                    s->path.n, s->path.p, s->type.n, s->type.p);
        } else if (e && e->restored) {
            /* Back to an earlier version: e came from a value kept aside, the newer version's value goes aside. */
            lost++;
            log_msg(log, LOG_WARN, "retain: %s changed type from %.*s to %s: its %s value kept aside earlier is "
                    "restored and the %.*s value is kept aside in the file", e->path, s->type.n, s->type.p,
                    e->type, e->type, s->type.n, s->type.p);
        } else if (e) {
            lost++;
            e->announced = true;
            log_msg(log, LOG_WARN, "retain: %s changed type from %.*s to %s: its saved value is kept aside in "
                    "the file and %s starts from its initial value", e->path, s->type.n, s->type.p, e->type,
                    e->path);
        } else {
            lost++;
            log_msg(log, LOG_WARN, "retain: %.*s (%.*s%s%.*s) is not retained by this program: its saved value "
                    "is kept aside in the file", s->path.n, s->path.p, s->type.n, s->type.p,
                    s->where.n ? " at " : "", s->where.n, s->where.p);
        }
    }
    for (size_t i = 0; i < rs->n_entries; i++) {
        const retain_entry_t *e = &rs->entries[i];
        if (!e->restored && !e->announced)
            log_msg(log, LOG_INFO, "retain: %s (%s) has no saved value: it starts from its initial value",
                    e->path, e->type);
    }
    if (restored)
        rs->rt->flags |= DIAG_FLAG_RETAIN_RESTORED;
    if (lost)
        rs->rt->flags |= DIAG_FLAG_RETAIN_KEPT_ASIDE;
    log_msg(log, lost ? LOG_WARN : LOG_INFO, "retain: restored %zu of %zu values from %s (%zu new, %zu kept "
            "aside now, %zu from earlier versions)", restored, rs->n_entries, rs->path, rs->n_entries - restored,
            lost, still);
}

/* Format version 1: the values of all entries in one block, accepted only
 * when the saving program had exactly this retained layout. */
static const char *restore_block(retain_store_t *rs, const uint8_t *buf, size_t len)
{
    const plc_program_t *prog = rs->rt->prog;
    uint8_t word[4];
    uint32_t h = 0;

    if (len != RETAIN_HEADER + rs->size + RETAIN_TRAILER || get32(buf + 24) != rs->size)
        return "format version 1 file of a different size: saved by a different program";
    if (crc32_update(0, buf, len - RETAIN_TRAILER) != get32(buf + len - RETAIN_TRAILER))
        return "CRC mismatch: the file is corrupt";
    put32(word, prog->layout_hash);
    h = crc32_update(h, word, 4);
    for (size_t i = 0; i < rs->n_entries; i++) {
        const retain_entry_t *e = &rs->entries[i];
        if (e->addr) {
            h = crc32_update(h, e->path, strlen(e->path) + 1);
            for (uint32_t v = 0; v < prog->n_vars; v++)
                if (prog->vars[v].path == e->path)
                    put32(word, prog->vars[v].type);
            h = crc32_update(h, word, 4);
            put32(word, e->size);
            h = crc32_update(h, word, 4);
            continue;
        }
        for (unsigned k = 0; k < e->nregs; k++) {
            put32(word, e->reg + k);
            h = crc32_update(h, word, 4);
        }
    }
    if (get32(buf + 12) != h)
        return "format version 1 file saved by a different program";
    for (size_t i = 0; i < rs->n_entries; i++)
        apply(rs, &rs->entries[i], buf + RETAIN_HEADER + rs->entries[i].offset);
    rs->rt->flags |= DIAG_FLAG_RETAIN_RESTORED;
    log_msg(rs->rt->log, LOG_INFO, "retain: restored %zu values from %s (format version 1; saved as version 2 "
            "from now on)", rs->n_entries, rs->path);
    return NULL;
}

static const char *read_file(retain_store_t *rs, uint8_t **out, size_t *len, char *why, size_t whylen)
{
    struct stat st;
    int fd = open(rs->path, O_RDONLY | O_CLOEXEC);

    *out = NULL;
    if (fd < 0) {
        snprintf(why, whylen, "%s", strerror(errno));
        return why;
    }
    if (fstat(fd, &st) != 0 || st.st_size < (off_t)(RETAIN_HEADER + RETAIN_TRAILER) || st.st_size > (1 << 28)) {
        snprintf(why, whylen, "size %lld bytes, not a retain file of this runtime", (long long)st.st_size);
        close(fd);
        return why;
    }
    uint8_t *buf = malloc((size_t)st.st_size);
    size_t got = 0;
    while (buf && got < (size_t)st.st_size) {
        ssize_t n = read(fd, buf + got, (size_t)st.st_size - got);
        if (n <= 0)
            break;
        got += (size_t)n;
    }
    close(fd);
    if (!buf || got != (size_t)st.st_size) {
        snprintf(why, whylen, "%s", buf ? "short read" : "out of memory");
        free(buf);
        return why;
    }
    *out = buf;
    *len = got;
    return NULL;
}

static void restore(retain_store_t *rs)
{
    uint8_t *buf;
    size_t len;
    char reason[96];
    const char *why;

    if (access(rs->path, F_OK) != 0 && errno == ENOENT) {
        log_msg(rs->rt->log, LOG_INFO, "retain: %s does not exist yet; RETAIN variables start from their "
                "initial values", rs->path);
        return;
    }
    why = read_file(rs, &buf, &len, reason, sizeof reason);
    if (!why && memcmp(buf, RETAIN_MAGIC, 8) != 0)
        why = "not a retain file";
    else if (!why && get32(buf + 8) == RETAIN_VERSION_BLOCK)
        why = restore_block(rs, buf, len);
    else if (!why && get32(buf + 8) != RETAIN_VERSION)
        why = "unknown format version";
    else if (!why && (get32(buf + 24) != len - RETAIN_HEADER - RETAIN_TRAILER))
        why = "body length differs from the file size: the file is truncated or corrupt";
    else if (!why && crc32_update(0, buf, len - RETAIN_TRAILER) != get32(buf + len - RETAIN_TRAILER))
        why = "CRC mismatch: the file is corrupt";
    else if (!why) {
        const uint32_t count = get32(buf + 12);
        const size_t body = len - RETAIN_HEADER - RETAIN_TRAILER;
        saved_entry_t *saved = NULL;
        if (count > body / ENTRY_HEAD)
            why = "entry count larger than the file: the file is corrupt";
        else
            saved = parse_entries(buf + RETAIN_HEADER, body, count, &why);
        if (saved) {
            rs->kept = malloc(len);
            if (!rs->kept)
                why = "out of memory";
            else
                match_entries(rs, saved, count);
            free(saved);
        }
    }
    free(buf);
    if (why)
        reject(rs, why);
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

/* The whole file for the payload in rs->values: entries, kept-aside entries, CRC. */
static void compose(retain_store_t *rs, uint64_t generation)
{
    uint8_t *f = rs->file_buf;
    size_t at = RETAIN_HEADER;

    for (size_t i = 0; i < rs->n_entries; i++) {
        const retain_entry_t *e = &rs->entries[i];
        size_t p = strlen(e->path), t = strlen(e->type), w = strlen(e->where);
        f[at] = 0;
        f[at + 1] = 0;
        put16(f + at + 2, (uint16_t)p);
        put16(f + at + 4, (uint16_t)t);
        put16(f + at + 6, (uint16_t)w);
        put32(f + at + 8, e->size);
        at += ENTRY_HEAD;
        memcpy(f + at, e->path, p);
        memcpy(f + at + p, e->type, t);
        memcpy(f + at + p + t, e->where, w);
        at += p + t + w;
        memcpy(f + at, rs->values + e->offset, e->size);
        at += e->size;
    }
    if (rs->kept_len)
        memcpy(f + at, rs->kept, rs->kept_len);
    at += rs->kept_len;
    memcpy(f, RETAIN_MAGIC, 8);
    put32(f + 8, RETAIN_VERSION);
    put32(f + 12, (uint32_t)(rs->n_entries + rs->n_kept));
    put32(f + 16, (uint32_t)generation);
    put32(f + 20, (uint32_t)(generation >> 32));
    put32(f + 24, (uint32_t)(at - RETAIN_HEADER));
    put32(f + at, crc32_update(0, f, at));
}

static int save_file(retain_store_t *rs, uint64_t generation)
{
    const char *step = "open";
    int fd;

    compose(rs, generation);
    fd = open(rs->tmp_path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0)
        goto fail;
    step = "write";
    if (write_all(fd, rs->file_buf, rs->file_size) != 0) {
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

    rt_thread_name("retain-writer");
    for (;;) {
        pthread_mutex_lock(&rs->mu);
        const bool full = rs->outbox_full, stopping = rs->stopping;
        const uint64_t generation = rs->generation;
        if (full) {
            memcpy(rs->values, rs->outbox, rs->size);
            rs->outbox_full = false;
        }
        pthread_mutex_unlock(&rs->mu);
        if (full)
            save_file(rs, generation);
        else if (stopping)
            break;                                 /* nothing left */
        else
            rt_wake_wait(&rs->wake, RT_WAKE_NEVER);
    }
    return NULL;
}

/* ------------------------------------------------------------- interface */

static void free_store(retain_store_t *rs)
{
    unlock_store(rs);
    free(rs->entries);
    free(rs->kept);
    free(rs->gather);
    free(rs->seen);
    free(rs->outbox);
    free(rs->values);
    free(rs->file_buf);
    free(rs);
}

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
    rs->lock_fd = -1;
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
    if (lock_store(rs) != 0) {
        free(rs);
        return -1;
    }
    if (build_entries(rt, rt->log, &rs->entries, &rs->n_entries, &rs->size) != 0) {
        unlock_store(rs);
        free(rs);
        return -1;
    }
    if (rs->n_entries == 0) {
        log_msg(rt->log, LOG_INFO, "retain: the program has no RETAIN data; %s stays as it is", rs->path);
        free_store(rs);
        return 0;
    }
    for (size_t i = 0; i < rs->n_entries; i++)
        if (strlen(rs->entries[i].path) > UINT16_MAX || strlen(rs->entries[i].type) > UINT16_MAX) {
            log_msg(rt->log, LOG_ERROR, "retain: %s: name or type too long", rs->entries[i].path);
            free_store(rs);
            return -1;
        }

    restore(rs);

    rs->file_size = RETAIN_HEADER + rs->kept_len + RETAIN_TRAILER;
    for (size_t i = 0; i < rs->n_entries; i++)
        rs->file_size += entry_head_len(&rs->entries[i]) + rs->entries[i].size;
    rs->gather = calloc(1, rs->size);
    rs->seen = calloc(1, rs->size);
    rs->outbox = calloc(1, rs->size);
    rs->values = calloc(1, rs->size);
    rs->file_buf = calloc(1, rs->file_size);
    if (!rs->gather || !rs->seen || !rs->outbox || !rs->values || !rs->file_buf) {
        free_store(rs);
        return -1;
    }
    gather(rs, rs->seen);
    rs->dirty = true;            /* the first save after start writes this program's layout */
    rt_mutex_init(&rs->mu);
    rt_wake_init(&rs->wake);
    if (pthread_create(&rs->writer, NULL, writer_thread, rs) != 0) {
        log_msg(rt->log, LOG_ERROR, "retain: cannot start the writer thread");
        pthread_mutex_destroy(&rs->mu);
        rt_wake_destroy(&rs->wake);
        free_store(rs);
        return -1;
    }
    log_msg(rt->log, LOG_INFO, "retain: %zu values (%zu bytes) retained, saved to %s at most every %d ms and at "
            "shutdown", rs->n_entries, rs->size, rs->path, rt->opt.retain_interval_ms);
    *out = rs;
    return 0;
}

void retain_capture(runtime_t *rt)
{
    retain_store_t *rs = rt->retain;

    if (!rs)
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

    if (!rs)
        return;
    retain_capture(rt);
    if (!rs->dirty)
        return;
    if (rs->handed_once && now - rs->last_handoff_ns < (uint64_t)rt->opt.retain_interval_ms * 1000000u)
        return;
    /* Never wait for the writer: if it is busy, try again next scan. */
    if (pthread_mutex_trylock(&rs->mu) != 0)
        return;
    const bool hand = !rs->outbox_full;
    if (hand) {
        memcpy(rs->outbox, rs->seen, rs->size);
        rs->outbox_full = true;
        rs->generation++;
        rs->dirty = false;
        rs->last_handoff_ns = now;
        rs->handed_once = true;
    }
    pthread_mutex_unlock(&rs->mu);
    if (hand)
        rt_wake(&rs->wake);
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
    pthread_mutex_unlock(&rs->mu);
    rt_wake(&rs->wake);
    pthread_join(rs->writer, NULL);
    log_msg(rt->log, LOG_INFO, "retain: %s up to date (%u saves this run%s)", rs->path,
            atomic_load(&rs->saves), atomic_load(&rs->last_failed) ? ", the last one FAILED" : "");
    pthread_mutex_destroy(&rs->mu);
    rt_wake_destroy(&rs->wake);
    free_store(rs);
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
