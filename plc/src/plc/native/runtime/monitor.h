/*
 * monitor.h - watching and forcing the running program, and the
 * application's events.
 *
 *   varpath.c   a variable path ("ATC.MACHINE.RUNNER.STEPS[3].LINE",
 *               "%IX0.0") resolved to storage through the program's variable
 *               and located tables; struct fields and array elements are
 *               laid out from the table's full type names (C layout rules,
 *               checked against the sizes the generated code reports)
 *   force.c     write once and force with PLC semantics, applied by the
 *               scan thread at two points of the scan (after the inputs,
 *               before the outputs); snapshots taken at the end of a scan
 *   monitor.c   the monitoring channel: a Unix socket, its own thread, a
 *               line protocol answered in JSON, a token for writes, an
 *               audit log
 *   events      the application's events: what its program does, told on
 *               the log and the status line.  An application links its own
 *               implementation of the four functions below (the tool
 *               changer's is plc/src/atc/native/events.c); events_none.c,
 *               the default, tells nothing
 *
 * The scan thread calls exactly three functions, one line each:
 * monitor_after_inputs(), monitor_before_outputs(), monitor_scan_done().
 * None of them blocks: every hand-over with the monitor thread is a trylock.
 */
#ifndef PLC_MONITOR_H
#define PLC_MONITOR_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "runtime.h"

/* ---------------------------------------------------------------- hooks */

void monitor_after_inputs(runtime_t *rt);    /* inputs latched, host writes applied: forces, writes */
void monitor_before_outputs(runtime_t *rt);  /* program ran: forced outputs held before publication */
void monitor_scan_done(runtime_t *rt);       /* image published: snapshots, events */

/* ------------------------------------------------------------- varpath */

#define VP_PATH_MAX 256
#define VP_VALUE_MAX 128      /* the largest elementary value (STRING) */

typedef struct var_ref {
    void *addr;
    uint32_t size;
    uint16_t type;            /* plc_type_t; PLC_T_OTHER: aggregate (type_name tells) */
    bool constant;
    bool located;
    char area;                /* located: 'I', 'Q', 'M' */
    const char *type_name;    /* full type at this point (into the table's string); may be NULL for located */
    size_t type_len;          /* length of type_name's part that describes this value */
    char path[VP_PATH_MAX];   /* canonical path */
} var_ref_t;

/* Resolve `path` (case-insensitive; a unique suffix of a full path will do,
 * and %IX0.0-style addresses name located variables).  Returns 0, or -1 with
 * a sentence in err. */
int varpath_resolve(const plc_program_t *prog, const char *path, var_ref_t *out, char *err, size_t errlen);

/* Parse text as a value of ref's elementary type into buf (ref->size bytes).
 * Returns 0, or -1 with a sentence in err. */
int varpath_parse_value(const var_ref_t *ref, const char *text, uint8_t *buf, char *err, size_t errlen);

/* Append the JSON form of the value in data (ref's layout) to out; aggregates
 * become arrays and objects.  Returns the number of characters written
 * (truncated output is never half a token: returns -1 when it does not fit). */
int varpath_format_json(const var_ref_t *ref, const uint8_t *data, char *out, size_t n);

/* ------------------------------------------------------------- force.c */

#define FORCE_MAX 64
#define SNAP_MAX_ITEMS 512
#define SNAP_MAX_BYTES (64 * 1024)

typedef enum force_op {
    FORCE_OP_WRITE = 1,       /* write once, before the program runs */
    FORCE_OP_FORCE,           /* hold the value after inputs and before outputs */
    FORCE_OP_UNFORCE_KEEP,    /* stop holding; the variable keeps its value */
    FORCE_OP_UNFORCE_RESTORE, /* stop holding; the value from before the force comes back */
    FORCE_OP_UNFORCE_ALL      /* every force ended, kept */
} force_op_t;

typedef struct force_entry {
    void *addr;
    uint32_t size;
    uint8_t value[VP_VALUE_MAX];
    uint8_t saved[VP_VALUE_MAX];   /* the value when the force began (unforce and restore) */
    uint64_t since_scan;
    char path[VP_PATH_MAX];
    char text[64];                 /* the value as the user wrote it */
} force_entry_t;

typedef struct force_state force_state_t;

force_state_t *force_create(void);
void force_destroy(force_state_t *fs);
/* Monitor thread: hand one operation to the scan thread and wait until it
 * was applied (at most timeout_ms).  Returns 0 with *scan the scan it took
 * effect on; -1 with err (not applied: nothing reached the program). */
int force_request(force_state_t *fs, force_op_t op, const var_ref_t *ref, const uint8_t *value, const char *text,
                  int timeout_ms, uint64_t *scan, char *err, size_t errlen);
/* Monitor thread: a copy of the active forces (the scan thread's table as of
 * the last request).  Returns their number. */
unsigned force_list(force_state_t *fs, force_entry_t *out, unsigned max);
/* Monitor thread: copy the items (addr, size) at the end of one scan into
 * data (consecutive); wait at most timeout_ms.  Returns 0 with *scan, or -1. */
typedef struct snap_item { void *addr; uint32_t size; } snap_item_t;
int force_snapshot(force_state_t *fs, const snap_item_t *items, unsigned n, uint8_t *data, int timeout_ms,
                   uint64_t *scan);
/* Scan thread. */
void force_after_inputs(force_state_t *fs, uint64_t scan);
void force_before_outputs(force_state_t *fs);
void force_scan_done(force_state_t *fs, uint64_t scan);
/* Number of active forces (scan thread only). */
unsigned force_count(const force_state_t *fs);

/* ----------------------------------------------------------- monitor.c */

typedef struct monitor monitor_t;
int monitor_start(runtime_t *rt, monitor_t **out);      /* after the first image is published */
void monitor_stop(monitor_t *m);

/* ----------------------------------- application events (events_none.c) */

typedef struct events events_t;
int events_open(runtime_t *rt, const char *path, events_t **out);   /* NULL path: nothing to tell */
void events_close(events_t *ev);
void events_after_scan(events_t *ev, runtime_t *rt, uint64_t now);  /* scan thread */
/* The application's part of the status line (log thread); "" when none. */
void events_status(events_t *ev, char *out, size_t n);
/* The application's latched fault code now, 0 = none (also with ev NULL): the diagnostic block carries it
 * (DIAG_APP_FAULT) so that `plc status` reports it and exits 1. Any thread. */
int events_fault(events_t *ev);

#endif /* PLC_MONITOR_H */
