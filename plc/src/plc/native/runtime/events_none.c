/*
 * events_none.c - the runtime without application events.
 *
 * An application can tell on the log what its program does (a tool change
 * requested and done, a fault raised) and add to the status line: it links
 * its own implementation of the four functions of monitor.h's events section
 * into the runtime in place of this file (`plc run` of an application's
 * project does so; plc.runtime.build_runtime(observer=...)), and reads the
 * signals it watches from the description `--events FILE` names.  Without
 * one, the runtime tells nothing of the program and --events is ignored.
 */
#include "monitor.h"

int events_open(runtime_t *rt, const char *path, events_t **out)
{
    *out = NULL;
    if (path)
        log_msg(rt->log, LOG_INFO, "events: %s ignored: this runtime was built without application events", path);
    return 0;
}

void events_close(events_t *ev)
{
    (void)ev;
}

void events_after_scan(events_t *ev, runtime_t *rt, uint64_t now)
{
    (void)ev;
    (void)rt;
    (void)now;
}

int events_fault(events_t *ev)
{
    (void)ev;
    return 0;
}

void events_status(events_t *ev, char *out, size_t n)
{
    (void)ev;
    if (n)
        out[0] = 0;
}
