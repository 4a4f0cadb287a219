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
 * range, host-writable range), so modbus_reply() only ever answers valid
 * requests.  That matters: on a bad quantity modbus_reply() would sleep for
 * the response timeout and flush the socket, and for function codes 0x11,
 * 0x16 and 0x17 it would answer by itself.
 *
 * Locking: the image lock is held only to copy the registers a request reads
 * into a scratch mapping, or to queue the values it writes; never during a
 * socket call.  Client sockets are non-blocking; a client that stops reading
 * its responses until its socket buffer is full is disconnected.  Allowed
 * clients are never disconnected for being idle (mb2hal never reconnects);
 * TCP keepalive only frees the slots of peers that have vanished.
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <modbus.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

#include "runtime.h"

#define MBAP_HEADER 7u                /* transaction id, protocol id, length, unit id */
#define MBAP_MAX_LENGTH 254u          /* unit id + the largest PDU (253 bytes) */
#define CLIENT_BUFFER (2u * (6u + MBAP_MAX_LENGTH))

/* Modbus exception codes */
#define EXC_ILLEGAL_FUNCTION 1
#define EXC_ILLEGAL_ADDRESS 2
#define EXC_ILLEGAL_VALUE 3

typedef struct client {
    int fd;                           /* -1: free slot */
    size_t len;
    uint8_t buf[CLIENT_BUFFER];
    char peer[INET_ADDRSTRLEN + 8];
} client_t;

struct modbus_server {
    runtime_t *rt;
    modbus_t *ctx;
    modbus_mapping_t *scratch;        /* what modbus_reply() reads from and writes into */
    int listen_fd;
    int wake[2];                      /* self-pipe: stop request */
    pthread_t thread;
    bool thread_started;
    client_t *clients;
    int n_clients;
    uint32_t requests, exceptions, refused;
    uint64_t last_refusal_log_ns;
    unsigned refusals_not_logged;
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
}

static void update_counters(modbus_server_t *srv)
{
    pthread_mutex_lock(&srv->rt->lock);
    publish_counters(srv);
    pthread_mutex_unlock(&srv->rt->lock);
}

static bool allowed(const rt_options_t *opt, uint32_t addr)
{
    if (opt->n_allow == 0)
        return true;
    for (int i = 0; i < opt->n_allow; i++)
        if ((addr & opt->allow[i].mask) == opt->allow[i].addr)
            return true;
    return false;
}

static void close_client(modbus_server_t *srv, client_t *c, const char *why)
{
    log_msg(srv->rt->log, LOG_INFO, "modbus: client %s disconnected (%s)", c->peer, why);
    close(c->fd);
    c->fd = -1;
    c->len = 0;
    srv->n_clients--;
    update_counters(srv);
}

/* --------------------------------------------------------------- accept */

static void refuse(modbus_server_t *srv, int fd, const char *peer, const char *why)
{
    uint64_t t = now_ns();

    close(fd);
    srv->refused++;
    update_counters(srv);
    /* One line per second at most, so a connection flood cannot flood the log. */
    if (t - srv->last_refusal_log_ns >= 1000000000u || srv->last_refusal_log_ns == 0) {
        if (srv->refusals_not_logged)
            log_msg(srv->rt->log, LOG_WARN, "modbus: connection from %s refused: %s (and %u more refusals not logged)",
                    peer, why, srv->refusals_not_logged);
        else
            log_msg(srv->rt->log, LOG_WARN, "modbus: connection from %s refused: %s", peer, why);
        srv->last_refusal_log_ns = t;
        srv->refusals_not_logged = 0;
    } else {
        srv->refusals_not_logged++;
    }
}

