/*
 * modbus_server.c - Modbus/TCP server thread on libmodbus.
 *
 * libmodbus provides the listening socket (modbus_tcp_listen) and builds and
 * sends every response (modbus_reply, modbus_reply_exception).  Receiving is
 * done here, not with modbus_receive(), for two reasons found in libmodbus
 * 3.1.6: modbus_receive() frames a request by its function code rather than
 * by the MBAP length (a lying length desynchronises the stream), and it
 * blocks the calling thread while a request arrives byte by byte (one slow
 * client would stall all others).  Here each client has its own buffer, reads
 * never block, and a request is handled only once the number of bytes its
 * MBAP header announces has arrived.
 *
 * Every request is checked completely before libmodbus sees it (function
 * code, PDU length against the MBAP length, quantity, byte count, address
 * range, host-writable range, read-only mode), so modbus_reply() only ever
 * answers valid requests.  That matters: on a bad quantity modbus_reply()
 * would sleep for the response timeout and flush the socket, and for function
 * codes 0x11, 0x16 and 0x17 it would answer by itself.
 *
 * Locking: the image lock is held only to copy the registers a request reads
 * into a scratch mapping, or to queue the values it writes; never during a
 * socket call.
 *
 * Hostile clients (the CNC must stay served):
 *   - a request begun but not complete after --frame-timeout ms is dropped
 *     with its connection; a connection with nothing pending is kept forever
 *     (mb2hal never reconnects);
 *   - a client whose responses stay unsent (it stopped reading) gets no more
 *     answers, and is dropped after --frame-timeout ms, or at once when a
 *     response does not fit in its socket buffer;
 *   - when every slot is taken, a new connection takes the slot of the
 *     longest-suspect client: one that has not completed a request yet, has
 *     one half-received, or leaves its responses unread.  Clients that have
 *     been served and have nothing pending are never reclaimed; if all slots
 *     hold such clients, the new connection is refused;
 *   - each round reads the clients already served first, and accepts at most
 *     ACCEPTS_PER_ROUND newcomers; dropped connections are reset, not closed;
 *   - with real-time scheduling on, this thread runs SCHED_FIFO below the scan.
 * Every decision is logged, at most one line per kind per second: the first
 * event at once, the others counted and summed up in one line a second later.
 *
 * Roles: each client gets a role when it is accepted, from the --allow entry
 * with the longest prefix that holds its address (engineer without --allow).
 * A `read` client is answered exception 01 to every write function code; a
 * `host` writes the host ranges only (--host-coils, --host-registers; any
 * other address: exception 02); an `engineer` every writable address.  The
 * whole request is checked before anything of it is queued: a multiple write
 * is applied entirely or not at all.
 *
 * Audit: every write request (function codes 5, 6, 15, 16, and 22, 23, which
 * are never served) goes to the audit file with its peer, role, function
 * code, table, address range, count and result, at most MODBUS_AUDIT_PER_S
 * lines a second: beyond that the requests are counted and summed up in one
 * line when the second is over.  Refused writes are also logged (one line per
 * second, as the decisions above).
 *
 * Modbus/TCP Security (MBAPS, --tls-cert): a second listener whose clients
 * take the same slots (--max-clients) and the same request path: libmodbus
 * has no TLS, so OpenSSL terminates it here.  Handshakes and reads are
 * non-blocking like the plain clients'; the decrypted bytes go to the same
 * framing and checks, and libmodbus builds the response as for a plain
 * client, into one end of a socket pair, from which it is read and encrypted
 * to the client.  TLS 1.2 at least, no renegotiation, no session resumption
 * (every connection shows its certificate).  The client must present a
 * certificate the CA of --tls-ca signed, valid now, else the handshake fails
 * and the connection is refused; its role is the value of the certificate's
 * MBAPS role extension (OID 1.3.6.1.4.1.50316.802.1, a UTF8String: read,
 * host or engineer); a certificate without it or with another value is
 * refused (no default role: who is not named gets nothing).  --allow does
 * not apply: the certificate is the client's identity.  A handshake not
 * done within --frame-timeout is dropped.  The audit line of a TLS client's
 * write carries its certificate's common name.
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <linux/sockios.h>
#include <modbus.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <openssl/err.h>
#include <openssl/ssl.h>
#include <openssl/x509v3.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "runtime.h"

#define MBAP_HEADER 7u                /* transaction id, protocol id, length, unit id */
#define MBAP_MAX_LENGTH 254u          /* unit id + the largest PDU (253 bytes) */
#define CLIENT_BUFFER (2u * (6u + MBAP_MAX_LENGTH))
#define CLIENT_SNDBUF 16384           /* per-client send buffer: ~60 of the largest responses */
#define LISTEN_BACKLOG 512           /* a connection storm overflows it later (SYN drops stall connect) */
#define ACCEPTS_PER_ROUND 2           /* a connection storm cannot starve the served clients */
#define EVENT_WINDOW_NS 1000000000u   /* one log line per kind per second */
#define PRIORITY_BELOW_SCAN 10       /* SCHED_FIFO priority of this thread: the scan's minus this */
#define UNSENT_POLL_NS 10000000u      /* how often a client that stopped reading is looked at */
#define PEER_TEXT (INET_ADDRSTRLEN + 8)
#define CN_TEXT 65                    /* a certificate's common name: at most 64 characters */
#define MBAPS_ROLE_OID "1.3.6.1.4.1.50316.802.1"

typedef struct client {
    int fd;                           /* -1: free slot */
    size_t len;                       /* bytes in buf */
    uint64_t connected_ns;
    uint64_t partial_since_ns;        /* when the incomplete request in buf began; 0: none */
    uint64_t unsent_since_ns;         /* when responses were first seen unsent; 0: flowing */
    uint64_t admitted_round;          /* server loop round it was accepted in */
    uint32_t served;                  /* requests answered */
    client_role_t role;
    SSL *ssl;                         /* a client of the TLS listener; NULL: plain */
    bool handshaking;                 /* its TLS handshake is not done yet */
    bool handshake_wants_write;       /* ... and waits for room in its socket */
    uint8_t buf[CLIENT_BUFFER];
    char peer[PEER_TEXT];
    char cn[CN_TEXT];                 /* a TLS client's certificate's common name (printable ASCII) */
} client_t;

/* ------------------------------------------------- rate-limited decisions */

typedef enum event_kind {
    EV_CONNECTED,
    EV_CLOSED,
    EV_REFUSED_ALLOWLIST,
    EV_REFUSED_FULL,
    EV_RECLAIMED,
    EV_FRAME_TIMEOUT,
    EV_SLOW_READER,
    EV_NOT_MODBUS,
    EV_SOCKET_ERROR,
    EV_STOPPING,
    EV_WRITE_REFUSED,
    EV_TLS_REFUSED,
    EV_TLS_TIMEOUT,
    EV_TLS_AUTHENTICATED,
    EV_COUNT
} event_kind_t;

static const struct {
    log_level_t level;
    const char *what;                 /* follows "client PEER " */
} EVENTS[EV_COUNT] = {
    [EV_CONNECTED] = { LOG_INFO, "connected" },
    [EV_CLOSED] = { LOG_INFO, "disconnected (closed by the client)" },
    [EV_REFUSED_ALLOWLIST] = { LOG_WARN, "refused: address not in the allowlist" },
    [EV_REFUSED_FULL] = { LOG_WARN, "refused: every slot holds a served client" },
    [EV_RECLAIMED] = { LOG_WARN, "dropped to make room: no request served, one half-received or answers unread" },
    [EV_FRAME_TIMEOUT] = { LOG_WARN, "dropped: request incomplete after the frame timeout" },
    [EV_SLOW_READER] = { LOG_WARN, "dropped: stopped reading its responses" },
    [EV_NOT_MODBUS] = { LOG_WARN, "dropped: MBAP header not Modbus/TCP" },
    [EV_SOCKET_ERROR] = { LOG_WARN, "dropped: socket error" },
    [EV_STOPPING] = { LOG_INFO, "disconnected (runtime stopping)" },
    [EV_WRITE_REFUSED] = { LOG_WARN, "write refused" },
    [EV_TLS_REFUSED] = { LOG_WARN, "refused: TLS handshake failed or no known role in its certificate" },
    [EV_TLS_TIMEOUT] = { LOG_WARN, "dropped: TLS handshake not done within the frame timeout" },
    [EV_TLS_AUTHENTICATED] = { LOG_INFO, "authenticated over TLS" },
};

