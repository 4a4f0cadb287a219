/*
 * mbload.c - Modbus/TCP load client for the runtime tests and benchmark.
 *
 * N client threads, each on its own connection, run the same cycle of three
 * requests, one at a time, and check every response:
 *   1. FC16 writes [client id, sequence] to its own two holding registers
 *      (BASE + 2 * client id);
 *   2. FC3 reads them back: they must hold exactly what this client wrote;
 *   3. FC3 reads %QW20..%QW21, which the fixture program sets to the tick at
 *      the start and at the end of each scan: both words must be equal (no
 *      half-finished scan) and never go backwards for this client.
 * Each request carries a transaction id unique to its client; the response
 * must echo it, with the same function code and the expected length.
 *
 * Prints one JSON line: requests, errors, requests per second, latency
 * percentiles.  Exit status 0 when there was no error.
 *
 * With --tls-cert/--tls-key/--tls-ca each connection is Modbus/TCP Security
 * (TLS with this client certificate, the server's verified against the CA);
 * the handshake is done before the clock starts.
 *
 *   mbload --port N [--host A] [--clients C] [--requests R | --duration S] [--base B]
 *          [--tls-cert F --tls-key F --tls-ca F]
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <getopt.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <openssl/ssl.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>

typedef struct worker {
    int id;
    pthread_t thread;
    uint32_t *lat_ns;
    long done;
    long errors;
    char first_error[160];
} worker_t;

static const char *host = "127.0.0.1";
static int port = 0, clients = 16, base = 1200;   /* %MW176.. : unused by the fixture */
static long requests = 10000;
static double duration = 0;
static pthread_barrier_t start_line;
static SSL_CTX *tls;                  /* NULL: plain Modbus/TCP */

static uint64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

static void fail(worker_t *w, const char *fmt, long k, long a, long b)
{
    if (w->errors++ == 0)
        snprintf(w->first_error, sizeof w->first_error, fmt, w->id, k, a, b);
}

static int recv_all(int fd, SSL *ssl, uint8_t *p, size_t n)
{
    while (n > 0) {
        ssize_t r = ssl ? SSL_read(ssl, p, (int)n) : recv(fd, p, n, 0);
        if (r <= 0)
            return -1;
        p += r;
        n -= (size_t)r;
    }
    return 0;
}

/* Send one request, receive its response; returns the response PDU length or -1. */
static int transact(int fd, SSL *ssl, const uint8_t *req, size_t len, uint8_t *rsp, size_t cap)
{
    if ((ssl ? SSL_write(ssl, req, (int)len) : send(fd, req, len, MSG_NOSIGNAL)) != (ssize_t)len)
        return -1;
    if (recv_all(fd, ssl, rsp, 7) != 0)
        return -1;
    size_t mlen = (size_t)(rsp[4] << 8 | rsp[5]);
    if (mlen < 2 || 6 + mlen > cap)
        return -1;
    if (recv_all(fd, ssl, rsp + 7, mlen - 1) != 0)
        return -1;
    return (int)(mlen - 1);
}