static void accept_clients(modbus_server_t *srv)
{
    const rt_options_t *opt = &srv->rt->opt;

    for (;;) {
        struct sockaddr_in sa;
        socklen_t salen = sizeof sa;
        char peer[INET_ADDRSTRLEN + 8], ip[INET_ADDRSTRLEN];
        int fd = accept4(srv->listen_fd, (struct sockaddr *)&sa, &salen, SOCK_NONBLOCK | SOCK_CLOEXEC);

        if (fd < 0) {
            if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR && errno != ECONNABORTED)
                log_msg(srv->rt->log, LOG_WARN, "modbus: accept failed: %s", strerror(errno));
            return;
        }
        if (!inet_ntop(AF_INET, &sa.sin_addr, ip, sizeof ip))
            snprintf(ip, sizeof ip, "?");
        snprintf(peer, sizeof peer, "%s:%u", ip, ntohs(sa.sin_port));

        if (!allowed(opt, ntohl(sa.sin_addr.s_addr))) {
            refuse(srv, fd, peer, "address not in the allowlist");
            continue;
        }
        if (srv->n_clients >= opt->max_clients) {
            char why[96];
            snprintf(why, sizeof why, "limit of %d clients reached (max_clients)", opt->max_clients);
            refuse(srv, fd, peer, why);
            continue;
        }
        if (fd >= FD_SETSIZE) {
            refuse(srv, fd, peer, "descriptor number too high for select()");
            continue;
        }
        int one = 1, idle = 60, intvl = 10, cnt = 6;
        setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        setsockopt(fd, SOL_SOCKET, SO_KEEPALIVE, &one, sizeof one);
        setsockopt(fd, IPPROTO_TCP, TCP_KEEPIDLE, &idle, sizeof idle);
        setsockopt(fd, IPPROTO_TCP, TCP_KEEPINTVL, &intvl, sizeof intvl);
        setsockopt(fd, IPPROTO_TCP, TCP_KEEPCNT, &cnt, sizeof cnt);

        for (int i = 0; i < opt->max_clients; i++) {
            client_t *c = &srv->clients[i];
            if (c->fd >= 0)
                continue;
            c->fd = fd;
            c->len = 0;
            snprintf(c->peer, sizeof c->peer, "%s", peer);
            srv->n_clients++;
            break;
        }
        update_counters(srv);
        log_msg(srv->rt->log, LOG_INFO, "modbus: client %s connected (%d of %d)", peer, srv->n_clients,
                opt->max_clients);
    }
}

/* ------------------------------------------------------------- requests */

/* Check a request.  Returns 0 when it may be served, else the exception code.
 * pdu points at the function code, pdu_len counts it. */
static int check_request(const rt_options_t *opt, const uint8_t *pdu, unsigned pdu_len)
{
    const unsigned fc = pdu[0];

    if (fc != 1 && fc != 2 && fc != 3 && fc != 4 && fc != 5 && fc != 6 && fc != 15 && fc != 16)
        return EXC_ILLEGAL_FUNCTION;
    if (pdu_len < 5)
        return EXC_ILLEGAL_VALUE;

    const unsigned addr = be16(pdu + 1);
    const unsigned qty = be16(pdu + 3);     /* the value for FC 5 and 6 */

    switch (fc) {
    case 1: case 2: case 3: case 4: {
        const unsigned max = fc <= 2 ? MODBUS_MAX_READ_BITS : MODBUS_MAX_READ_REGISTERS;
        const unsigned size = fc <= 2 ? MAP_BITS : fc == 3 ? MAP_HOLDING : MAP_INPUT_REGS;
        if (pdu_len != 5 || qty < 1 || qty > max)
            return EXC_ILLEGAL_VALUE;
        if (addr + qty > size)
            return EXC_ILLEGAL_ADDRESS;
        return 0;
    }
    case 5:
        if (pdu_len != 5 || (qty != 0x0000 && qty != 0xFF00))
            return EXC_ILLEGAL_VALUE;
        if (addr >= MAP_BITS || !addr_set_has(&opt->writable_coils, addr))
            return EXC_ILLEGAL_ADDRESS;
        return 0;
    case 6:
        if (pdu_len != 5)
            return EXC_ILLEGAL_VALUE;
        if (addr >= MAP_HOLDING || !addr_set_has(&opt->writable_registers, addr))
            return EXC_ILLEGAL_ADDRESS;
        return 0;
    default: {                                  /* 15 and 16 */
        const unsigned max = fc == 15 ? MODBUS_MAX_WRITE_BITS : MODBUS_MAX_WRITE_REGISTERS;
        const unsigned size = fc == 15 ? MAP_BITS : MAP_HOLDING;
        const addr_set_t *w = fc == 15 ? &opt->writable_coils : &opt->writable_registers;
        if (pdu_len < 6 || qty < 1 || qty > max)
            return EXC_ILLEGAL_VALUE;
        const unsigned bytes = fc == 15 ? (qty + 7) / 8 : 2 * qty;
        if (pdu[5] != bytes || pdu_len != 6 + bytes)
            return EXC_ILLEGAL_VALUE;
        if (addr + qty > size)
            return EXC_ILLEGAL_ADDRESS;
        for (unsigned a = addr; a < addr + qty; a++)
            if (!addr_set_has(w, a))
                return EXC_ILLEGAL_ADDRESS;
        return 0;
    }
    }
}