typedef struct event_gate {
    uint64_t last_line_ns;            /* 0: no line yet */
    unsigned held;                    /* events since that line, not logged yet */
    char last_peer[PEER_TEXT];
    char last_detail[176];            /* room for a TLS refusal: the common name (64) and the reason */
} event_gate_t;

struct modbus_server {
    runtime_t *rt;
    modbus_t *ctx;
    modbus_mapping_t *scratch;        /* what modbus_reply() reads from and writes into */
    int listen_fd;
    int tls_listen_fd;                /* -1: no TLS listener */
    SSL_CTX *tls;
    ASN1_OBJECT *role_oid;            /* the MBAPS role extension */
    int reply_pair[2];                /* libmodbus writes a TLS client's response into [0], read from [1] */
    int wake[2];                      /* self-pipe: stop request */
    pthread_t thread;
    bool thread_started;
    client_t *clients;
    int n_clients;
    uint64_t frame_timeout_ns;
    uint64_t round;                   /* select() rounds so far */
    uint32_t requests, exceptions, refused, dropped;
    uint32_t writes, writes_refused;
    event_gate_t gates[EV_COUNT];
    /* the audit's rate bound: a window of one second from its first line */
    uint64_t audit_window_ns;         /* when the window began; 0: none open */
    unsigned audit_lines;             /* itemised in it */
    unsigned audit_held_ok, audit_held_refused;   /* counted, not itemised */
    char audit_last[400];             /* the last request not itemised */
};

/* --------------------------------------------------------------- helpers */

static uint16_t be16(const uint8_t *p)
{
    return (uint16_t)((p[0] << 8) | p[1]);
}

static void publish_counters(modbus_server_t *srv)   /* caller holds the lock */
{
    bus_image_t *b = &srv->rt->bimg;

    diag_put16(b, DIAG_CLIENTS, (uint16_t)srv->n_clients);
    diag_put32(b, DIAG_REQUESTS, srv->requests);
    diag_put32(b, DIAG_EXCEPTIONS, srv->exceptions);
    diag_put32(b, DIAG_REFUSED, srv->refused);
    diag_put32(b, DIAG_DROPPED, srv->dropped);
    diag_put32(b, DIAG_WRITES, srv->writes);
    diag_put32(b, DIAG_WRITES_REFUSED, srv->writes_refused);
    atomic_store_explicit(&srv->rt->live.clients, (unsigned)srv->n_clients, memory_order_relaxed);
    atomic_store_explicit(&srv->rt->live.requests, srv->requests, memory_order_relaxed);
}

static void update_counters(modbus_server_t *srv)
{
    pthread_mutex_lock(&srv->rt->lock);
    publish_counters(srv);
    pthread_mutex_unlock(&srv->rt->lock);
}

/* Whether a client at addr is accepted, and with which role: that of the --allow entry with the longest
 * prefix holding addr (entries of one network have one role: main.c); without entries any client, engineer. */
static bool allowed(const rt_options_t *opt, uint32_t addr, client_role_t *role)
{
    int best = -1;

    *role = ROLE_ENGINEER;
    if (opt->n_allow == 0)
        return true;
    for (int i = 0; i < opt->n_allow; i++)
        if ((addr & opt->allow[i].mask) == opt->allow[i].addr
            && (best < 0 || __builtin_popcount(opt->allow[i].mask) > __builtin_popcount(opt->allow[best].mask)))
            best = i;
    if (best < 0)
        return false;
    *role = opt->allow[best].role;
    return true;
}

static void detail_text(const char *detail, char *out, size_t n)
{
    if (detail[0])
        snprintf(out, n, " [%s]", detail);
    else
        out[0] = 0;
}

/* Log one decision: at once when the kind had no line in the last second,
 * else counted for the summary line flush_events() writes. */
