/*
 * mbfuzz.c - black-box Modbus/TCP frame fuzzer for the runtime.
 *
 * C connections, each on its own thread, send mutated frames to the server
 * and read whatever comes back without waiting for it.  One frame is one
 * application data unit as the fuzzer built it; frames are sent in batches of
 * 1..8 written at once (so the server sees coalesced ADUs), and each frame is
 * one of these shapes:
 *
 *   valid         a request of a served function code, random fields, often in range
 *   boundary      quantities and addresses at and beyond the limits (0, max, max + 1, 0xFFFF)
 *   unknown-fc    a function code the server does not serve, random body
 *   lying-length  the MBAP length field differs from the bytes that follow
 *   protocol      a protocol id other than 0
 *   truncated     the first k bytes of a frame only
 *   byte-count    FC 15/16 with a byte count that does not match the quantity or the data
 *   flipped       a valid frame with random bits flipped
 *   noise         random bytes
 *
 * The shapes that break the stream (lying-length, protocol, truncated,
 * noise: about one frame in eight) end their batch and the connection with
 * an orderly close (FIN, then the answers are read until the server closes
 * too), so the server reads every frame of it; one batch
 * in 64 of the others ends with an abrupt close (RST) instead, which may cut
 * frames the server has not read yet.
 * Deterministic for a given --seed (per connection: seed + index).
 *
 * Prints one JSON line: frames, bytes, batches, connections opened, closes
 * seen from the server, response bytes, seconds, frames per second.
 * Exit status 0 when the fuzzing ran to the end (the fuzzer does not judge
 * the server: the caller checks it still answers and has no sanitizer report).
 *
 *   mbfuzz --port N [--frames F] [--connections C] [--seed S]
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <getopt.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <stdbool.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

/* libmodbus's names (modbus.h), without linking libmodbus into the fuzzer */
#define MODBUS_FC_READ_COILS 0x01
#define MODBUS_FC_READ_DISCRETE_INPUTS 0x02
#define MODBUS_FC_READ_HOLDING_REGISTERS 0x03
#define MODBUS_FC_READ_INPUT_REGISTERS 0x04
#define MODBUS_FC_WRITE_SINGLE_COIL 0x05
#define MODBUS_FC_WRITE_SINGLE_REGISTER 0x06
#define MODBUS_FC_WRITE_MULTIPLE_COILS 0x0F
#define MODBUS_FC_WRITE_MULTIPLE_REGISTERS 0x10
#define MODBUS_MAX_WRITE_BITS 1968
#define MODBUS_MAX_WRITE_REGISTERS 123

#define MAX_FRAME 300
#define MAX_BATCH 8

enum shape { VALID, BOUNDARY, UNKNOWN_FC, LYING_LENGTH, PROTOCOL, TRUNCATED, BYTE_COUNT, FLIPPED, NOISE, SHAPES };

typedef struct fuzzer {
    int index;
    pthread_t thread;
    uint64_t rng;
    long frames_goal;
    long frames, batches, connections, server_closes, connect_failures;
    uint64_t bytes, response_bytes;
    long shapes[SHAPES];
} fuzzer_t;

static int port;

static uint64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

static uint32_t next(fuzzer_t *f)                /* xorshift64* */
{
    f->rng ^= f->rng >> 12;
    f->rng ^= f->rng << 25;
    f->rng ^= f->rng >> 27;
    return (uint32_t)((f->rng * 2685821657736338717ull) >> 32);
}

static unsigned below(fuzzer_t *f, unsigned n)
{
    return next(f) % n;
}

static void put16(uint8_t *p, unsigned v)
{
    p[0] = (uint8_t)(v >> 8);
    p[1] = (uint8_t)v;
}

