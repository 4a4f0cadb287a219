/*
 * notify.c - the service manager's notify protocol (systemd, sd_notify(3)),
 * spoken directly: one datagram per message to the AF_UNIX socket named by
 * $NOTIFY_SOCKET ("@name" for the abstract namespace).
 *
 * The scan thread says READY=1 after the first scan, then WATCHDOG=1 every
 * quarter of $WATCHDOG_USEC as long as its scans complete: a program stuck in
 * run() stops the pings, and the service manager restarts the runtime after
 * WatchdogSec (the runtime's own watchdog has made the outputs safe by then).
 * A program that faulted is a stable, safe and reported state: the pings go
 * on and STATUS= says why the program stopped.  STOPPING=1 at shutdown.
 *
 * Sending never blocks (MSG_DONTWAIT): a full or absent socket loses a
 * message, never a scan.  Without $NOTIFY_SOCKET every call does nothing.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include "runtime.h"

struct notifier {
    runtime_t *rt;
    int fd;
    struct sockaddr_un addr;
    socklen_t addr_len;
    uint64_t ping_every_ns;       /* 0: no watchdog asked for */
    uint64_t last_ping_ns;
    bool ready_sent;
    plc_state_t last_state;
    bool failing;
};

int notify_open(runtime_t *rt, notifier_t **out)
{
    const char *path = getenv("NOTIFY_SOCKET");
    const char *usec = getenv("WATCHDOG_USEC");
    const char *pid = getenv("WATCHDOG_PID");
    notifier_t *n;
    size_t len;

    *out = NULL;
    if (!path || !*path)
        return 0;
    len = strlen(path);
    if ((path[0] != '/' && path[0] != '@') || len >= sizeof n->addr.sun_path) {
        log_msg(rt->log, LOG_WARN, "notify: NOTIFY_SOCKET '%s' is not a socket path: no notifications", path);
        return 0;
    }
    n = calloc(1, sizeof *n);
    if (!n)
        return -1;
    n->rt = rt;
    n->addr.sun_family = AF_UNIX;
    memcpy(n->addr.sun_path, path, len);
    if (path[0] == '@')
        n->addr.sun_path[0] = 0;
    n->addr_len = (socklen_t)(offsetof(struct sockaddr_un, sun_path) + len + (path[0] == '/'));
    n->fd = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
    if (n->fd < 0) {
        log_msg(rt->log, LOG_WARN, "notify: cannot create a socket (%s): no notifications", strerror(errno));
        free(n);
        return 0;
    }
    if (usec && (!pid || strtol(pid, NULL, 10) == (long)getpid())) {
        char *end;
        unsigned long long us = strtoull(usec, &end, 10);
        if (*end == 0 && us > 0)
            n->ping_every_ns = us * 1000u / 4u;
    }
    if (n->ping_every_ns)
        log_msg(rt->log, LOG_INFO, "notify: service manager watchdog every %.0f ms (pinged every %.0f ms while "
                "scans run)", n->ping_every_ns * 4 / 1e6, n->ping_every_ns / 1e6);
    n->last_state = PLC_STATE_STARTING;
    *out = n;
    return 0;
}

void notify_send(notifier_t *n, const char *fmt, ...)
{
    char msg[256];
    va_list ap;

    if (!n)
        return;
    va_start(ap, fmt);
    int len = vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    if (len < 0)
        return;
    if ((size_t)len >= sizeof msg)
        len = sizeof msg - 1;
    if (sendto(n->fd, msg, (size_t)len, MSG_DONTWAIT | MSG_NOSIGNAL, (const struct sockaddr *)&n->addr,
               n->addr_len) < 0) {
        if (!n->failing)            /* one line per failure streak */
            log_msg(n->rt->log, LOG_WARN, "notify: cannot send to NOTIFY_SOCKET (%s)", strerror(errno));
        n->failing = true;
        return;
    }
    n->failing = false;
}

/* STATUS= of a running program; `prefix` goes first in the same datagram ("" or "READY=1\n"). */
static void say_running(notifier_t *n, const runtime_t *rt, const char *prefix)
{
    notify_send(n, "%sSTATUS=running %s, scan period %.3f ms", prefix,
                rt->prog->config_name ? rt->prog->config_name : "program", rt->period_ns / 1e6);
}

static void say_state(notifier_t *n, const runtime_t *rt)
{
    const plc_state_t state = (plc_state_t)atomic_load(&rt->state);

    if (state == n->last_state)
        return;
    n->last_state = state;
    if (state == PLC_STATE_RUNNING)
        say_running(n, rt, "");
    else if (state == PLC_STATE_FAULTED)
        notify_send(n, "STATUS=FAULTED: program stopped (fault kind %d at line %d), outputs safe, Modbus serving",
                    rt->fault_kind, rt->fault_line);
}

void notify_after_scan(notifier_t *n, const runtime_t *rt, uint64_t now)
{
    if (!n)
        return;
    if (!n->ready_sent) {
        say_running(n, rt, "READY=1\n");
        n->ready_sent = true;
        n->last_state = (plc_state_t)atomic_load(&rt->state);
    }
    say_state(n, rt);
    if (n->ping_every_ns && now - n->last_ping_ns >= n->ping_every_ns) {
        notify_send(n, "WATCHDOG=1");
        n->last_ping_ns = now;
    }
}

void notify_close(notifier_t *n)
{
    if (!n)
        return;
    notify_send(n, "STATUS=stopped: outputs safe, retained data saved");
    close(n->fd);
    free(n);
}