static void note_event(modbus_server_t *srv, event_kind_t kind, const char *peer, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

static void note_event(modbus_server_t *srv, event_kind_t kind, const char *peer, const char *fmt, ...)
{
    event_gate_t *g = &srv->gates[kind];
    uint64_t t = now_ns();
    va_list ap;

    va_start(ap, fmt);
    vsnprintf(g->last_detail, sizeof g->last_detail, fmt, ap);
    va_end(ap);
    snprintf(g->last_peer, sizeof g->last_peer, "%s", peer);
    if (g->last_line_ns != 0 && t - g->last_line_ns < EVENT_WINDOW_NS) {
        g->held++;
        return;
    }
    char detail[sizeof g->last_detail + 4];
    detail_text(g->last_detail, detail, sizeof detail);
    log_msg(srv->rt->log, EVENTS[kind].level, "modbus: client %s %s%s", peer, EVENTS[kind].what, detail);
    g->last_line_ns = t;
    g->held = 0;
}

/* Write the summary lines that are due; return the next time one will be. */
static uint64_t flush_events(modbus_server_t *srv, uint64_t t, bool all)
{
    uint64_t next = UINT64_MAX;

    for (int k = 0; k < EV_COUNT; k++) {
        event_gate_t *g = &srv->gates[k];
        if (g->held == 0)
            continue;
        if (!all && t - g->last_line_ns < EVENT_WINDOW_NS) {
            if (g->last_line_ns + EVENT_WINDOW_NS < next)
                next = g->last_line_ns + EVENT_WINDOW_NS;
            continue;
        }
        log_msg(srv->rt->log, EVENTS[k].level, "modbus: %u more clients %s in the last %.1f s [the last: %s%s%s]",
                g->held, EVENTS[k].what, (double)(t - g->last_line_ns) / 1e9, g->last_peer,
                g->last_detail[0] ? ", " : "", g->last_detail);
        g->last_line_ns = t;
        g->held = 0;
    }
    return next;
}

static void close_client(modbus_server_t *srv, client_t *c, event_kind_t why, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

static void close_client(modbus_server_t *srv, client_t *c, event_kind_t why, const char *fmt, ...)
{
    char detail[176];
    va_list ap;

    va_start(ap, fmt);
    vsnprintf(detail, sizeof detail, fmt, ap);
    va_end(ap);
    note_event(srv, why, c->peer, "%s", detail);
    if (c->ssl) {
        if (why == EV_CLOSED || why == EV_STOPPING)
            SSL_shutdown(c->ssl);             /* close_notify, once; no wait for the client's */
        SSL_free(c->ssl);
        c->ssl = NULL;
    }
    if (why != EV_CLOSED && why != EV_STOPPING) {
        /* Reset, not FIN: a hostile storm leaves no TIME_WAIT sockets behind here. */
        struct linger abort_close = { .l_onoff = 1, .l_linger = 0 };
        setsockopt(c->fd, SOL_SOCKET, SO_LINGER, &abort_close, sizeof abort_close);
    }
    close(c->fd);
    c->fd = -1;
    c->len = 0;
    c->handshaking = c->handshake_wants_write = false;
    srv->n_clients--;
    if (why == EV_TLS_REFUSED)
        srv->refused++;                       /* no certificate, a bad one, or no role: not let in */
    else if (why != EV_CLOSED && why != EV_STOPPING)
        srv->dropped++;
    update_counters(srv);
}

/* Bytes queued on the socket that the peer's window does not let out yet. */
static int unsent_bytes(int fd)
{
    int n = 0;

    if (ioctl(fd, SIOCOUTQNSD, &n) != 0)
        return 0;
    return n;
}

/* --------------------------------------------------------------- accept */

static void refuse(modbus_server_t *srv, int fd, const char *peer, event_kind_t why, const char *detail)
{
    close(fd);
    srv->refused++;
    update_counters(srv);
    note_event(srv, why, peer, "%s", detail);
}

/* The slot a new connection may take from a suspect client, or NULL.  Suspect:
 * no request completed yet, a request half-received, or responses left unread;
 * the longest-suspect goes.
 * A client accepted in this round has not been read yet: it is not a candidate,
 * but *fresh says one exists (the caller then leaves the newcomer queued). */
static client_t *reclaimable(modbus_server_t *srv, bool *fresh)
{
    client_t *victim = NULL;
    uint64_t oldest = UINT64_MAX;

    *fresh = false;
    for (int i = 0; i < srv->rt->opt.max_clients; i++) {
        client_t *c = &srv->clients[i];
        if (c->fd < 0)
            continue;
        if (c->admitted_round == srv->round) {
            *fresh = true;
            continue;
        }
        uint64_t since = c->partial_since_ns ? c->partial_since_ns
                         : c->served == 0 ? c->connected_ns
                         : c->unsent_since_ns;
        if (since != 0 && since < oldest) {
            oldest = since;
            victim = c;
        }
    }
    return victim;
}

/* Socket options of a client that has sent a complete request: set then, not at
 * accept, so a connection storm costs the server as little as possible. */
static void tune_socket(int fd)
{
    int one = 1, idle = 60, intvl = 10, cnt = 6, sndbuf = CLIENT_SNDBUF;

    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &sndbuf, sizeof sndbuf);
    setsockopt(fd, SOL_SOCKET, SO_KEEPALIVE, &one, sizeof one);
    setsockopt(fd, IPPROTO_TCP, TCP_KEEPIDLE, &idle, sizeof idle);
    setsockopt(fd, IPPROTO_TCP, TCP_KEEPINTVL, &intvl, sizeof intvl);
    setsockopt(fd, IPPROTO_TCP, TCP_KEEPCNT, &cnt, sizeof cnt);
}

/* A TLS client begins with its handshake (tls_handshake), within the frame timeout; its role is its
 * certificate's.  NULL when OpenSSL cannot take it (logged). */
static SSL *tls_session(modbus_server_t *srv, int fd)
{
    SSL *ssl = SSL_new(srv->tls);

    if (ssl && SSL_set_fd(ssl, fd) == 1) {
        SSL_set_accept_state(ssl);
        return ssl;
    }
    log_msg(srv->rt->log, LOG_WARN, "modbus: cannot begin a TLS session: %s", ERR_error_string(ERR_get_error(), NULL));
    SSL_free(ssl);
    return NULL;
}

static void admit(modbus_server_t *srv, int fd, const char *peer, client_role_t role, SSL *ssl)
{
    const rt_options_t *opt = &srv->rt->opt;

    for (int i = 0; i < opt->max_clients; i++) {
        client_t *c = &srv->clients[i];
        if (c->fd >= 0)
            continue;
        c->fd = fd;
        c->len = 0;
        c->connected_ns = now_ns();
        c->partial_since_ns = c->unsent_since_ns = 0;
        c->served = 0;
        c->admitted_round = srv->round;
        c->role = role;
        c->ssl = ssl;
        c->handshaking = ssl != NULL;
        c->handshake_wants_write = false;
        c->cn[0] = 0;
        if (ssl)
            c->partial_since_ns = c->connected_ns;      /* the handshake is bound by the frame timeout */
        snprintf(c->peer, sizeof c->peer, "%s", peer);
        srv->n_clients++;
        break;
    }
    update_counters(srv);
    if (ssl)
        note_event(srv, EV_CONNECTED, peer, "%d of %d, TLS: role from its certificate", srv->n_clients,
                   opt->max_clients);
    else
        note_event(srv, EV_CONNECTED, peer, "%d of %d, role %s", srv->n_clients, opt->max_clients, role_name(role));
}

/* The newcomers of one listener: the plain one (the allowlist gives the role) or the TLS one (the certificate
 * will). */
static void accept_clients(modbus_server_t *srv, int listen_fd, bool tls)
{
    const rt_options_t *opt = &srv->rt->opt;

    for (int n = 0; n < ACCEPTS_PER_ROUND; n++) {
        bool fresh = false;
        if (srv->n_clients >= opt->max_clients && !reclaimable(srv, &fresh) && fresh)
            return;                         /* read the newest first; the rest wait in the backlog */

        struct sockaddr_in sa;
        socklen_t salen = sizeof sa;
        char peer[PEER_TEXT], ip[INET_ADDRSTRLEN];
        int fd = accept4(listen_fd, (struct sockaddr *)&sa, &salen, SOCK_NONBLOCK | SOCK_CLOEXEC);

        if (fd < 0) {
            if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR && errno != ECONNABORTED)
                log_msg(srv->rt->log, LOG_WARN, "modbus: accept failed: %s", strerror(errno));
            return;
        }
        if (!inet_ntop(AF_INET, &sa.sin_addr, ip, sizeof ip))
            snprintf(ip, sizeof ip, "?");
        snprintf(peer, sizeof peer, "%s:%u", ip, ntohs(sa.sin_port));

        client_role_t role = ROLE_READ;
        if (!tls && !allowed(opt, ntohl(sa.sin_addr.s_addr), &role)) {
            refuse(srv, fd, peer, EV_REFUSED_ALLOWLIST, "");
            continue;
        }
        if (fd >= FD_SETSIZE) {
            refuse(srv, fd, peer, EV_REFUSED_FULL, "descriptor number too high for select()");
            continue;
        }
        if (srv->n_clients >= opt->max_clients) {
            client_t *victim = reclaimable(srv, &fresh);
            if (!victim) {
                char why[64];
                snprintf(why, sizeof why, "limit of %d clients, --max-clients", opt->max_clients);
                refuse(srv, fd, peer, EV_REFUSED_FULL, why);
                continue;
            }
            close_client(srv, victim, EV_RECLAIMED, "for %s; connected %llu ms ago, %u requests served, %zu bytes "
                         "pending", peer, (unsigned long long)((now_ns() - victim->connected_ns) / 1000000u),
                         victim->served, victim->len);
        }
        SSL *ssl = NULL;
        if (tls && !(ssl = tls_session(srv, fd))) {
            refuse(srv, fd, peer, EV_TLS_REFUSED, "no TLS session");
            continue;
        }
        admit(srv, fd, peer, role, ssl);
    }
}

/* ------------------------------------------------------------- requests */

static bool is_write(unsigned fc)
{
    return fc == MODBUS_FC_WRITE_SINGLE_COIL || fc == MODBUS_FC_WRITE_SINGLE_REGISTER
           || fc == MODBUS_FC_WRITE_MULTIPLE_COILS || fc == MODBUS_FC_WRITE_MULTIPLE_REGISTERS;
}

/* Every function code that writes, served or not: what the audit and the write counters see. */
static bool writes_something(unsigned fc)
{
    return is_write(fc) || fc == MODBUS_FC_MASK_WRITE_REGISTER || fc == MODBUS_FC_WRITE_AND_READ_REGISTERS;
}

static bool is_read(unsigned fc)
{
    return fc == MODBUS_FC_READ_COILS || fc == MODBUS_FC_READ_DISCRETE_INPUTS
           || fc == MODBUS_FC_READ_HOLDING_REGISTERS || fc == MODBUS_FC_READ_INPUT_REGISTERS;
}