/* A served request (function code, fields) into pdu; returns its length. */
static unsigned valid_pdu(fuzzer_t *f, uint8_t *pdu, bool boundary)
{
    static const uint8_t fcs[] = {
        MODBUS_FC_READ_COILS, MODBUS_FC_READ_DISCRETE_INPUTS, MODBUS_FC_READ_HOLDING_REGISTERS,
        MODBUS_FC_READ_INPUT_REGISTERS, MODBUS_FC_WRITE_SINGLE_COIL, MODBUS_FC_WRITE_SINGLE_REGISTER,
        MODBUS_FC_WRITE_MULTIPLE_COILS, MODBUS_FC_WRITE_MULTIPLE_REGISTERS,
    };
    static const unsigned edges[] = { 0, 1, 123, 124, 125, 126, 799, 800, 1968, 1969, 2000, 2001, 8191, 8192,
                                      0x7FFF, 0xFFFF };
    const unsigned fc = fcs[below(f, 8)];
    unsigned addr, qty;

    if (boundary) {
        addr = edges[below(f, 16)];
        qty = edges[below(f, 16)];
    } else {
        addr = below(f, 4) == 0 ? next(f) & 0xFFFF : below(f, 1100);
        qty = below(f, 4) == 0 ? next(f) & 0xFFFF : 1 + below(f, 125);
    }
    pdu[0] = (uint8_t)fc;
    put16(pdu + 1, addr);
    switch (fc) {
    case MODBUS_FC_WRITE_SINGLE_COIL:
        put16(pdu + 3, below(f, 3) == 0 ? next(f) & 0xFFFF : below(f, 2) ? 0xFF00 : 0);
        return 5;
    case MODBUS_FC_WRITE_SINGLE_REGISTER:
        put16(pdu + 3, next(f) & 0xFFFF);
        return 5;
    case MODBUS_FC_WRITE_MULTIPLE_COILS:
    case MODBUS_FC_WRITE_MULTIPLE_REGISTERS: {
        const bool coils = fc == MODBUS_FC_WRITE_MULTIPLE_COILS;
        const unsigned max = coils ? MODBUS_MAX_WRITE_BITS : MODBUS_MAX_WRITE_REGISTERS;
        if (qty > max && !boundary)
            qty = 1 + below(f, max);
        unsigned bytes = coils ? (qty + 7) / 8 : 2 * qty;
        if (bytes > 246)
            bytes = 246;
        put16(pdu + 3, qty);
        pdu[5] = (uint8_t)bytes;
        for (unsigned i = 0; i < bytes; i++)
            pdu[6 + i] = (uint8_t)next(f);
        return 6 + bytes;
    }
    default:
        put16(pdu + 3, qty);
        return 5;
    }
}

/* Shares of the shapes, in 1/100. */
static const unsigned WEIGHT[SHAPES] = {
    [VALID] = 32, [BOUNDARY] = 16, [UNKNOWN_FC] = 12, [BYTE_COUNT] = 12, [FLIPPED] = 16,
    [LYING_LENGTH] = 4, [PROTOCOL] = 2, [TRUNCATED] = 3, [NOISE] = 3,
};

static bool breaks_stream(enum shape s)
{
    return s == LYING_LENGTH || s == PROTOCOL || s == TRUNCATED || s == NOISE;
}

static enum shape pick_shape(fuzzer_t *f)
{
    unsigned r = below(f, 100);
    for (int s = 0; s < SHAPES; s++) {
        if (r < WEIGHT[s])
            return (enum shape)s;
        r -= WEIGHT[s];
    }
    return VALID;
}

