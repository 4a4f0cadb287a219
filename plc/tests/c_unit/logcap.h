/*
 * logcap.h - the runtime's log_msg() for unit tests: instead of log.c's ring
 * and thread, every line is kept in memory (any thread may log) so that a case
 * can check what the runtime said.  Lines look like log.c's without the time
 * stamp: "warning: retain: ...", "error: ...", info lines bare.
 * LOGCAP_SHOW=1 in the environment also prints them on stderr.
 */
#ifndef C_UNIT_LOGCAP_H
#define C_UNIT_LOGCAP_H

#include <stddef.h>

#include "runtime.h"

/* A log sink to give the runtime's parts (some log only when they have one); log_msg() ignores which. */
log_sink_t *logcap_sink(void);
void logcap_clear(void);
/* A copy of every line logged since the last clear, '\n'-terminated; valid until the next call. */
const char *logcap_text(void);
/* How many lines logged since the last clear contain part. */
unsigned logcap_count(const char *part);

#endif /* C_UNIT_LOGCAP_H */
