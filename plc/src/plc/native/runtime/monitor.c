/*
 * monitor.c - the monitoring channel: watch, write and force over a Unix socket.
 *
 * Never the Modbus port (docs/monitoring.md) and never on the scan thread: one
 * thread of its own serves a Unix socket (mode 0600, so local and the
 * runtime's user only) with a line protocol; every answer is one JSON line.
 *
 *   hello                      program, scan period, scans, whether writes are allowed
 *   list [PREFIX]              every variable (path, type, constant, retain) and located variable
 *   read PATH...               values of one scan: {"ok":true,"values":{PATH:VALUE,...},"scan":N}
 *   sub MS PATH...             every MS ms (10..10000) a line {"sub":ID,"values":{...},"scan":N}
 *                              (no "ok" key: that tells it from an answer)
 *   unsub ID
 *   auth TOKEN                 unlocks the writes below for this connection
 *   write PATH VALUE           set once, before the next scan's program
 *   force PATH VALUE           hold after the inputs and before the outputs, every scan
 *   unforce PATH [keep|restore]   end a force; keep the value (default) or restore the one before it
 *   unforce-all                end every force, values kept
 *   forces                     the active forces
 *
 * Errors are {"ok":false,"error":"..."}; nothing of a refused request reaches
 * the program.  Paths are those of varpath.c.  Every write, force and unforce,
 * and every refused token, goes to the audit file (--audit) and to the log
 * with the peer's uid and pid.  A connection may send 100 requests a second
 * (bursts of 50); more are refused with an error, and a line longer than
 * 4096 bytes or an answer backlog above 8 MiB ends the connection.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <poll.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include "monitor.h"

#define MON_MAX_CLIENTS 16
#define MON_LINE_MAX 4096
#define MON_OUT_MAX (8u << 20)
#define MON_MAX_SUBS 4
#define MON_SUB_VARS 64
#define MON_READ_VARS 64
#define MON_RATE_PER_S 100.0
#define MON_BURST 50.0
#define MON_WAIT_MS 2000            /* longest wait for the scan thread (a stopped scan: an error, not a hang) */

typedef struct sub {
    int id;                          /* 0: free */
    int period_ms;
    uint64_t due_ns;
    unsigned n;
    var_ref_t refs[MON_SUB_VARS];
} sub_t;

typedef struct client {
    int fd;                          /* -1: free */
    char in[MON_LINE_MAX + 1];
    size_t in_len;
    char *out;
    size_t out_len, out_cap;
    bool authed, closing;
    unsigned uid, pid;
    double tokens;
    uint64_t refill_ns;
    int next_sub_id;
    sub_t subs[MON_MAX_SUBS];
} client_t;

struct monitor {
    runtime_t *rt;
    int listen_fd;
    int wake[2];
    pthread_t thread;
    bool started;
    char path[sizeof(((struct sockaddr_un *)0)->sun_path)];
    char token[256];
    bool have_token;
    client_t clients[MON_MAX_CLIENTS];
    snap_item_t items[SNAP_MAX_ITEMS];
    uint8_t data[SNAP_MAX_BYTES];
    char line[64 * 1024];            /* one value's JSON */
};

/* ---------------------------------------------------------------- hooks */

void monitor_after_inputs(runtime_t *rt)
{
    if (rt->force)
        force_after_inputs(rt->force, rt->stats.scans + 1);
}

void monitor_before_outputs(runtime_t *rt)
{
    if (rt->force)
        force_before_outputs(rt->force);
}

void monitor_scan_done(runtime_t *rt)
{
    if (rt->force)
        force_scan_done(rt->force, rt->stats.scans);
    if (rt->events)
        events_after_scan(rt->events, rt, now_ns());
}

/* --------------------------------------------------------------- output */