static int check_read(const uint8_t *pdu, unsigned pdu_len)
{
    const unsigned fc = pdu[0], addr = be16(pdu + 1), qty = be16(pdu + 3);
    const bool bits = fc == MODBUS_FC_READ_COILS || fc == MODBUS_FC_READ_DISCRETE_INPUTS;
    const unsigned max = bits ? MODBUS_MAX_READ_BITS : MODBUS_MAX_READ_REGISTERS;
    const unsigned size = bits ? MAP_BITS : fc == MODBUS_FC_READ_HOLDING_REGISTERS ? MAP_HOLDING : MAP_INPUT_REGS;

    if (pdu_len != 5 || qty < 1 || qty > max)
        return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
    if (addr + qty > size)
        return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
    return 0;
}

/* A write request against the coils and registers `wcoils`, `wregs` (those of the client's role). */
static int check_write(const addr_set_t *wcoils, const addr_set_t *wregs, const uint8_t *pdu, unsigned pdu_len)
{
    const unsigned fc = pdu[0], addr = be16(pdu + 1), qty = be16(pdu + 3);   /* qty: the value for 5 and 6 */

    switch (fc) {
    case MODBUS_FC_WRITE_SINGLE_COIL:
        if (pdu_len != 5 || (qty != 0x0000 && qty != 0xFF00))
            return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
        if (addr >= MAP_BITS || !addr_set_has(wcoils, addr))
            return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
        return 0;
    case MODBUS_FC_WRITE_SINGLE_REGISTER:
        if (pdu_len != 5)
            return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
        if (addr >= MAP_HOLDING || !addr_set_has(wregs, addr))
            return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
        return 0;
    default: {                                  /* multiple coils, multiple registers */
        const bool coils = fc == MODBUS_FC_WRITE_MULTIPLE_COILS;
        const unsigned max = coils ? MODBUS_MAX_WRITE_BITS : MODBUS_MAX_WRITE_REGISTERS;
        const unsigned size = coils ? MAP_BITS : MAP_HOLDING;
        const addr_set_t *w = coils ? wcoils : wregs;
        if (pdu_len < 6 || qty < 1 || qty > max)
            return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
        const unsigned bytes = coils ? (qty + 7) / 8 : 2 * qty;
        if (pdu[5] != bytes || pdu_len != 6 + bytes)
            return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
        if (addr + qty > size)
            return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
        for (unsigned a = addr; a < addr + qty; a++)
            if (!addr_set_has(w, a))
                return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
        return 0;
    }
    }
}

/* Check a request of a client of `role`.  Returns 0 when it may be served, else the exception code, with
 * *why saying what refused it.  pdu points at the function code, pdu_len counts it. */
static int check_request(const rt_options_t *opt, client_role_t role, const uint8_t *pdu, unsigned pdu_len,
                         const char **why)
{
    const unsigned fc = pdu[0];
    int exc;

    *why = "";
    if (!is_read(fc) && !is_write(fc)) {
        *why = "function code not served";
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    }
    if (is_write(fc) && opt->read_only) {
        *why = "read-only server";
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;   /* the whole write function set is off */
    }
    if (is_write(fc) && role == ROLE_READ) {
        *why = "role read writes nothing";
        return MODBUS_EXCEPTION_ILLEGAL_FUNCTION;
    }
    if (pdu_len < 5) {
        *why = "request too short";
        return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
    }
    if (is_read(fc))
        return check_read(pdu, pdu_len);
    if (role == ROLE_HOST) {
        exc = check_write(&opt->host_coils, &opt->host_registers, pdu, pdu_len);
        if (exc == MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS)
            *why = check_write(&opt->writable_coils, &opt->writable_registers, pdu, pdu_len) == 0
                   ? "outside the host ranges: an engineer's" : "not writable";
    } else {
        exc = check_write(&opt->writable_coils, &opt->writable_registers, pdu, pdu_len);
        if (exc == MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS)
            *why = "not writable";
    }
    if (exc == MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE)
        *why = "bad quantity, value or byte count";
    return exc;
}

/* ---------------------------------------------------------------- audit */

static const char *exception_name(int exc)
{
    return exc == MODBUS_EXCEPTION_ILLEGAL_FUNCTION ? "ILLEGAL FUNCTION"
           : exc == MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS ? "ILLEGAL DATA ADDRESS"
           : exc == MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE ? "ILLEGAL DATA VALUE" : "?";
}

/* "fc=16 registers 520-521 count=2": what a write request touches, as far as it says. */
static void describe_write(const uint8_t *pdu, unsigned pdu_len, char *out, size_t n)
{
    const unsigned fc = pdu[0];

    if (pdu_len < 5) {
        snprintf(out, n, "fc=%u (%u bytes: too short)", fc, pdu_len);
        return;
    }
    const unsigned addr = be16(pdu + 1), qty = be16(pdu + 3);
    switch (fc) {
    case MODBUS_FC_WRITE_SINGLE_COIL:
        snprintf(out, n, "fc=%u coil %u count=1", fc, addr);
        break;
    case MODBUS_FC_WRITE_SINGLE_REGISTER:
    case MODBUS_FC_MASK_WRITE_REGISTER:
        snprintf(out, n, "fc=%u register %u count=1", fc, addr);
        break;
    case MODBUS_FC_WRITE_AND_READ_REGISTERS:
        if (pdu_len >= 9)
            snprintf(out, n, "fc=%u registers %u-%u count=%u", fc, be16(pdu + 5),
                     be16(pdu + 5) + (be16(pdu + 7) ? be16(pdu + 7) - 1u : 0u), be16(pdu + 7));
        else
            snprintf(out, n, "fc=%u (%u bytes: too short)", fc, pdu_len);
        break;
    default:
        snprintf(out, n, "fc=%u %s %u-%u count=%u", fc, fc == MODBUS_FC_WRITE_MULTIPLE_COILS ? "coils" : "registers",
                 addr, addr + (qty ? qty - 1u : 0u), qty);
        break;
    }
}

/* The summary of the requests of the audit window not itemised, when there are some. */
static void audit_summary(modbus_server_t *srv, uint64_t t)
{
    const unsigned held = srv->audit_held_ok + srv->audit_held_refused;

    if (held > 0)
        audit_line(srv->rt->audit, "modbus %u more write requests in %.1f s not itemised (at most %u lines a "
                   "second): %u served, %u refused; the last: %s", held, (double)(t - srv->audit_window_ns) / 1e9,
                   MODBUS_AUDIT_PER_S, srv->audit_held_ok, srv->audit_held_refused, srv->audit_last);
    srv->audit_held_ok = srv->audit_held_refused = 0;
    srv->audit_window_ns = 0;
    srv->audit_lines = 0;
}

/* A write request in the audit file: itemised while its window has room, else counted. */
static void audit_write(modbus_server_t *srv, const client_t *c, const char *what, int exc, const char *why)
{
    char result[120];
    const uint64_t t = now_ns();

    if (!srv->rt->audit)
        return;
    if (srv->audit_window_ns != 0 && t - srv->audit_window_ns >= EVENT_WINDOW_NS)
        audit_summary(srv, t);
    if (srv->audit_window_ns == 0)
        srv->audit_window_ns = t;
    if (exc)
        snprintf(result, sizeof result, "refused: exception %02d %s (%s)", exc, exception_name(exc), why);
    else
        snprintf(result, sizeof result, "ok");
    char who[PEER_TEXT + CN_TEXT + 40];              /* a TLS client: its certificate's common name too */
    if (c->ssl)
        snprintf(who, sizeof who, "peer=%s tls cn=\"%s\" role=%s", c->peer, c->cn, role_name(c->role));
    else
        snprintf(who, sizeof who, "peer=%s role=%s", c->peer, role_name(c->role));
    if (srv->audit_lines < MODBUS_AUDIT_PER_S) {
        srv->audit_lines++;
        audit_line(srv->rt->audit, "modbus %s %s -> %s", who, what, result);
        return;
    }
    if (exc)
        srv->audit_held_refused++;
    else
        srv->audit_held_ok++;
    snprintf(srv->audit_last, sizeof srv->audit_last, "%s %s -> %s", who, what, result);
}

