/*
 * io_wrap.h - the file calls of retain.c's saves, seen and failed on demand.
 *
 * test_retain links with -Wl,--wrap=fsync,--wrap=rename: every fsync() and
 * rename() retain.c makes comes here first, is recorded (which file, which
 * directory, from where to where) and then done, or failed with the errno a
 * case asks for.  Any thread may call them (the retain writer does).
 */
#ifndef C_UNIT_IO_WRAP_H
#define C_UNIT_IO_WRAP_H

#include <limits.h>
#include <stdbool.h>

typedef enum io_call { IO_FSYNC_FILE, IO_FSYNC_DIR, IO_RENAME, IO_CALLS } io_call_t;

typedef struct io_event {
    io_call_t call;
    char path[PATH_MAX];          /* the file or directory synced, the file renamed */
    char to[PATH_MAX];            /* rename's target */
} io_event_t;

/* Forget what was recorded; stop failing. */
void io_reset(void);
/* Copy up to max recorded calls in order; returns how many were recorded. */
unsigned io_events(io_event_t *out, unsigned max);
/* How many calls of this kind were recorded. */
unsigned io_count(io_call_t call);
/* Fail every later call of this kind with err (0: do it again) until io_reset(). */
void io_fail(io_call_t call, int err);
/* fsync() returns 0 at once (loops that save hundreds of times on a loaded disk). */
void io_skip_sync(bool skip);

#endif /* C_UNIT_IO_WRAP_H */