/* Copy what a valid request reads into the scratch mapping, or queue what it
 * writes into the image.  Caller holds the image lock. */
static void serve_locked(modbus_server_t *srv, const uint8_t *pdu)
{
    bus_image_t *b = &srv->rt->bimg;
    modbus_mapping_t *m = srv->scratch;
    const unsigned fc = pdu[0], addr = be16(pdu + 1), qty = be16(pdu + 3);

    switch (fc) {
    case 1:
        memcpy(m->tab_bits + addr, b->coils + addr, qty);
        break;
    case 2:
        memcpy(m->tab_input_bits + addr, b->discrete + addr, qty);
        break;
    case 3:
        memcpy(m->tab_registers + addr, b->holding + addr, 2u * qty);
        break;
    case 4:
        memcpy(m->tab_input_registers + addr, b->input_regs + addr, 2u * qty);
        break;
    case 5:
        image_host_write_coil(b, addr, qty == 0xFF00);
        break;
    case 6:
        image_host_write_register(b, addr, (uint16_t)qty);
        break;
    case 15:
        for (unsigned i = 0; i < qty; i++)
            image_host_write_coil(b, addr + i, (pdu[6 + i / 8] >> (i % 8)) & 1u);
        break;
    case 16:
        for (unsigned i = 0; i < qty; i++)
            image_host_write_register(b, addr + i, be16(pdu + 6 + 2 * i));
        break;
    default:
        break;
    }
}

/* Handle one complete frame.  Returns -1 when the client must be closed. */
static int handle_frame(modbus_server_t *srv, client_t *c, const uint8_t *req, unsigned len)
{
    const uint8_t *pdu = req + MBAP_HEADER;
    const unsigned pdu_len = len - MBAP_HEADER;
    int exc = check_request(&srv->rt->opt, pdu, pdu_len);
    int rc;

    pthread_mutex_lock(&srv->rt->lock);
    if (exc == 0)
        serve_locked(srv, pdu);
    srv->requests++;
    if (exc)
        srv->exceptions++;
    publish_counters(srv);
    pthread_mutex_unlock(&srv->rt->lock);

    modbus_set_socket(srv->ctx, c->fd);
    if (exc)
        rc = modbus_reply_exception(srv->ctx, req, (unsigned)exc);
    else
        rc = modbus_reply(srv->ctx, req, (int)len, srv->scratch);
    modbus_set_socket(srv->ctx, -1);
    if (rc < 0) {
        char why[128];
        snprintf(why, sizeof why, "cannot send a response: %s", modbus_strerror(errno));
        close_client(srv, c, why);
        return -1;
    }
    return 0;
}