/* Copy what a valid request reads into the scratch mapping, or queue what it
 * writes into the image.  Caller holds the image lock. */
static void serve_locked(modbus_server_t *srv, const uint8_t *pdu)
{
    bus_image_t *b = &srv->rt->bimg;
    modbus_mapping_t *m = srv->scratch;
    const unsigned fc = pdu[0], addr = be16(pdu + 1), qty = be16(pdu + 3);

    switch (fc) {
    case MODBUS_FC_READ_COILS:
        memcpy(m->tab_bits + addr, b->coils + addr, qty);
        break;
    case MODBUS_FC_READ_DISCRETE_INPUTS:
        memcpy(m->tab_input_bits + addr, b->discrete + addr, qty);
        break;
    case MODBUS_FC_READ_HOLDING_REGISTERS:
        memcpy(m->tab_registers + addr, b->holding + addr, 2u * qty);
        break;
    case MODBUS_FC_READ_INPUT_REGISTERS:
        memcpy(m->tab_input_registers + addr, b->input_regs + addr, 2u * qty);
        break;
    case MODBUS_FC_WRITE_SINGLE_COIL:
        image_host_write_coil(b, addr, qty == 0xFF00);
        break;
    case MODBUS_FC_WRITE_SINGLE_REGISTER:
        image_host_write_register(b, addr, (uint16_t)qty);
        break;
    case MODBUS_FC_WRITE_MULTIPLE_COILS:
        for (unsigned i = 0; i < qty; i++)
            image_host_write_coil(b, addr + i, (pdu[6 + i / 8] >> (i % 8)) & 1u);
        break;
    case MODBUS_FC_WRITE_MULTIPLE_REGISTERS:
        for (unsigned i = 0; i < qty; i++)
            image_host_write_register(b, addr + i, be16(pdu + 6 + 2 * i));
        break;
    default:
        break;
    }
}

/* libmodbus builds and sends the response to a checked request (an exception when exc) on fd. */
static int reply(modbus_server_t *srv, int fd, const uint8_t *req, unsigned len, int exc)
{
    int rc;

    modbus_set_socket(srv->ctx, fd);
    if (exc)
        rc = modbus_reply_exception(srv->ctx, req, (unsigned)exc);
    else
        rc = modbus_reply(srv->ctx, req, (int)len, srv->scratch);
    modbus_set_socket(srv->ctx, -1);
    return rc;
}

/* What OpenSSL said last on this thread (its queue emptied), or what the system did. */
static const char *tls_error_text(void)
{
    unsigned long e = ERR_get_error();
    const char *reason = e ? ERR_reason_error_string(e) : NULL;

    ERR_clear_error();
    return reason ? reason : errno ? strerror(errno) : "connection closed";
}

/* The same response for a TLS client: libmodbus writes it into the socket pair, it goes out encrypted.
 * Returns its length, -1 with errno as reply() (EAGAIN: the client's socket is full), -2: a TLS error. */
static int reply_tls(modbus_server_t *srv, client_t *c, const uint8_t *req, unsigned len, int exc)
{
    uint8_t out[MODBUS_TCP_MAX_ADU_LENGTH + 16];
    ssize_t got = 0, n;
    int rc = reply(srv, srv->reply_pair[0], req, len, exc);

    /* all of it, also what a failed reply left: the next response starts clean */
    while ((size_t)got < sizeof out && (n = read(srv->reply_pair[1], out + got, sizeof out - (size_t)got)) > 0)
        got += n;
    if (rc < 0)
        return rc;
    if (got != rc) {
        errno = EMBBADDATA;
        return -1;
    }
    ERR_clear_error();
    errno = 0;
    int w = SSL_write(c->ssl, out, (int)got);
    if (w == (int)got)
        return rc;
    int e = SSL_get_error(c->ssl, w);
    if (e == SSL_ERROR_WANT_WRITE || e == SSL_ERROR_WANT_READ) {
        errno = EAGAIN;                      /* the record did not fit: a client that stopped reading */
        return -1;
    }
    return -2;
}

/* Handle one complete frame.  Returns -1 when the client was closed. */
static int handle_frame(modbus_server_t *srv, client_t *c, const uint8_t *req, unsigned len)
{
    const uint8_t *pdu = req + MBAP_HEADER;
    const unsigned pdu_len = len - MBAP_HEADER;
    const char *why;
    int exc = check_request(&srv->rt->opt, c->role, pdu, pdu_len, &why);
    const bool write = writes_something(pdu[0]);
    int rc;

    pthread_mutex_lock(&srv->rt->lock);
    if (exc == 0)
        serve_locked(srv, pdu);          /* checked whole above: a multiple write is queued whole */
    srv->requests++;
    if (exc)
        srv->exceptions++;
    if (write && exc)
        srv->writes_refused++;
    else if (write)
        srv->writes++;
    publish_counters(srv);
    pthread_mutex_unlock(&srv->rt->lock);

    if (write) {
        char what[96];
        describe_write(pdu, pdu_len, what, sizeof what);
        audit_write(srv, c, what, exc, why);
        if (exc)
            note_event(srv, EV_WRITE_REFUSED, c->peer, "role %s, %s: exception %02d, %s", role_name(c->role), what,
                       exc, why);
    }

    if (c->served == 0)
        tune_socket(c->fd);
    rc = c->ssl ? reply_tls(srv, c, req, len, exc) : reply(srv, c->fd, req, len, exc);
    if (rc == -2) {
        close_client(srv, c, EV_SOCKET_ERROR, "cannot send a TLS response: %s", tls_error_text());
        return -1;
    }
    if (rc < 0) {
        /* A non-blocking send that does not fit whole: the client stopped reading. */
        if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EMBBADDATA)
            close_client(srv, c, EV_SLOW_READER, "its socket buffer is full; %u requests served", c->served);
        else
            close_client(srv, c, EV_SOCKET_ERROR, "cannot send a response: %s", modbus_strerror(errno));
        return -1;
    }
    c->served++;
    if (c->unsent_since_ns == 0 && unsent_bytes(c->fd) > 0)
        c->unsent_since_ns = now_ns();
    return 0;
}

/* ------------------------------------------------------------------ TLS */

/* The role a client certificate names in its MBAPS role extension: a DER UTF8String, read, host or engineer.
 * false with the reason in why when it names none of them. */
static bool certificate_role(modbus_server_t *srv, X509 *cert, client_role_t *role, char *why, size_t n)
{
    int at = X509_get_ext_by_OBJ(cert, srv->role_oid, -1);

    if (at < 0) {
        snprintf(why, n, "its certificate has no role extension (OID " MBAPS_ROLE_OID ")");
        return false;
    }
    const ASN1_OCTET_STRING *data = X509_EXTENSION_get_data(X509_get_ext(cert, at));
    const unsigned char *p = ASN1_STRING_get0_data(data), *end = p + ASN1_STRING_length(data);
    ASN1_UTF8STRING *text = d2i_ASN1_UTF8STRING(NULL, &p, end - p);
    bool ok = text != NULL && p == end;

    if (!ok) {
        snprintf(why, n, "its role extension is not one UTF8String");
    } else {
        const int len = ASN1_STRING_length(text);
        const char *v = (const char *)ASN1_STRING_get0_data(text);
        if (len == 4 && memcmp(v, "read", 4) == 0)
            *role = ROLE_READ;
        else if (len == 4 && memcmp(v, "host", 4) == 0)
            *role = ROLE_HOST;
        else if (len == 8 && memcmp(v, "engineer", 8) == 0)
            *role = ROLE_ENGINEER;
        else {
            char shown[24];
            int k = 0;
            for (; k < len && k < (int)sizeof shown - 1; k++)
                shown[k] = v[k] > 0x20 && v[k] < 0x7f ? v[k] : '?';
            shown[k] = 0;
            snprintf(why, n, "its role '%s' is not read, host or engineer", shown);
            ok = false;
        }
    }
    ASN1_UTF8STRING_free(text);
    return ok;
}

