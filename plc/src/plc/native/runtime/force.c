/*
 * force.c - write once, force, and snapshots, between the monitor thread and
 * the scan thread.
 *
 * PLC semantics (docs/monitoring.md): a write sets a value once, before the
 * program runs; a force holds a value: it is laid on the variable after the
 * inputs are read (and host writes applied) and again before the outputs are
 * published, so a forced input is what the program sees and a forced output
 * is what leaves the PLC, whatever the program assigned in between.  Ending a
 * force keeps the present value, or restores the one from before the force.
 * Forces live in memory only: a restart has none.
 *
 * The force table belongs to the scan thread.  The monitor thread hands it
 * one operation at a time in a mailbox guarded by a mutex that the scan
 * thread only ever trylocks: when the monitor holds it, the operation simply
 * waits for the next scan.  The scan tells the monitor that an operation or
 * a snapshot is done with rt_wake(), which never blocks (a condition
 * variable's signal could wait for the SCHED_OTHER monitor thread).  The monitor keeps a copy of the table, refreshed
 * whenever an operation completes, to list the forces without touching the
 * scan thread's.  Snapshots take the same road the other way: the monitor
 * names the items, the scan thread copies them at the end of one scan.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "monitor.h"

struct force_state {
    /* scan thread only */
    force_entry_t table[FORCE_MAX];
    unsigned n;

    pthread_mutex_t mu;            /* the mailbox and the snapshot request; trylocked by the scan thread */
    rt_wake_t done;                /* the scan thread: an operation or a snapshot is done */
    atomic_bool op_pending;        /* an operation waits in the mailbox */
    atomic_bool snap_pending;      /* a snapshot waits to be taken */

    /* mailbox */
    force_op_t op;
    force_entry_t arg;
    bool op_done;
    int op_result;                 /* 0, or -1 with op_err */
    char op_err[2 * VP_PATH_MAX + 64];
    uint64_t op_scan;
    force_entry_t copy[FORCE_MAX]; /* the table after the last operation */
    unsigned n_copy;

    /* snapshot */
    const snap_item_t *items;
    unsigned n_items;
    uint8_t *data;
    bool snap_done;
    uint64_t snap_scan;
};

force_state_t *force_create(void)
{
    force_state_t *fs = calloc(1, sizeof *fs);

    if (!fs)
        return NULL;
    rt_mutex_init(&fs->mu);
    rt_wake_init(&fs->done);
    return fs;
}

void force_destroy(force_state_t *fs)
{
    if (!fs)
        return;
    pthread_mutex_destroy(&fs->mu);
    rt_wake_destroy(&fs->done);
    free(fs);
}

/* Called with fs->mu held; returns with it held, once *done is true or the monotonic time `until` has passed. */
static void wait_done(force_state_t *fs, const bool *done, uint64_t until)
{
    while (!*done && now_ns() < until) {
        pthread_mutex_unlock(&fs->mu);
        rt_wake_wait(&fs->done, until);
        pthread_mutex_lock(&fs->mu);
    }
}

/* ------------------------------------------------------- monitor side */

int force_request(force_state_t *fs, force_op_t op, const var_ref_t *ref, const uint8_t *value, const char *text,
                  int timeout_ms, uint64_t *scan, char *err, size_t errlen)
{
    const uint64_t until = now_ns() + (uint64_t)timeout_ms * 1000000u;

    pthread_mutex_lock(&fs->mu);
    memset(&fs->arg, 0, sizeof fs->arg);
    fs->op = op;
    if (ref) {
        fs->arg.addr = ref->addr;
        fs->arg.size = ref->size;
        snprintf(fs->arg.path, sizeof fs->arg.path, "%s", ref->path);
    }
    if (value && ref)
        memcpy(fs->arg.value, value, ref->size);
    snprintf(fs->arg.text, sizeof fs->arg.text, "%s", text ? text : "");
    fs->op_done = false;
    atomic_store(&fs->op_pending, true);
    wait_done(fs, &fs->op_done, until);
    if (!fs->op_done) {
        /* Withdrawn under the lock: the scan thread can no longer take it. */
        atomic_store(&fs->op_pending, false);
        pthread_mutex_unlock(&fs->mu);
        snprintf(err, errlen, "the scan did not take the request within %d ms (is the PLC scanning?): not applied",
                 timeout_ms);
        return -1;
    }
    int result = fs->op_result;
    if (result != 0)
        snprintf(err, errlen, "%s", fs->op_err);
    *scan = fs->op_scan;
    pthread_mutex_unlock(&fs->mu);
    return result;
}

unsigned force_list(force_state_t *fs, force_entry_t *out, unsigned max)
{
    pthread_mutex_lock(&fs->mu);
    unsigned n = fs->n_copy < max ? fs->n_copy : max;
    memcpy(out, fs->copy, n * sizeof *out);
    pthread_mutex_unlock(&fs->mu);
    return n;
}