static void read_client(modbus_server_t *srv, client_t *c)
{
    ssize_t n = recv(c->fd, c->buf + c->len, sizeof c->buf - c->len, 0);

    if (n == 0) {
        close_client(srv, c, "closed by the client");
        return;
    }
    if (n < 0) {
        if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)
            close_client(srv, c, strerror(errno));
        return;
    }
    c->len += (size_t)n;

    while (c->len >= MBAP_HEADER) {
        const unsigned protocol = be16(c->buf + 2);
        const unsigned length = be16(c->buf + 4);     /* unit id + PDU */
        char why[96];

        if (protocol != 0) {
            snprintf(why, sizeof why, "protocol id %u in the MBAP header, not Modbus", protocol);
            close_client(srv, c, why);
            return;
        }
        if (length < 2 || length > MBAP_MAX_LENGTH) {
            snprintf(why, sizeof why, "MBAP length %u outside 2..%u", length, MBAP_MAX_LENGTH);
            close_client(srv, c, why);
            return;
        }
        const unsigned frame = 6 + length;
        if (c->len < frame)
            return;                               /* wait for the rest */
        if (handle_frame(srv, c, c->buf, frame) < 0)
            return;
        memmove(c->buf, c->buf + frame, c->len - frame);
        c->len -= frame;
    }
}

/* --------------------------------------------------------------- thread */

static void *server_thread(void *arg)
{
    modbus_server_t *srv = arg;
    const int max = srv->rt->opt.max_clients;

    for (;;) {
        fd_set rfds;
        int top = srv->listen_fd > srv->wake[0] ? srv->listen_fd : srv->wake[0];

        FD_ZERO(&rfds);
        FD_SET(srv->listen_fd, &rfds);
        FD_SET(srv->wake[0], &rfds);
        for (int i = 0; i < max; i++) {
            if (srv->clients[i].fd >= 0) {
                FD_SET(srv->clients[i].fd, &rfds);
                if (srv->clients[i].fd > top)
                    top = srv->clients[i].fd;
            }
        }
        if (select(top + 1, &rfds, NULL, NULL, NULL) < 0) {
            if (errno == EINTR)
                continue;
            log_msg(srv->rt->log, LOG_ERROR, "modbus: select failed: %s", strerror(errno));
            usleep(10000);
            continue;
        }
        if (FD_ISSET(srv->wake[0], &rfds))
            break;
        for (int i = 0; i < max; i++)
            if (srv->clients[i].fd >= 0 && FD_ISSET(srv->clients[i].fd, &rfds))
                read_client(srv, &srv->clients[i]);
        if (FD_ISSET(srv->listen_fd, &rfds))
            accept_clients(srv);
    }

    for (int i = 0; i < max; i++)
        if (srv->clients[i].fd >= 0)
            close_client(srv, &srv->clients[i], "runtime stopping");
    return NULL;
}

static void destroy(modbus_server_t *srv)
{
    if (srv->listen_fd >= 0)
        close(srv->listen_fd);
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

int modbus_server_start(runtime_t *rt, modbus_server_t **out)
{
    const rt_options_t *opt = &rt->opt;
    modbus_server_t *srv = calloc(1, sizeof *srv);
    struct in_addr ia;
    struct sockaddr_in bound;
    socklen_t blen = sizeof bound;
    char allow_text[256] = "any address";

    if (!srv)
        return -1;
    srv->rt = rt;
    srv->listen_fd = srv->wake[0] = srv->wake[1] = -1;
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
    srv->listen_fd = modbus_tcp_listen(srv->ctx, 64);
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
            used += (size_t)snprintf(allow_text + used, sizeof allow_text - used, "%s%s/%d", i ? ", " : "", ip,
                                     __builtin_popcount(opt->allow[i].mask));
        }
    }
    log_msg(rt->log, LOG_INFO, "modbus: listening on %s:%u (max %d clients, clients allowed from %s)",
            opt->bind, ntohs(bound.sin_port), opt->max_clients, allow_text);

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