/* The certificate's common name as printable ASCII without quotes ("-" without one): for the log and audit. */
static void certificate_cn(X509 *cert, char *out, size_t n)
{
    int len = X509_NAME_get_text_by_NID(X509_get_subject_name(cert), NID_commonName, out, (int)n);

    if (len <= 0) {
        snprintf(out, n, "-");
        return;
    }
    for (char *p = out; *p; p++)
        if (*p < 0x20 || *p > 0x7e || *p == '"' || *p == '\\')
            *p = '?';
}

/* One step of a TLS client's handshake; when it is done, the role its certificate names (or the client is
 * refused: no certificate, one the CA did not sign, expired, or without a known role). */
static void tls_handshake(modbus_server_t *srv, client_t *c)
{
    char why[160];

    ERR_clear_error();
    errno = 0;
    int r = SSL_do_handshake(c->ssl);
    if (r != 1) {
        int e = SSL_get_error(c->ssl, r);
        if (e == SSL_ERROR_WANT_READ || e == SSL_ERROR_WANT_WRITE) {
            c->handshake_wants_write = e == SSL_ERROR_WANT_WRITE;
            return;
        }
        long verify = SSL_get_verify_result(c->ssl);
        if (verify != X509_V_OK)
            snprintf(why, sizeof why, "certificate: %s", X509_verify_cert_error_string(verify));
        else
            snprintf(why, sizeof why, "%s", tls_error_text());
        ERR_clear_error();
        close_client(srv, c, EV_TLS_REFUSED, "%s", why);
        return;
    }
    X509 *cert = SSL_get1_peer_certificate(c->ssl);
    client_role_t role = ROLE_READ;
    bool known = cert != NULL && certificate_role(srv, cert, &role, why, sizeof why);
    if (cert)
        certificate_cn(cert, c->cn, sizeof c->cn);
    X509_free(cert);
    if (!known) {
        close_client(srv, c, EV_TLS_REFUSED, "cn \"%s\": %s", c->cn, cert ? why : "no certificate");
        return;
    }
    c->role = role;
    c->handshaking = c->handshake_wants_write = false;
    c->partial_since_ns = 0;
    note_event(srv, EV_TLS_AUTHENTICATED, c->peer, "%s, cn \"%s\", role %s", SSL_get_version(c->ssl), c->cn,
               role_name(role));
}

/* recv() of a plain client, SSL_read() of a TLS one, with recv()'s results: 0 closed, -1 with errno
 * (EAGAIN: nothing now; EPROTO: a TLS error, its reason in *why). */
static ssize_t client_recv(client_t *c, uint8_t *buf, size_t n, const char **why)
{
    if (!c->ssl)
        return recv(c->fd, buf, n, 0);
    ERR_clear_error();
    errno = 0;
    int r = SSL_read(c->ssl, buf, (int)n);
    if (r > 0)
        return r;
    switch (SSL_get_error(c->ssl, r)) {
    case SSL_ERROR_WANT_READ:
    case SSL_ERROR_WANT_WRITE:
        errno = EAGAIN;
        return -1;
    case SSL_ERROR_ZERO_RETURN:
        return 0;
    case SSL_ERROR_SYSCALL:
        if (errno == 0)
            return 0;
        return -1;
    default:
        *why = tls_error_text();
        errno = EPROTO;
        return -1;
    }
}

/* Whether a TLS client has decrypted bytes waiting in OpenSSL (select() does not see them). */
static bool tls_pending(const client_t *c)
{
    return c->ssl && !c->handshaking && c->unsent_since_ns == 0 && SSL_pending(c->ssl) > 0;
}

/* ------------------------------------------------------------- receive */

/* Serve the complete requests in a client's buffer.  -1 when the client was closed. */
static int take_frames(modbus_server_t *srv, client_t *c)
{
    while (c->len >= MBAP_HEADER) {
        const unsigned protocol = be16(c->buf + 2);
        const unsigned length = be16(c->buf + 4);     /* unit id + PDU */

        if (protocol != 0) {
            close_client(srv, c, EV_NOT_MODBUS, "protocol id %u", protocol);
            return -1;
        }
        if (length < 2 || length > MBAP_MAX_LENGTH) {
            close_client(srv, c, EV_NOT_MODBUS, "MBAP length %u outside 2..%u", length, MBAP_MAX_LENGTH);
            return -1;
        }
        const unsigned frame = 6 + length;
        if (c->len < frame)
            break;                                /* wait for the rest */
        if (handle_frame(srv, c, c->buf, frame) < 0)
            return -1;
        memmove(c->buf, c->buf + frame, c->len - frame);
        c->len -= frame;
        c->partial_since_ns = 0;
    }
    if (c->len == 0)
        c->partial_since_ns = 0;
    else if (c->partial_since_ns == 0)
        c->partial_since_ns = now_ns();
    return 0;
}

static void read_client(modbus_server_t *srv, client_t *c)
{
    do {
        const char *why = NULL;
        ssize_t n = client_recv(c, c->buf + c->len, sizeof c->buf - c->len, &why);
        if (n == 0) {
            close_client(srv, c, EV_CLOSED, "%s", "");
            return;
        }
        if (n < 0) {
            if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)
                close_client(srv, c, EV_SOCKET_ERROR, "%s", why ? why : strerror(errno));
            return;
        }
        c->len += (size_t)n;
        if (take_frames(srv, c) < 0)
            return;
    } while (tls_pending(c));        /* a TLS record holds more than the buffer took */
}

/* Drop half-received requests and stalled readers whose time is up; return
 * the next instant a check is due (UINT64_MAX: none). */
static uint64_t enforce_timeouts(modbus_server_t *srv, uint64_t t)
{
    const uint64_t limit = srv->frame_timeout_ns;
    uint64_t next = UINT64_MAX;

    for (int i = 0; i < srv->rt->opt.max_clients; i++) {
        client_t *c = &srv->clients[i];
        if (c->fd < 0)
            continue;
        if (c->unsent_since_ns) {
            int unsent = unsent_bytes(c->fd);
            if (unsent == 0) {
                c->unsent_since_ns = 0;                   /* reading again: its requests are read again */
                if (c->len > 0)
                    c->partial_since_ns = t;              /* the rest was held back by us, not by it */
            } else if (t - c->unsent_since_ns >= limit) {
                close_client(srv, c, EV_SLOW_READER, "%d response bytes unsent for %llu ms", unsent,
                             (unsigned long long)(limit / 1000000u));
                continue;
            } else {
                if (t + UNSENT_POLL_NS < next)
                    next = t + UNSENT_POLL_NS;
                continue;                                 /* not read meanwhile: no frame timeout */
            }
        }
        if (c->partial_since_ns) {
            if (t - c->partial_since_ns >= limit && c->handshaking) {
                close_client(srv, c, EV_TLS_TIMEOUT, "after %llu ms", (unsigned long long)(limit / 1000000u));
                continue;
            }
            if (t - c->partial_since_ns >= limit) {
                close_client(srv, c, EV_FRAME_TIMEOUT, "%zu bytes of a request after %llu ms", c->len,
                             (unsigned long long)(limit / 1000000u));
                continue;
            }
            if (c->partial_since_ns + limit < next)
                next = c->partial_since_ns + limit;
        }
    }
    return next;
}

/* --------------------------------------------------------------- thread */

/* With real-time scheduling on, the server thread runs SCHED_FIFO below the scan
 * thread: the CNC's requests are answered in time however busy the machine is,
 * and the scan still preempts the network. */