/* One frame of shape s into out; returns its length. */
static unsigned build_frame(fuzzer_t *f, enum shape s, uint8_t *out)
{
    uint8_t pdu[256];
    unsigned pdu_len, length, protocol = 0;

    f->shapes[s]++;
    switch (s) {
    case VALID:
    case LYING_LENGTH:
    case PROTOCOL:
    case TRUNCATED:
    case FLIPPED:
        pdu_len = valid_pdu(f, pdu, false);
        break;
    case BOUNDARY:
        pdu_len = valid_pdu(f, pdu, true);
        break;
    case BYTE_COUNT:                        /* a valid request, its function, byte count and length replaced */
        (void)valid_pdu(f, pdu, false);
        pdu[0] = below(f, 2) ? MODBUS_FC_WRITE_MULTIPLE_COILS : MODBUS_FC_WRITE_MULTIPLE_REGISTERS;
        pdu[5] = (uint8_t)next(f);
        pdu_len = 6 + below(f, 247);                    /* the largest PDU: 253 bytes */
        break;
    case UNKNOWN_FC: {
        static const uint8_t odd[] = { 0x00, 0x07, 0x08, 0x0B, 0x0C, 0x11, 0x14, 0x15, 0x16, 0x17, 0x18, 0x2B,
                                       0x41, 0x7F, 0x80, 0x83, 0xFF };
        pdu_len = 1 + below(f, 20);
        for (unsigned i = 0; i < pdu_len; i++)
            pdu[i] = (uint8_t)next(f);
        pdu[0] = below(f, 2) ? odd[below(f, sizeof odd)] : (uint8_t)next(f);
        break;
    }
    default:                                             /* NOISE */
        length = 1 + below(f, 40);
        for (unsigned i = 0; i < length; i++)
            out[i] = (uint8_t)next(f);
        return length;
    }

    length = pdu_len + 1;
    if (s == LYING_LENGTH) {
        switch (below(f, 4)) {
        case 0: length = next(f) & 0xFFFF; break;
        case 1: length = pdu_len + 1 + 1 + below(f, 20); break;          /* announces more than follows */
        case 2: length = below(f, pdu_len + 1); break;                   /* announces less */
        default: length = below(f, 2) ? 0 : 255 + below(f, 3); break;
        }
    }
    if (s == PROTOCOL)
        protocol = 1 + below(f, 0xFFFF);
    put16(out, next(f) & 0xFFFF);
    put16(out + 2, protocol);
    put16(out + 4, length);
    out[6] = (uint8_t)next(f);
    memcpy(out + 7, pdu, pdu_len);
    unsigned total = 7 + pdu_len;
    if (s == FLIPPED)                                    /* mostly in the PDU, now and then in the header */
        for (unsigned k = 1 + below(f, 3); k > 0; k--)
            out[below(f, 4) ? 7 + below(f, total - 7) : below(f, 7)] ^= (uint8_t)(1u << below(f, 8));
    if (s == TRUNCATED)
        total = 1 + below(f, total - 1);
    return total;
}

static int open_connection(fuzzer_t *f)
{
    struct sockaddr_in sa = { .sin_family = AF_INET, .sin_port = htons((uint16_t)port) };
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0), one = 1;
    struct timeval tv = { .tv_sec = 5 };

    /* A source address of its own for each connection (127.x.y.z): a port the server
     * still holds in TIME_WAIT would otherwise stall connect() for a second now and then. */
    struct sockaddr_in src = { .sin_family = AF_INET,
                               .sin_addr.s_addr = htonl(0x7F000000u | (1u + below(f, 0xFFFFFDu))) };

    inet_pton(AF_INET, "127.0.0.1", &sa.sin_addr);
    if (fd < 0)
        return -1;
    bind(fd, (struct sockaddr *)&src, sizeof src);
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
    if (connect(fd, (struct sockaddr *)&sa, sizeof sa) != 0) {
        close(fd);
        f->connect_failures++;
        return -1;
    }
    f->connections++;
    return fd;
}

static void abrupt_close(int fd)
{
    struct linger lg = { .l_onoff = 1, .l_linger = 0 };
    setsockopt(fd, SOL_SOCKET, SO_LINGER, &lg, sizeof lg);
    close(fd);
}

/* Read what the server sent so far; returns -1 when it closed the connection. */
static int drain(fuzzer_t *f, int fd)
{
    uint8_t buf[4096];

    for (;;) {
        ssize_t n = recv(fd, buf, sizeof buf, MSG_DONTWAIT);
        if (n > 0) {
            f->response_bytes += (uint64_t)n;
            continue;
        }
        if (n == 0 || (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR))
            return -1;
        return 0;
    }
}

/* Orderly close: send FIN, read the answers until the server closes too
 * (bounded), so every frame sent is read and answered or refused. */
static void finish(fuzzer_t *f, int fd)
{
    struct pollfd p = { .fd = fd, .events = POLLIN };

    shutdown(fd, SHUT_WR);
    while (poll(&p, 1, 5000) == 1 && drain(f, fd) == 0)
        ;
    close(fd);
}