static void *run_worker(void *arg)
{
    worker_t *w = arg;
    struct sockaddr_in sa = { .sin_family = AF_INET, .sin_port = htons((uint16_t)port) };
    uint8_t req[64], rsp[300];
    int fd = socket(AF_INET, SOCK_STREAM, 0), one = 1;
    struct timeval tv = { 5, 0 };
    uint16_t last_tick = 0;
    int have_tick = 0;

    inet_pton(AF_INET, host, &sa.sin_addr);
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    int connected = connect(fd, (struct sockaddr *)&sa, sizeof sa) == 0;
    SSL *ssl = NULL;
    if (connected && tls) {
        ssl = SSL_new(tls);
        connected = ssl && SSL_set_fd(ssl, fd) == 1 && SSL_connect(ssl) == 1;
    }
    pthread_barrier_wait(&start_line);
    if (!connected) {
        fail(w, "client %d: connect or TLS handshake failed (%ld %ld %ld)", 0, 0, 0);
        SSL_free(ssl);
        close(fd);
        return NULL;
    }
    const uint64_t t_end = duration > 0 ? now_ns() + (uint64_t)(duration * 1e9) : 0;
    const uint16_t my_reg = (uint16_t)(base + 2 * w->id);
    uint16_t written = 0;

    for (long k = 0; duration > 0 ? now_ns() < t_end : k < requests; k++) {
        const uint16_t tid = (uint16_t)((w->id & 0x1f) << 11 | (k & 0x7ff));
        const int kind = (int)(k % 3);
        size_t len;

        req[0] = (uint8_t)(tid >> 8);
        req[1] = (uint8_t)tid;
        req[2] = req[3] = 0;
        req[6] = 1;
        if (kind == 0) {
            written = (uint16_t)k;
            const uint8_t pdu[] = { 16, (uint8_t)(my_reg >> 8), (uint8_t)my_reg, 0, 2, 4,
                                    (uint8_t)(w->id >> 8), (uint8_t)w->id, (uint8_t)(written >> 8), (uint8_t)written };
            memcpy(req + 7, pdu, sizeof pdu);
            len = 7 + sizeof pdu;
        } else {
            const uint16_t a = kind == 1 ? my_reg : 20;
            const uint8_t pdu[] = { 3, (uint8_t)(a >> 8), (uint8_t)a, 0, 2 };
            memcpy(req + 7, pdu, sizeof pdu);
            len = 7 + sizeof pdu;
        }
        req[4] = (uint8_t)((len - 6) >> 8);
        req[5] = (uint8_t)(len - 6);

        const uint64_t t0 = now_ns();
        int n = transact(fd, ssl, req, len, rsp, sizeof rsp);
        const uint64_t t1 = now_ns();
        if (w->done < (duration > 0 ? 2000000 : requests))
            w->lat_ns[w->done] = (uint32_t)((t1 - t0) > UINT32_MAX ? UINT32_MAX : (t1 - t0));
        w->done++;
        if (n < 0) {
            fail(w, "client %d: request %ld: connection failed (%ld %ld)", k, 0, 0);
            break;
        }
        const unsigned rtid = (unsigned)(rsp[0] << 8 | rsp[1]);
        if (rtid != tid) {
            fail(w, "client %d: request %ld: transaction id %ld, expected %ld", k, (long)rtid, (long)tid);
            continue;
        }
        if (rsp[7] != req[7]) {
            fail(w, "client %d: request %ld: function %ld in response to %ld", k, rsp[7], req[7]);
            continue;
        }
        if (kind == 0) {
            if (n != 5 || (rsp[8] << 8 | rsp[9]) != my_reg || (rsp[10] << 8 | rsp[11]) != 2)
                fail(w, "client %d: request %ld: bad write echo (len %ld, addr %ld)", k, n, rsp[8] << 8 | rsp[9]);
            continue;
        }
        if (n != 6 || rsp[8] != 4) {
            fail(w, "client %d: request %ld: bad read response length %ld byte count %ld", k, n, rsp[8]);
            continue;
        }
        const uint16_t r0 = (uint16_t)(rsp[9] << 8 | rsp[10]), r1 = (uint16_t)(rsp[11] << 8 | rsp[12]);
        if (kind == 1) {
            if (r0 != w->id || r1 != written)
                fail(w, "client %d: request %ld: read back owner %ld value %ld", k, r0, r1);
        } else {
            if (r0 != r1)
                fail(w, "client %d: request %ld: half-finished scan: tick words %ld and %ld", k, r0, r1);
            else if (have_tick && (uint16_t)(r0 - last_tick) >= 0x8000u)
                fail(w, "client %d: request %ld: tick went back from %ld to %ld", k, last_tick, r0);
            last_tick = r0;
            have_tick = 1;
        }
    }
    if (ssl)
        SSL_shutdown(ssl);
    SSL_free(ssl);
    close(fd);
    return NULL;
}

static int cmp_u32(const void *a, const void *b)
{
    uint32_t x = *(const uint32_t *)a, y = *(const uint32_t *)b;
    return x < y ? -1 : x > y;
}