static void setup_priority(modbus_server_t *srv)
{
    rt_thread_name("modbus-server");
    int prio = rt_thread_fifo(srv->rt, -PRIORITY_BELOW_SCAN);
    if (prio < 0)
        log_msg(srv->rt->log, LOG_INFO, "modbus: server thread at normal priority (SCHED_FIFO: %s)", strerror(-prio));
    else if (prio > 0)
        log_msg(srv->rt->log, LOG_INFO, "modbus: server thread is SCHED_FIFO priority %d", prio);
}

static void *server_thread(void *arg)
{
    modbus_server_t *srv = arg;
    const int max = srv->rt->opt.max_clients;

    setup_priority(srv);

    for (;; srv->round++) {
        fd_set rfds, wfds;
        int top = srv->listen_fd > srv->wake[0] ? srv->listen_fd : srv->wake[0];
        bool pending = false;                             /* a TLS client with bytes OpenSSL holds */
        uint64_t t = now_ns();
        uint64_t due = enforce_timeouts(srv, t);
        uint64_t flush = flush_events(srv, t, false);
        struct timeval tv, *wait = NULL;

        if (flush < due)
            due = flush;
        if (srv->audit_held_ok + srv->audit_held_refused > 0) {
            if (t - srv->audit_window_ns >= EVENT_WINDOW_NS)
                audit_summary(srv, t);
            else if (srv->audit_window_ns + EVENT_WINDOW_NS < due)
                due = srv->audit_window_ns + EVENT_WINDOW_NS;
        }
        if (due != UINT64_MAX) {
            uint64_t left = due > t ? due - t : 0;
            left += 999;                                  /* round up to whole microseconds */
            tv.tv_sec = (time_t)(left / 1000000000u);
            tv.tv_usec = (suseconds_t)(left % 1000000000u / 1000u);
            wait = &tv;
        }
        FD_ZERO(&rfds);
        FD_ZERO(&wfds);
        FD_SET(srv->listen_fd, &rfds);
        FD_SET(srv->wake[0], &rfds);
        if (srv->tls_listen_fd >= 0) {
            FD_SET(srv->tls_listen_fd, &rfds);
            if (srv->tls_listen_fd > top)
                top = srv->tls_listen_fd;
        }
        for (int i = 0; i < max; i++) {
            /* A client that leaves its responses unread gets no more answers to build:
             * its requests wait in its own socket until it reads or the timeout drops it. */
            const client_t *c = &srv->clients[i];
            if (c->fd >= 0 && c->unsent_since_ns == 0) {
                FD_SET(c->fd, c->handshake_wants_write ? &wfds : &rfds);
                if (c->fd > top)
                    top = c->fd;
                pending = pending || tls_pending(c);
            }
        }
        if (pending) {
            tv.tv_sec = 0;
            tv.tv_usec = 0;
            wait = &tv;                                   /* serve them now, after a look at the sockets */
        }
        int ready = select(top + 1, &rfds, &wfds, NULL, wait);
        if (ready < 0) {
            if (errno == EINTR)
                continue;
            log_msg(srv->rt->log, LOG_ERROR, "modbus: select failed: %s", strerror(errno));
            struct timespec pause = { 0, 10000000 };      /* 10 ms, then select again */
            nanosleep(&pause, NULL);
            continue;
        }
        if (ready == 0 && !pending)
            continue;                                     /* a timeout is due */
        if (FD_ISSET(srv->wake[0], &rfds))
            break;
        /* Clients already served first (the CNC), then the newcomers and the suspects. */
        for (int pass = 0; pass < 2; pass++)
            for (int i = 0; i < max; i++) {
                client_t *c = &srv->clients[i];
                if (c->fd < 0 || (c->served > 0) != (pass == 0))
                    continue;
                if (FD_ISSET(c->fd, &rfds) || FD_ISSET(c->fd, &wfds) || tls_pending(c)) {
                    FD_CLR(c->fd, &rfds);
                    FD_CLR(c->fd, &wfds);
                    if (c->handshaking)
                        tls_handshake(srv, c);
                    else
                        read_client(srv, c);
                }
            }
        if (FD_ISSET(srv->listen_fd, &rfds))
            accept_clients(srv, srv->listen_fd, false);
        if (srv->tls_listen_fd >= 0 && FD_ISSET(srv->tls_listen_fd, &rfds))
            accept_clients(srv, srv->tls_listen_fd, true);
    }

    for (int i = 0; i < max; i++)
        if (srv->clients[i].fd >= 0)
            close_client(srv, &srv->clients[i], EV_STOPPING, "%s", "");
    flush_events(srv, now_ns(), true);
    audit_summary(srv, now_ns());
    return NULL;
}

static void destroy(modbus_server_t *srv)
{
    if (srv->listen_fd >= 0)
        close(srv->listen_fd);
    if (srv->tls_listen_fd >= 0)
        close(srv->tls_listen_fd);
    for (int i = 0; i < 2; i++)
        if (srv->reply_pair[i] >= 0)
            close(srv->reply_pair[i]);
    SSL_CTX_free(srv->tls);
    ASN1_OBJECT_free(srv->role_oid);
    if (srv->wake[0] >= 0)
        close(srv->wake[0]);
    if (srv->wake[1] >= 0)
        close(srv->wake[1]);
    if (srv->scratch)
        modbus_mapping_free(srv->scratch);
    if (srv->ctx)
        modbus_free(srv->ctx);
    free(srv->clients);
    free(srv);
}

static int probe_address(runtime_t *rt, const char *addr, int port, const char *what)
{
    struct sockaddr_in sa = { .sin_family = AF_INET, .sin_port = htons((uint16_t)port) };
    int one = 1, fd, rc;

    if (inet_pton(AF_INET, addr, &sa.sin_addr) != 1)
        return 0;                   /* modbus_server_start names the bad address */
    fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return 0;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);     /* as libmodbus listens */
    rc = bind(fd, (struct sockaddr *)&sa, sizeof sa);
    if (rc != 0)
        log_msg(rt->log, LOG_ERROR, "modbus: cannot listen%s on %s:%d: %s", what, addr, port, strerror(errno));
    close(fd);
    return rc == 0 ? 0 : -1;
}

int modbus_server_probe(runtime_t *rt)
{
    const rt_options_t *opt = &rt->opt;

    if (probe_address(rt, opt->bind, opt->port, "") != 0)
        return -1;
    return opt->tls_cert ? probe_address(rt, opt->tls_bind, opt->tls_port, " for TLS") : 0;
}

/* The server's TLS context: its certificate and key, the CA a client's certificate must be signed by, TLS 1.2
 * at least, no renegotiation, no session tickets or cache.  NULL (logged, naming the file) when one does not
 * load. */
static SSL_CTX *tls_context(runtime_t *rt)
{
    const rt_options_t *opt = &rt->opt;
    const char *what = NULL, *file = "";
    STACK_OF(X509_NAME) *names = NULL;

    ERR_clear_error();
    errno = 0;
    SSL_CTX *ctx = SSL_CTX_new(TLS_server_method());
    if (!ctx || SSL_CTX_set_min_proto_version(ctx, TLS1_2_VERSION) != 1)
        what = "cannot create the TLS context";
    else if (SSL_CTX_use_certificate_chain_file(ctx, opt->tls_cert) != 1)
        what = "cannot load the server certificate (PEM) ", file = opt->tls_cert;
    else if (SSL_CTX_use_PrivateKey_file(ctx, opt->tls_key, SSL_FILETYPE_PEM) != 1)
        what = "cannot load the private key (PEM) ", file = opt->tls_key;
    else if (SSL_CTX_check_private_key(ctx) != 1)
        what = "the private key does not belong to the server certificate: ", file = opt->tls_key;
    else if (SSL_CTX_load_verify_locations(ctx, opt->tls_ca, NULL) != 1 || !(names = SSL_load_client_CA_file(opt->tls_ca)))
        what = "cannot load the CA certificate(s) (PEM) ", file = opt->tls_ca;
    if (what) {
        log_msg(rt->log, LOG_ERROR, "modbus: TLS: %s%s: %s", what, file, tls_error_text());
        SSL_CTX_free(ctx);
        return NULL;
    }
    SSL_CTX_set_client_CA_list(ctx, names);
    SSL_CTX_set_verify(ctx, SSL_VERIFY_PEER | SSL_VERIFY_FAIL_IF_NO_PEER_CERT, NULL);
    SSL_CTX_set_options(ctx, SSL_OP_NO_RENEGOTIATION | SSL_OP_IGNORE_UNEXPECTED_EOF | SSL_OP_NO_TICKET);
    SSL_CTX_set_num_tickets(ctx, 0);
    SSL_CTX_set_session_cache_mode(ctx, SSL_SESS_CACHE_OFF);
    return ctx;
}