static void out_raw(client_t *c, const char *s, size_t n)
{
    if (c->closing)
        return;
    if (c->out_len + n > MON_OUT_MAX) {
        c->closing = true;           /* a reader that does not read: dropped, the scan never notices */
        return;
    }
    if (c->out_len + n > c->out_cap) {
        size_t cap = c->out_cap ? c->out_cap : 4096;
        while (cap < c->out_len + n)
            cap *= 2;
        char *p = realloc(c->out, cap);
        if (!p) {
            c->closing = true;
            return;
        }
        c->out = p;
        c->out_cap = cap;
    }
    memcpy(c->out + c->out_len, s, n);
    c->out_len += n;
}

static void outf(client_t *c, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void outf(client_t *c, const char *fmt, ...)
{
    char buf[1024];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    if (n < 0)
        return;
    if ((size_t)n < sizeof buf) {
        out_raw(c, buf, (size_t)n);
        return;
    }
    char *big = malloc((size_t)n + 1);
    if (!big)
        return;
    va_start(ap, fmt);
    vsnprintf(big, (size_t)n + 1, fmt, ap);
    va_end(ap);
    out_raw(c, big, (size_t)n);
    free(big);
}

static void out_json_string(client_t *c, const char *s)
{
    out_raw(c, "\"", 1);
    for (; *s; s++) {
        unsigned char ch = (unsigned char)*s;
        if (ch == '"' || ch == '\\')
            outf(c, "\\%c", ch);
        else if (ch < 0x20 || ch >= 0x7f)
            outf(c, "\\u%04x", ch);
        else
            out_raw(c, s, 1);
    }
    out_raw(c, "\"", 1);
}

static void reply_error(client_t *c, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void reply_error(client_t *c, const char *fmt, ...)
{
    char msg[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    outf(c, "{\"ok\":false,\"error\":");
    out_json_string(c, msg);
    outf(c, "}\n");
}

/* ---------------------------------------------------------------- audit */

static void audit(monitor_t *m, const client_t *c, const char *what, const char *path, const char *value,
                  const char *result)
{
    audit_line(m->rt->audit, "uid=%u pid=%u %s %s%s%s -> %s", c->uid, c->pid, what, path ? path : "",
               value ? " := " : "", value ? value : "", result);
    log_msg(m->rt->log, strncmp(result, "ok", 2) == 0 ? LOG_INFO : LOG_WARN, "monitor: %s %s%s%s by uid %u pid %u: %s",
            what, path ? path : "", value ? " := " : "", value ? value : "", c->uid, c->pid, result);
}

/* ------------------------------------------------------------ requests */

static char *next_word(char **p)
{
    while (**p == ' ' || **p == '\t')
        (*p)++;
    if (!**p)
        return NULL;
    char *w = *p;
    while (**p && **p != ' ' && **p != '\t')
        (*p)++;
    if (**p)
        *(*p)++ = 0;
    return w;
}

static char *rest_of_line(char **p)
{
    while (**p == ' ' || **p == '\t')
        (*p)++;
    char *r = *p;
    size_t n = strlen(r);
    while (n && (r[n - 1] == ' ' || r[n - 1] == '\t'))
        r[--n] = 0;
    return n ? r : NULL;
}

/* Take one snapshot of refs[0..n) and write "PATH":VALUE,... to c. */
static int snapshot_values(monitor_t *m, client_t *c, const var_ref_t *refs, unsigned n, uint64_t *scan)
{
    size_t bytes = 0;
    for (unsigned i = 0; i < n; i++) {
        m->items[i].addr = refs[i].addr;
        m->items[i].size = refs[i].size;
        bytes += refs[i].size;
    }
    if (bytes > sizeof m->data)
        return -1;
    if (force_snapshot(m->rt->force, m->items, n, m->data, MON_WAIT_MS, scan) != 0)
        return -2;
    size_t off = 0;
    for (unsigned i = 0; i < n; i++) {
        if (i)
            out_raw(c, ",", 1);
        out_json_string(c, refs[i].path);
        out_raw(c, ":", 1);
        int k = varpath_format_json(&refs[i], m->data + off, m->line, sizeof m->line);
        if (k < 0)
            out_raw(c, "null", 4);
        else
            out_raw(c, m->line, (size_t)k);
        off += refs[i].size;
    }
    return 0;
}

static int resolve_all(monitor_t *m, client_t *c, char **p, var_ref_t *refs, unsigned max, unsigned *n)
{
    char err[256];
    size_t bytes = 0;
    *n = 0;
    for (char *w = next_word(p); w; w = next_word(p)) {
        if (*n >= max) {
            reply_error(c, "at most %u variables per request", max);
            return -1;
        }
        if (varpath_resolve(m->rt->prog, w, &refs[*n], err, sizeof err) != 0) {
            reply_error(c, "%s", err);
            return -1;
        }
        bytes += refs[*n].size;
        (*n)++;
    }
    if (*n == 0) {
        reply_error(c, "name at least one variable");
        return -1;
    }
    if (bytes > SNAP_MAX_BYTES / 4) {
        reply_error(c, "the values asked for take %zu bytes: at most %d per request", bytes, SNAP_MAX_BYTES / 4);
        return -1;
    }
    return 0;
}

static void cmd_read(monitor_t *m, client_t *c, char *p)
{
    static var_ref_t refs[MON_READ_VARS];
    unsigned n;
    uint64_t scan;

    if (resolve_all(m, c, &p, refs, MON_READ_VARS, &n) != 0)
        return;
    size_t mark = c->out_len;
    outf(c, "{\"ok\":true,\"values\":{");
    if (snapshot_values(m, c, refs, n, &scan) != 0) {
        c->out_len = mark;
        reply_error(c, "no scan took the snapshot within %d ms (is the PLC scanning?)", MON_WAIT_MS);
        return;
    }
    outf(c, "},\"scan\":%" PRIu64 "}\n", scan);
}

static void cmd_sub(monitor_t *m, client_t *c, char *p)
{
    char *ms = next_word(&p);
    char *end;
    long period = ms ? strtol(ms, &end, 10) : 0;
    if (!ms || *end || period < 10 || period > 10000) {
        reply_error(c, "sub MS PATH...: MS is the period in milliseconds, 10..10000");
        return;
    }
    sub_t *s = NULL;
    for (int i = 0; i < MON_MAX_SUBS; i++)
        if (c->subs[i].id == 0) {
            s = &c->subs[i];
            break;
        }
    if (!s) {
        reply_error(c, "at most %d subscriptions per connection", MON_MAX_SUBS);
        return;
    }
    unsigned n;
    if (resolve_all(m, c, &p, s->refs, MON_SUB_VARS, &n) != 0)
        return;
    s->n = n;
    s->period_ms = (int)period;
    s->id = ++c->next_sub_id;
    s->due_ns = now_ns();
    outf(c, "{\"ok\":true,\"sub\":%d,\"period_ms\":%ld,\"paths\":[", s->id, period);
    for (unsigned i = 0; i < n; i++) {
        if (i)
            out_raw(c, ",", 1);
        out_json_string(c, s->refs[i].path);
    }
    outf(c, "]}\n");
}

static void cmd_unsub(client_t *c, char *p)
{
    char *w = next_word(&p);
    int id = w ? atoi(w) : 0;
    for (int i = 0; i < MON_MAX_SUBS; i++)
        if (id > 0 && c->subs[i].id == id) {
            c->subs[i].id = 0;
            outf(c, "{\"ok\":true}\n");
            return;
        }
    reply_error(c, "no subscription %s", w ? w : "(none given)");
}

static void cmd_list(monitor_t *m, client_t *c, char *p)
{
    const plc_program_t *prog = m->rt->prog;
    char *prefix = next_word(&p);
    char want[VP_PATH_MAX] = "";
    bool first = true;

    if (prefix)
        for (size_t i = 0; prefix[i] && i + 1 < sizeof want; i++)
            want[i] = (char)(prefix[i] >= 'a' && prefix[i] <= 'z' ? prefix[i] - 32 : prefix[i]), want[i + 1] = 0;
    outf(c, "{\"ok\":true,\"vars\":[");
    for (uint32_t i = 0; i < prog->n_vars; i++) {
        const plc_var_t *v = &prog->vars[i];
        if (want[0] && !strstr(v->path, want))
            continue;
        outf(c, "%s{\"path\":", first ? "" : ",");
        out_json_string(c, v->path);
        outf(c, ",\"type\":");
        out_json_string(c, v->type_name ? v->type_name : plc_type_name(v->type));
        outf(c, ",\"constant\":%s,\"retain\":%s}", v->constant ? "true" : "false", v->retain ? "true" : "false");
        first = false;
    }
    for (uint32_t i = 0; i < prog->n_located; i++) {
        const plc_located_t *l = &prog->located[i];
        if (want[0] && !strstr(l->var, want) && !strstr(l->address, want))
            continue;
        outf(c, "%s{\"path\":", first ? "" : ",");
        out_json_string(c, l->var);
        outf(c, ",\"type\":\"%s\",\"address\":\"%s\",\"constant\":false,\"retain\":%s}", plc_type_name(l->type),
             l->address, l->retain ? "true" : "false");
        first = false;
    }
    outf(c, "]}\n");
}

static bool token_equal(const char *a, const char *b)
{
    size_t na = strlen(a), nb = strlen(b);
    unsigned diff = (unsigned)(na ^ nb);
    for (size_t i = 0; i < na; i++)
        diff |= (unsigned char)a[i] ^ (unsigned char)b[i % (nb ? nb : 1)];
    return diff == 0;
}

static void cmd_auth(monitor_t *m, client_t *c, char *p)
{
    char *tok = next_word(&p);
    if (!m->have_token) {
        reply_error(c, "writes are disabled: the runtime was started without --monitor-token");
        return;
    }
    if (!tok || !token_equal(tok, m->token)) {
        c->authed = false;
        audit(m, c, "auth", NULL, NULL, "refused: bad token");
        reply_error(c, "bad token: writes stay locked");
        return;
    }
    c->authed = true;
    outf(c, "{\"ok\":true,\"writes\":true}\n");
}

static bool may_write(monitor_t *m, client_t *c, const char *what, const char *path)
{
    if (c->authed)
        return true;
    audit(m, c, what, path, NULL, "refused: no token");
    reply_error(c, "%s needs the token: send 'auth TOKEN' first (%s)", what,
                m->have_token ? "the token is in the file given to --monitor-token"
                              : "writes are disabled: the runtime was started without --monitor-token");
    return false;
}

static void cmd_write_force(monitor_t *m, client_t *c, char *p, force_op_t op)
{
    const char *what = op == FORCE_OP_WRITE ? "write" : "force";
    char *path = next_word(&p);
    char *value = rest_of_line(&p);
    char err[256], res[300];
    uint8_t buf[VP_VALUE_MAX];
    var_ref_t ref;
    uint64_t scan;

    if (!may_write(m, c, what, path))
        return;
    if (!path || !value) {
        reply_error(c, "%s PATH VALUE", what);
        return;
    }
    if (varpath_resolve(m->rt->prog, path, &ref, err, sizeof err) != 0) {
        snprintf(res, sizeof res, "refused: %s", err);
        audit(m, c, what, path, value, res);
        reply_error(c, "%s", err);
        return;
    }
    if (ref.constant) {
        snprintf(res, sizeof res, "refused: %s is a CONSTANT", ref.path);
        audit(m, c, what, ref.path, value, res);
        reply_error(c, "%s is a CONSTANT: it cannot be written or forced", ref.path);
        return;
    }
    if (varpath_parse_value(&ref, value, buf, err, sizeof err) != 0) {
        snprintf(res, sizeof res, "refused: %s", err);
        audit(m, c, what, ref.path, value, res);
        reply_error(c, "%s: %s", ref.path, err);
        return;
    }
    if (force_request(m->rt->force, op, &ref, buf, value, MON_WAIT_MS, &scan, err, sizeof err) != 0) {
        snprintf(res, sizeof res, "refused: %s", err);
        audit(m, c, what, ref.path, value, res);
        reply_error(c, "%s", err);
        return;
    }
    snprintf(res, sizeof res, "ok at scan %" PRIu64, scan);
    audit(m, c, what, ref.path, value, res);
    outf(c, "{\"ok\":true,\"path\":");
    out_json_string(c, ref.path);
    outf(c, ",\"scan\":%" PRIu64 "}\n", scan);
}

static void cmd_unforce(monitor_t *m, client_t *c, char *p, bool all)
{
    char *path = all ? NULL : next_word(&p);
    char *how = all ? NULL : next_word(&p);
    char err[256], res[300];
    var_ref_t ref;
    uint64_t scan;
    force_op_t op = all ? FORCE_OP_UNFORCE_ALL : FORCE_OP_UNFORCE_KEEP;

    if (!may_write(m, c, all ? "unforce-all" : "unforce", path))
        return;
    if (!all) {
        if (!path) {
            reply_error(c, "unforce PATH [keep|restore]");
            return;
        }
        if (how && !strcasecmp(how, "restore"))
            op = FORCE_OP_UNFORCE_RESTORE;
        else if (how && strcasecmp(how, "keep")) {
            reply_error(c, "unforce PATH [keep|restore]: '%s' is neither", how);
            return;
        }
        if (varpath_resolve(m->rt->prog, path, &ref, err, sizeof err) != 0) {
            reply_error(c, "%s", err);
            return;
        }
    }
    const char *what = all ? "unforce-all" : op == FORCE_OP_UNFORCE_RESTORE ? "unforce-restore" : "unforce-keep";
    if (force_request(m->rt->force, op, all ? NULL : &ref, NULL, NULL, MON_WAIT_MS, &scan, err, sizeof err) != 0) {
        snprintf(res, sizeof res, "refused: %s", err);
        audit(m, c, what, all ? NULL : ref.path, NULL, res);
        reply_error(c, "%s", err);
        return;
    }
    snprintf(res, sizeof res, "ok at scan %" PRIu64, scan);
    audit(m, c, what, all ? NULL : ref.path, NULL, res);
    outf(c, "{\"ok\":true,\"scan\":%" PRIu64 "}\n", scan);
}

static void cmd_forces(monitor_t *m, client_t *c)
{
    static force_entry_t list[FORCE_MAX];
    unsigned n = force_list(m->rt->force, list, FORCE_MAX);

    outf(c, "{\"ok\":true,\"forces\":[");
    for (unsigned i = 0; i < n; i++) {
        outf(c, "%s{\"path\":", i ? "," : "");
        out_json_string(c, list[i].path);
        outf(c, ",\"value\":");
        out_json_string(c, list[i].text);
        outf(c, ",\"since_scan\":%" PRIu64 "}", list[i].since_scan);
    }
    outf(c, "]}\n");
}

static void cmd_hello(monitor_t *m, client_t *c)
{
    const runtime_t *rt = m->rt;
    outf(c, "{\"ok\":true,\"runtime\":\"" RT_NAME " " RT_VERSION "\",\"program\":");
    out_json_string(c, rt->prog->config_name ? rt->prog->config_name : "");
    outf(c, ",\"period_us\":%.1f,\"writes\":%s,\"authenticated\":%s,\"pid\":%d}\n", rt->period_ns / 1e3,
         m->have_token ? "true" : "false", c->authed ? "true" : "false", (int)getpid());
}

static bool take_token(client_t *c)
{
    uint64_t now = now_ns();
    c->tokens += (double)(now - c->refill_ns) / 1e9 * MON_RATE_PER_S;
    if (c->tokens > MON_BURST)
        c->tokens = MON_BURST;
    c->refill_ns = now;
    if (c->tokens < 1.0)
        return false;
    c->tokens -= 1.0;
    return true;
}

static void handle_line(monitor_t *m, client_t *c, char *line)
{
    char *p = line;
    char *cmd = next_word(&p);

    if (!cmd)
        return;
    if (!take_token(c)) {
        reply_error(c, "too many requests: at most %.0f a second (request ignored)", MON_RATE_PER_S);
        return;
    }
    if (!strcmp(cmd, "hello")) cmd_hello(m, c);
    else if (!strcmp(cmd, "read")) cmd_read(m, c, p);
    else if (!strcmp(cmd, "sub")) cmd_sub(m, c, p);
    else if (!strcmp(cmd, "unsub")) cmd_unsub(c, p);
    else if (!strcmp(cmd, "list")) cmd_list(m, c, p);
    else if (!strcmp(cmd, "auth")) cmd_auth(m, c, p);
    else if (!strcmp(cmd, "write")) cmd_write_force(m, c, p, FORCE_OP_WRITE);
    else if (!strcmp(cmd, "force")) cmd_write_force(m, c, p, FORCE_OP_FORCE);
    else if (!strcmp(cmd, "unforce")) cmd_unforce(m, c, p, false);
    else if (!strcmp(cmd, "unforce-all")) cmd_unforce(m, c, p, true);
    else if (!strcmp(cmd, "forces")) cmd_forces(m, c);
    else reply_error(c, "unknown request '%.40s' (hello, list, read, sub, unsub, auth, write, force, unforce, "
                     "unforce-all, forces)", cmd);
}

/* ------------------------------------------------------------ sockets */

static void client_close(client_t *c)
{
    if (c->fd >= 0)
        close(c->fd);
    free(c->out);
    memset(c, 0, sizeof *c);
    c->fd = -1;
}

static void accept_client(monitor_t *m)
{
    int fd = accept4(m->listen_fd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
    if (fd < 0)
        return;
    client_t *c = NULL;
    for (int i = 0; i < MON_MAX_CLIENTS; i++)
        if (m->clients[i].fd < 0) {
            c = &m->clients[i];
            break;
        }
    if (!c) {
        static const char busy[] = "{\"ok\":false,\"error\":\"too many monitor connections (at most 16)\"}\n";
        if (write(fd, busy, sizeof busy - 1) < 0) { /* nothing more to do */ }
        close(fd);
        return;
    }
    c->fd = fd;
    c->tokens = MON_BURST;
    c->refill_ns = now_ns();
    struct ucred cred;
    socklen_t len = sizeof cred;
    if (getsockopt(fd, SOL_SOCKET, SO_PEERCRED, &cred, &len) == 0) {
        c->uid = (unsigned)cred.uid;
        c->pid = (unsigned)cred.pid;
    }
}

static void read_client(monitor_t *m, client_t *c)
{
    for (;;) {
        ssize_t r = read(c->fd, c->in + c->in_len, MON_LINE_MAX - c->in_len);
        if (r == 0) {
            c->closing = true;
            c->out_len = 0;
            return;
        }
        if (r < 0) {
            if (errno != EAGAIN && errno != EINTR) {
                c->closing = true;
                c->out_len = 0;
            }
            return;
        }
        c->in_len += (size_t)r;
        char *start = c->in, *nl;
        while ((nl = memchr(start, '\n', c->in_len - (size_t)(start - c->in))) != NULL) {
            *nl = 0;
            if (nl > start && nl[-1] == '\r')
                nl[-1] = 0;
            handle_line(m, c, start);
            start = nl + 1;
        }
        size_t left = c->in_len - (size_t)(start - c->in);
        memmove(c->in, start, left);
        c->in_len = left;
        if (c->in_len >= MON_LINE_MAX) {
            reply_error(c, "request longer than %d bytes: connection closed", MON_LINE_MAX);
            c->closing = true;
            return;
        }
    }
}

static void flush_client(client_t *c)
{
    while (c->out_len > 0) {
        ssize_t w = send(c->fd, c->out, c->out_len, MSG_NOSIGNAL);
        if (w < 0) {
            if (errno == EAGAIN || errno == EINTR)
                return;
            c->out_len = 0;
            c->closing = true;
            return;
        }
        memmove(c->out, c->out + w, c->out_len - (size_t)w);
        c->out_len -= (size_t)w;
    }
}

static void serve_subscriptions(monitor_t *m, uint64_t now)
{
    for (int i = 0; i < MON_MAX_CLIENTS; i++) {
        client_t *c = &m->clients[i];
        if (c->fd < 0 || c->closing)
            continue;
        for (int k = 0; k < MON_MAX_SUBS; k++) {
            sub_t *s = &c->subs[k];
            if (s->id == 0 || now < s->due_ns)
                continue;
            uint64_t scan;
            size_t mark = c->out_len;
            outf(c, "{\"sub\":%d,\"values\":{", s->id);
            if (snapshot_values(m, c, s->refs, s->n, &scan) != 0) {
                c->out_len = mark;
                outf(c, "{\"sub\":%d,\"error\":\"no scan within %d ms\"}\n", s->id, MON_WAIT_MS);
            } else {
                outf(c, "},\"scan\":%" PRIu64 "}\n", scan);
            }
            s->due_ns += (uint64_t)s->period_ms * 1000000u;
            if (s->due_ns < now)                         /* fell behind: no burst to catch up */
                s->due_ns = now + (uint64_t)s->period_ms * 1000000u;
        }
    }
}

static int next_timeout_ms(monitor_t *m, uint64_t now)
{
    uint64_t next = UINT64_MAX;
    for (int i = 0; i < MON_MAX_CLIENTS; i++)
        for (int k = 0; k < MON_MAX_SUBS; k++)
            if (m->clients[i].fd >= 0 && m->clients[i].subs[k].id && m->clients[i].subs[k].due_ns < next)
                next = m->clients[i].subs[k].due_ns;
    if (next == UINT64_MAX)
        return 1000;
    if (next <= now)
        return 0;
    uint64_t ms = (next - now + 999999u) / 1000000u;
    return ms > 1000 ? 1000 : (int)ms;
}

static void *monitor_thread(void *arg)
{
    monitor_t *m = arg;
    struct pollfd pfd[2 + MON_MAX_CLIENTS];
    int slot[2 + MON_MAX_CLIENTS];

    rt_thread_name("monitor");         /* SCHED_OTHER: the scan only trylocks what it shares (force.c) */
    for (;;) {
        int n = 0;
        pfd[n].fd = m->wake[0];
        pfd[n++].events = POLLIN;
        pfd[n].fd = m->listen_fd;
        pfd[n++].events = POLLIN;
        for (int i = 0; i < MON_MAX_CLIENTS; i++) {
            client_t *c = &m->clients[i];
            if (c->fd < 0)
                continue;
            if (c->closing && c->out_len == 0) {
                client_close(c);
                continue;
            }
            pfd[n].fd = c->fd;
            pfd[n].events = (short)((c->closing ? 0 : POLLIN) | (c->out_len ? POLLOUT : 0));
            slot[n++] = i;
        }
        int rc = poll(pfd, (nfds_t)n, next_timeout_ms(m, now_ns()));
        if (rc < 0 && errno != EINTR)
            break;
        if (pfd[0].revents)
            break;
        if (pfd[1].revents & POLLIN)
            accept_client(m);
        for (int j = 2; j < n; j++) {
            client_t *c = &m->clients[slot[j]];
            if (pfd[j].revents & (POLLERR | POLLHUP | POLLNVAL)) {
                if (!(pfd[j].revents & POLLIN)) {
                    c->out_len = 0;
                    c->closing = true;
                    continue;
                }
            }
            if (pfd[j].revents & POLLIN)
                read_client(m, c);
        }
        serve_subscriptions(m, now_ns());
        for (int i = 0; i < MON_MAX_CLIENTS; i++)
            if (m->clients[i].fd >= 0 && m->clients[i].out_len)
                flush_client(&m->clients[i]);
    }
    return NULL;
}

/* ------------------------------------------------------------- start/stop */

static int read_token(monitor_t *m, const char *file)
{
    FILE *f = fopen(file, "r");
    if (!f) {
        log_msg(m->rt->log, LOG_ERROR, "monitor: cannot read the token file %s: %m", file);
        return -1;
    }
    if (!fgets(m->token, sizeof m->token, f))
        m->token[0] = 0;
    fclose(f);
    m->token[strcspn(m->token, "\r\n \t")] = 0;
    if (strlen(m->token) < 16) {
        log_msg(m->rt->log, LOG_ERROR, "monitor: the token in %s is shorter than 16 characters", file);
        return -1;
    }
    m->have_token = true;
    return 0;
}

static int bind_socket(monitor_t *m, const char *path)
{
    struct sockaddr_un sa = { .sun_family = AF_UNIX };

    if (strlen(path) >= sizeof sa.sun_path) {
        log_msg(m->rt->log, LOG_ERROR, "monitor: socket path %s is longer than %zu characters", path,
                sizeof sa.sun_path - 1);
        return -1;
    }
    snprintf(sa.sun_path, sizeof sa.sun_path, "%s", path);
    int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return -1;
    struct stat st;
    if (lstat(path, &st) == 0) {
        if (!S_ISSOCK(st.st_mode)) {
            log_msg(m->rt->log, LOG_ERROR, "monitor: %s exists and is not a socket", path);
            close(fd);
            return -1;
        }
        int probe = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
        if (probe >= 0 && connect(probe, (struct sockaddr *)&sa, sizeof sa) == 0) {
            close(probe);
            close(fd);
            log_msg(m->rt->log, LOG_ERROR, "monitor: %s is served by another running runtime", path);
            return -1;
        }
        if (probe >= 0)
            close(probe);
        unlink(path);                     /* left behind by a runtime that was killed */
    }
    mode_t old = umask(0177);
    int rc = bind(fd, (struct sockaddr *)&sa, sizeof sa);
    umask(old);
    if (rc != 0 || listen(fd, 8) != 0) {
        log_msg(m->rt->log, LOG_ERROR, "monitor: cannot listen on %s: %m", path);
        close(fd);
        return -1;
    }
    chmod(path, 0600);
    snprintf(m->path, sizeof m->path, "%s", path);
    return fd;
}

int monitor_start(runtime_t *rt, monitor_t **out)
{
    *out = NULL;
    if (!rt->opt.monitor_path)
        return 0;
    monitor_t *m = calloc(1, sizeof *m);
    if (!m)
        return -1;
    m->rt = rt;
    m->listen_fd = -1;
    m->wake[0] = m->wake[1] = -1;
    for (int i = 0; i < MON_MAX_CLIENTS; i++)
        m->clients[i].fd = -1;
    if (rt->opt.monitor_token_file && read_token(m, rt->opt.monitor_token_file) != 0)
        goto fail;
    if (rt->opt.audit_path && !rt->audit) {
        log_msg(rt->log, LOG_ERROR, "monitor: no writes and forces without their audit file %s", rt->opt.audit_path);
        goto fail;
    }
    rt->force = force_create();
    if (!rt->force || pipe2(m->wake, O_CLOEXEC) != 0)
        goto fail;
    m->listen_fd = bind_socket(m, rt->opt.monitor_path);
    if (m->listen_fd < 0)
        goto fail;
    if (pthread_create(&m->thread, NULL, monitor_thread, m) != 0)
        goto fail;
    m->started = true;
    log_msg(rt->log, LOG_INFO, "monitor on %s (%s; audit %s)", m->path,
            m->have_token ? "writes and forces with the token" : "read-only: no --monitor-token",
            rt->opt.audit_path ? rt->opt.audit_path : "to the log only");
    *out = m;
    return 0;
fail:
    monitor_stop(m);
    return -1;
}

void monitor_stop(monitor_t *m)
{
    if (!m)
        return;
    if (m->started) {
        if (write(m->wake[1], "x", 1) < 0) { /* the thread also ends when poll fails */ }
        pthread_join(m->thread, NULL);
    }
    for (int i = 0; i < MON_MAX_CLIENTS; i++)
        if (m->clients[i].fd >= 0)
            client_close(&m->clients[i]);
    if (m->listen_fd >= 0) {
        close(m->listen_fd);
        unlink(m->path);
    }
    if (m->wake[0] >= 0)
        close(m->wake[0]);
    if (m->wake[1] >= 0)
        close(m->wake[1]);
    /* rt->force stays until the scan has stopped calling the hooks: freed by main after scan_run */
    free(m);
}