static void *fuzz_thread(void *arg)
{
    fuzzer_t *f = arg;
    uint8_t batch[MAX_BATCH * MAX_FRAME];
    int fd = -1;

    while (f->frames < f->frames_goal) {
        if (fd < 0) {
            fd = open_connection(f);
            if (fd < 0) {
                if (f->connect_failures > 1000)
                    break;
                struct timespec pause = { 0, 1000000 };          /* 1 ms, then connect again */
                nanosleep(&pause, NULL);
                continue;
            }
        }
        unsigned n = 1 + below(f, MAX_BATCH), len = 0;
        bool broken = false;
        for (unsigned i = 0; i < n && !broken && f->frames < f->frames_goal; i++, f->frames++) {
            enum shape s = pick_shape(f);
            len += build_frame(f, s, batch + len);
            broken = breaks_stream(s);
        }
        f->batches++;
        size_t sent = 0;
        while (sent < len) {
            ssize_t w = send(fd, batch + sent, len - sent, MSG_NOSIGNAL);
            if (w <= 0)
                break;
            sent += (size_t)w;
        }
        f->bytes += sent;
        if (sent < len || drain(f, fd) < 0) {
            f->server_closes++;
            close(fd);
            fd = -1;
            continue;
        }
        if (broken) {                                    /* FIN after the data: the server reads it all */
            finish(f, fd);
            fd = -1;
        } else if (below(f, 64) == 0) {                  /* RST: what the server has not read yet is lost */
            abrupt_close(fd);
            fd = -1;
        }
    }
    if (fd >= 0)
        close(fd);
    return NULL;
}

int main(int argc, char **argv)
{
    static const struct option opts[] = {
        { "port", required_argument, NULL, 'p' },
        { "frames", required_argument, NULL, 'f' },
        { "connections", required_argument, NULL, 'c' },
        { "seed", required_argument, NULL, 's' },
        { NULL, 0, NULL, 0 },
    };
    long frames = 100000;
    int connections = 4, c;
    unsigned long long seed = 1;

    while ((c = getopt_long(argc, argv, "", opts, NULL)) != -1) {
        switch (c) {
        case 'p': port = atoi(optarg); break;
        case 'f': frames = atol(optarg); break;
        case 'c': connections = atoi(optarg); break;
        case 's': seed = strtoull(optarg, NULL, 10); break;
        default:
            fprintf(stderr, "usage: mbfuzz --port N [--frames F] [--connections C] [--seed S]\n");
            return 2;
        }
    }
    if (port <= 0 || frames < 1 || connections < 1 || connections > 64) {
        fprintf(stderr, "mbfuzz: need --port, --frames >= 1 and 1..64 connections\n");
        return 2;
    }

    fuzzer_t *fz = calloc((size_t)connections, sizeof *fz);
    if (!fz)
        return 1;
    uint64_t t0 = now_ns();
    for (int i = 0; i < connections; i++) {
        fz[i].index = i;
        fz[i].rng = (seed + (uint64_t)i) * 0x9E3779B97F4A7C15ull | 1u;
        fz[i].frames_goal = frames / connections + (i < frames % connections);
        pthread_create(&fz[i].thread, NULL, fuzz_thread, &fz[i]);
    }
    fuzzer_t sum = { 0 };
    for (int i = 0; i < connections; i++) {
        pthread_join(fz[i].thread, NULL);
        sum.frames += fz[i].frames;
        sum.batches += fz[i].batches;
        sum.connections += fz[i].connections;
        sum.server_closes += fz[i].server_closes;
        sum.connect_failures += fz[i].connect_failures;
        sum.bytes += fz[i].bytes;
        sum.response_bytes += fz[i].response_bytes;
        for (int s = 0; s < SHAPES; s++)
            sum.shapes[s] += fz[i].shapes[s];
    }
    double seconds = (double)(now_ns() - t0) / 1e9;
    printf("{\"frames\": %ld, \"bytes\": %llu, \"batches\": %ld, \"connections\": %ld, \"server_closes\": %ld, "
           "\"connect_failures\": %ld, \"response_bytes\": %llu, \"seconds\": %.3f, \"frames_per_s\": %.0f, "
           "\"shapes\": [%ld, %ld, %ld, %ld, %ld, %ld, %ld, %ld, %ld]}\n",
           sum.frames, (unsigned long long)sum.bytes, sum.batches, sum.connections, sum.server_closes,
           sum.connect_failures, (unsigned long long)sum.response_bytes, seconds, sum.frames / seconds,
           sum.shapes[0], sum.shapes[1], sum.shapes[2], sum.shapes[3], sum.shapes[4], sum.shapes[5],
           sum.shapes[6], sum.shapes[7], sum.shapes[8]);
    free(fz);
    return sum.frames == frames ? 0 : 1;
}