int main(int argc, char **argv)
{
    static const struct option opts[] = {
        { "host", required_argument, NULL, 'h' }, { "port", required_argument, NULL, 'p' },
        { "clients", required_argument, NULL, 'c' }, { "requests", required_argument, NULL, 'n' },
        { "duration", required_argument, NULL, 'd' }, { "base", required_argument, NULL, 'b' },
        { "tls-cert", required_argument, NULL, 'C' }, { "tls-key", required_argument, NULL, 'K' },
        { "tls-ca", required_argument, NULL, 'A' },
        { NULL, 0, NULL, 0 },
    };
    const char *cert = NULL, *key = NULL, *ca = NULL;
    int c;

    while ((c = getopt_long(argc, argv, "", opts, NULL)) != -1) {
        switch (c) {
        case 'h': host = optarg; break;
        case 'p': port = atoi(optarg); break;
        case 'c': clients = atoi(optarg); break;
        case 'n': requests = atol(optarg); break;
        case 'd': duration = atof(optarg); break;
        case 'b': base = atoi(optarg); break;
        case 'C': cert = optarg; break;
        case 'K': key = optarg; break;
        case 'A': ca = optarg; break;
        default:
            fprintf(stderr, "usage: mbload --port N [--host A] [--clients C] [--requests R | --duration S] [--base B]"
                    " [--tls-cert F --tls-key F --tls-ca F]\n");
            return 2;
        }
    }
    if (cert || key || ca) {
        tls = SSL_CTX_new(TLS_client_method());
        if (!tls || !cert || !key || !ca || SSL_CTX_use_certificate_chain_file(tls, cert) != 1
            || SSL_CTX_use_PrivateKey_file(tls, key, SSL_FILETYPE_PEM) != 1
            || SSL_CTX_load_verify_locations(tls, ca, NULL) != 1) {
            fprintf(stderr, "mbload: --tls-cert, --tls-key and --tls-ca: all three, loadable\n");
            return 2;
        }
        SSL_CTX_set_verify(tls, SSL_VERIFY_PEER, NULL);
    }
    if (port <= 0 || clients < 1 || clients > 32 || (requests < 1 && duration <= 0)) {
        fprintf(stderr, "mbload: need --port, 1..32 clients and requests or a duration\n");
        return 2;
    }

    worker_t *w = calloc((size_t)clients, sizeof *w);
    long cap = duration > 0 ? 2000000 : requests;
    pthread_barrier_init(&start_line, NULL, (unsigned)clients + 1);
    for (int i = 0; i < clients; i++) {
        w[i].id = i;
        w[i].lat_ns = calloc((size_t)cap, sizeof(uint32_t));
        pthread_create(&w[i].thread, NULL, run_worker, &w[i]);
    }
    pthread_barrier_wait(&start_line);
    const uint64_t t0 = now_ns();
    for (int i = 0; i < clients; i++)
        pthread_join(w[i].thread, NULL);
    const double secs = (double)(now_ns() - t0) / 1e9;

    long total = 0, errors = 0, stored = 0;
    const char *first = "";
    for (int i = 0; i < clients; i++) {
        total += w[i].done;
        errors += w[i].errors;
        stored += w[i].done < cap ? w[i].done : cap;
        if (w[i].errors && !*first)
            first = w[i].first_error;
    }
    uint32_t *all = calloc((size_t)stored + 1, sizeof(uint32_t));
    long at = 0;
    for (int i = 0; i < clients; i++) {
        long n = w[i].done < cap ? w[i].done : cap;
        memcpy(all + at, w[i].lat_ns, (size_t)n * sizeof(uint32_t));
        at += n;
    }
    qsort(all, (size_t)stored, sizeof(uint32_t), cmp_u32);
#define PCT(p) (stored ? all[(long)((p) * (double)(stored - 1))] / 1e3 : 0.0)
    printf("{\"clients\": %d, \"requests\": %ld, \"errors\": %ld, \"seconds\": %.3f, \"rps\": %.0f, "
           "\"p50_us\": %.1f, \"p99_us\": %.1f, \"max_us\": %.1f, \"first_error\": \"%s\"}\n",
           clients, total, errors, secs, secs > 0 ? (double)total / secs : 0.0, PCT(0.50), PCT(0.99),
           stored ? all[stored - 1] / 1e3 : 0.0, first);
    return errors ? 1 : 0;
}