int modbus_server_check_tls(runtime_t *rt)
{
    if (!rt->opt.tls_cert)
        return 0;
    SSL_CTX *ctx = tls_context(rt);
    SSL_CTX_free(ctx);
    return ctx ? 0 : -1;
}

/* The TLS listener's socket (non-blocking), or -1 (logged). */
static int listen_tls(runtime_t *rt)
{
    const rt_options_t *opt = &rt->opt;
    struct sockaddr_in sa = { .sin_family = AF_INET, .sin_port = htons((uint16_t)opt->tls_port) };
    int one = 1, fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);

    if (fd < 0 || inet_pton(AF_INET, opt->tls_bind, &sa.sin_addr) != 1
        || setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one) != 0
        || bind(fd, (struct sockaddr *)&sa, sizeof sa) != 0 || listen(fd, LISTEN_BACKLOG) != 0) {
        log_msg(rt->log, LOG_ERROR, "modbus: cannot listen for TLS on %s:%d: %s", opt->tls_bind, opt->tls_port,
                strerror(errno));
        if (fd >= 0)
            close(fd);
        return -1;
    }
    return fd;
}

int modbus_server_start(runtime_t *rt, modbus_server_t **out)
{
    const rt_options_t *opt = &rt->opt;
    modbus_server_t *srv = calloc(1, sizeof *srv);
    struct in_addr ia;
    struct sockaddr_in bound;
    socklen_t blen = sizeof bound;
    char allow_text[400] = "any address";

    if (!srv)
        return -1;
    srv->rt = rt;
    srv->frame_timeout_ns = (uint64_t)opt->frame_timeout_ms * 1000000u;
    srv->listen_fd = srv->wake[0] = srv->wake[1] = -1;
    srv->tls_listen_fd = srv->reply_pair[0] = srv->reply_pair[1] = -1;
    srv->clients = calloc((size_t)opt->max_clients, sizeof *srv->clients);
    if (!srv->clients) {
        destroy(srv);
        return -1;
    }
    for (int i = 0; i < opt->max_clients; i++)
        srv->clients[i].fd = -1;

    /* libmodbus listens on every interface for any address starting with '0'. */
    if (inet_pton(AF_INET, opt->bind, &ia) != 1 || (opt->bind[0] == '0' && ia.s_addr != 0)) {
        log_msg(rt->log, LOG_ERROR, "modbus: bind address '%s' is not a usable IPv4 address", opt->bind);
        destroy(srv);
        return -1;
    }
    srv->ctx = modbus_new_tcp(opt->bind, opt->port);
    srv->scratch = modbus_mapping_new((int)MAP_BITS, (int)MAP_BITS, (int)MAP_HOLDING, (int)MAP_INPUT_REGS);
    if (!srv->ctx || !srv->scratch) {
        log_msg(rt->log, LOG_ERROR, "modbus: cannot create the libmodbus context: %s", modbus_strerror(errno));
        destroy(srv);
        return -1;
    }
    srv->listen_fd = modbus_tcp_listen(srv->ctx, LISTEN_BACKLOG);
    if (srv->listen_fd < 0) {
        log_msg(rt->log, LOG_ERROR, "modbus: cannot listen on %s:%d: %s", opt->bind, opt->port,
                modbus_strerror(errno));
        destroy(srv);
        return -1;
    }
    fcntl(srv->listen_fd, F_SETFL, fcntl(srv->listen_fd, F_GETFL) | O_NONBLOCK);
    fcntl(srv->listen_fd, F_SETFD, FD_CLOEXEC);
    if (pipe2(srv->wake, O_CLOEXEC) != 0) {
        log_msg(rt->log, LOG_ERROR, "modbus: pipe: %s", strerror(errno));
        destroy(srv);
        return -1;
    }
    getsockname(srv->listen_fd, (struct sockaddr *)&bound, &blen);

    if (opt->n_allow > 0) {
        size_t used = 0;
        allow_text[0] = 0;
        for (int i = 0; i < opt->n_allow && used < sizeof allow_text - 40; i++) {
            struct in_addr a = { htonl(opt->allow[i].addr) };
            char ip[INET_ADDRSTRLEN];
            inet_ntop(AF_INET, &a, ip, sizeof ip);
            used += (size_t)snprintf(allow_text + used, sizeof allow_text - used, "%s%s/%d%s%s", i ? ", " : "", ip,
                                     __builtin_popcount(opt->allow[i].mask),
                                     opt->allow[i].role == ROLE_ENGINEER ? "" : " as ",
                                     opt->allow[i].role == ROLE_ENGINEER ? "" : role_name(opt->allow[i].role));
        }
    }
    log_msg(rt->log, LOG_INFO, "modbus: listening on %s:%u (max %d clients, clients allowed from %s, "
            "frame timeout %d ms%s)", opt->bind, ntohs(bound.sin_port), opt->max_clients, allow_text,
            opt->frame_timeout_ms, opt->read_only ? ", READ-ONLY: every write refused" : "");

    if (opt->tls_cert) {
        srv->role_oid = OBJ_txt2obj(MBAPS_ROLE_OID, 1);
        srv->tls = tls_context(rt);
        if (!srv->role_oid || !srv->tls || (srv->tls_listen_fd = listen_tls(rt)) < 0) {
            destroy(srv);
            return -1;
        }
        if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, srv->reply_pair) != 0) {
            log_msg(rt->log, LOG_ERROR, "modbus: socketpair: %s", strerror(errno));
            destroy(srv);
            return -1;
        }
        fcntl(srv->reply_pair[1], F_SETFL, fcntl(srv->reply_pair[1], F_GETFL) | O_NONBLOCK);
        blen = sizeof bound;
        getsockname(srv->tls_listen_fd, (struct sockaddr *)&bound, &blen);
        log_msg(rt->log, LOG_INFO, "modbus: TLS (Modbus/TCP Security) on %s:%u: TLS 1.2 or later, client "
                "certificates signed by %s, role from their extension " MBAPS_ROLE_OID " (read, host or engineer; "
                "none: refused), the same %d slots and %d ms for a handshake", opt->tls_bind, ntohs(bound.sin_port),
                opt->tls_ca, opt->max_clients, opt->frame_timeout_ms);
    }

    update_counters(srv);
    if (pthread_create(&srv->thread, NULL, server_thread, srv) != 0) {
        log_msg(rt->log, LOG_ERROR, "modbus: cannot start the server thread");
        destroy(srv);
        return -1;
    }
    srv->thread_started = true;
    *out = srv;
    return 0;
}

void modbus_server_stop(modbus_server_t *srv)
{
    if (!srv)
        return;
    if (srv->thread_started) {
        ssize_t w = write(srv->wake[1], "x", 1);
        (void)w;
        pthread_join(srv->thread, NULL);
    }
    destroy(srv);
}