int force_snapshot(force_state_t *fs, const snap_item_t *items, unsigned n, uint8_t *data, int timeout_ms,
                   uint64_t *scan)
{
    const uint64_t until = now_ns() + (uint64_t)timeout_ms * 1000000u;

    pthread_mutex_lock(&fs->mu);
    fs->items = items;
    fs->n_items = n;
    fs->data = data;
    fs->snap_done = false;
    atomic_store(&fs->snap_pending, true);
    wait_done(fs, &fs->snap_done, until);
    bool done = fs->snap_done;
    atomic_store(&fs->snap_pending, false);
    fs->items = NULL;
    fs->data = NULL;
    *scan = fs->snap_scan;
    pthread_mutex_unlock(&fs->mu);
    return done ? 0 : -1;
}

/* --------------------------------------------------------- scan side */

static int find(const force_state_t *fs, const void *addr)
{
    for (unsigned i = 0; i < fs->n; i++)
        if (fs->table[i].addr == addr)
            return (int)i;
    return -1;
}

static bool overlaps(const force_entry_t *a, const force_entry_t *b)
{
    const uint8_t *a0 = a->addr, *b0 = b->addr;
    return a0 < b0 + b->size && b0 < a0 + a->size && a0 != b0;
}

/* Caller holds fs->mu.  Sets op_result/op_err. */
static void take_op(force_state_t *fs, uint64_t scan)
{
    force_entry_t *a = &fs->arg;
    int i = find(fs, a->addr);

    fs->op_result = 0;
    switch (fs->op) {
    case FORCE_OP_WRITE:
        memcpy(a->addr, a->value, a->size);
        if (i >= 0)     /* a forced variable keeps its force; the write shows until the force lays it back */
            snprintf(fs->op_err, sizeof fs->op_err, "forced");
        break;
    case FORCE_OP_FORCE:
        for (unsigned k = 0; k < fs->n; k++)
            if (overlaps(&fs->table[k], a)) {
                fs->op_result = -1;
                snprintf(fs->op_err, sizeof fs->op_err, "%s overlaps the forced %s: unforce that first",
                         a->path, fs->table[k].path);
                return;
            }
        if (i >= 0) {                     /* a new value for a force: the saved value stays the first one */
            memcpy(fs->table[i].value, a->value, a->size);
            snprintf(fs->table[i].text, sizeof fs->table[i].text, "%s", a->text);
        } else if (fs->n >= FORCE_MAX) {
            fs->op_result = -1;
            snprintf(fs->op_err, sizeof fs->op_err, "at most %d forces at a time", FORCE_MAX);
            return;
        } else {
            force_entry_t *e = &fs->table[fs->n++];
            *e = *a;
            memcpy(e->saved, a->addr, a->size);
            e->since_scan = scan;
        }
        memcpy(a->addr, a->value, a->size);
        break;
    case FORCE_OP_UNFORCE_KEEP:
    case FORCE_OP_UNFORCE_RESTORE:
        if (i < 0) {
            fs->op_result = -1;
            snprintf(fs->op_err, sizeof fs->op_err, "%s is not forced", a->path);
            return;
        }
        if (fs->op == FORCE_OP_UNFORCE_RESTORE)
            memcpy(fs->table[i].addr, fs->table[i].saved, fs->table[i].size);
        fs->table[i] = fs->table[--fs->n];
        break;
    case FORCE_OP_UNFORCE_ALL:
        fs->n = 0;
        break;
    }
}

void force_after_inputs(force_state_t *fs, uint64_t scan)
{
    if (atomic_load(&fs->op_pending) && pthread_mutex_trylock(&fs->mu) == 0) {
        if (atomic_load(&fs->op_pending)) {
            take_op(fs, scan);
            fs->op_scan = scan;
            memcpy(fs->copy, fs->table, fs->n * sizeof fs->table[0]);
            fs->n_copy = fs->n;
            fs->op_done = true;
            atomic_store(&fs->op_pending, false);
        }
        pthread_mutex_unlock(&fs->mu);
        rt_wake(&fs->done);
    }
    for (unsigned i = 0; i < fs->n; i++)
        memcpy(fs->table[i].addr, fs->table[i].value, fs->table[i].size);
}

unsigned force_count(const force_state_t *fs)
{
    return fs->n;
}

void force_before_outputs(force_state_t *fs)
{
    for (unsigned i = 0; i < fs->n; i++)
        memcpy(fs->table[i].addr, fs->table[i].value, fs->table[i].size);
}

void force_scan_done(force_state_t *fs, uint64_t scan)
{
    if (!atomic_load(&fs->snap_pending) || pthread_mutex_trylock(&fs->mu) != 0)
        return;
    if (atomic_load(&fs->snap_pending) && fs->data) {
        size_t off = 0;
        for (unsigned i = 0; i < fs->n_items; i++) {
            memcpy(fs->data + off, fs->items[i].addr, fs->items[i].size);
            off += fs->items[i].size;
        }
        fs->snap_scan = scan;
        fs->snap_done = true;
        atomic_store(&fs->snap_pending, false);
    }
    pthread_mutex_unlock(&fs->mu);
    rt_wake(&fs->done);
}
