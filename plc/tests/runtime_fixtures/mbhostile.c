/*
 * mbhostile.c - hostile Modbus/TCP clients for the hardening benchmark.
 *
 * Keeps three kinds of hostile connections open against a server until
 * SIGTERM or SIGINT, one thread each:
 *   half-frame   connects, sends 4 of the 7 MBAP header bytes, then nothing;
 *   slow reader  connects with a 4 KB receive buffer and sends 16 reads of 125
 *                registers every 50 ms, never reading an answer;
 *   storm        connects and closes at --storm-hz.
 * A connection the server drops is opened again --reopen-ms later.  Written
 * in C so that the load costs the machine little CPU of its own: what the
 * benchmark measures is the server's behaviour, not the load generator's.
 *
 * On exit prints one JSON line: connections opened, drops seen, storm cycles.
 *
 *   mbhostile --port N [--half H] [--slow S] [--storm T] [--storm-hz F] [--reopen-ms M]
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <getopt.h>
#include <netinet/in.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#define MODBUS_FC_READ_HOLDING_REGISTERS 0x03     /* libmodbus's name (modbus.h) */

static int port, storm_hz = 100, reopen_ms = 100;
static atomic_bool stopping;
static atomic_long opened, drops, storm_cycles;

static void sleep_ms(long ms)
{
    struct timespec ts = { .tv_sec = ms / 1000, .tv_nsec = (ms % 1000) * 1000000L };
    nanosleep(&ts, NULL);
}

static int open_connection(int rcvbuf)
{
    struct sockaddr_in sa = { .sin_family = AF_INET, .sin_port = htons((uint16_t)port) };
    struct timeval tv = { .tv_sec = 2 };
    int fd = socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);

    if (fd < 0)
        return -1;
    inet_pton(AF_INET, "127.0.0.1", &sa.sin_addr);
    if (rcvbuf)
        setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof rcvbuf);
    setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &tv, sizeof tv);
    if (connect(fd, (struct sockaddr *)&sa, sizeof sa) != 0) {
        close(fd);
        return -1;
    }
    atomic_fetch_add(&opened, 1);
    return fd;
}

static void *half_frame(void *arg)
{
    static const uint8_t half[4] = { 0x00, 0x01, 0x00, 0x00 };
    struct timeval poll_every = { .tv_usec = 100000 };
    (void)arg;

    while (!atomic_load(&stopping)) {
        int fd = open_connection(0);
        if (fd < 0) {
            sleep_ms(reopen_ms);
            continue;
        }
        setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &poll_every, sizeof poll_every);
        if (send(fd, half, sizeof half, MSG_NOSIGNAL) == (ssize_t)sizeof half) {
            uint8_t b[64];
            while (!atomic_load(&stopping)) {             /* until the server drops it */
                ssize_t n = recv(fd, b, sizeof b, 0);
                if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR))
                    break;
            }
        }
        close(fd);
        if (!atomic_load(&stopping)) {
            atomic_fetch_add(&drops, 1);
            sleep_ms(reopen_ms);
        }
    }
    return NULL;
}

static void *slow_reader(void *arg)
{
    uint8_t ask[16 * 12];
    (void)arg;

    for (int i = 0; i < 16; i++) {                       /* read holding registers 0..124 */
        static const uint8_t one[12] = { 0, 1, 0, 0, 0, 6, 1, MODBUS_FC_READ_HOLDING_REGISTERS, 0, 0, 0, 125 };
        memcpy(ask + 12 * i, one, 12);
    }
    while (!atomic_load(&stopping)) {
        int fd = open_connection(4096);
        if (fd < 0) {
            sleep_ms(reopen_ms);
            continue;
        }
        while (!atomic_load(&stopping)) {                 /* ask, never read */
            ssize_t n = send(fd, ask, sizeof ask, MSG_NOSIGNAL | MSG_DONTWAIT);
            if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)
                break;                                   /* dropped by the server */
            sleep_ms(50);
        }
        close(fd);
        if (!atomic_load(&stopping)) {
            atomic_fetch_add(&drops, 1);
            sleep_ms(reopen_ms);
        }
    }
    return NULL;
}

static void *storm(void *arg)
{
    (void)arg;
    while (!atomic_load(&stopping)) {
        int fd = open_connection(0);
        if (fd >= 0) {
            close(fd);
            atomic_fetch_add(&storm_cycles, 1);
        }
        sleep_ms(1000 / storm_hz);
    }
    return NULL;
}

int main(int argc, char **argv)
{
    static const struct option opts[] = {
        { "port", required_argument, NULL, 'p' },
        { "half", required_argument, NULL, 'h' },
        { "slow", required_argument, NULL, 's' },
        { "storm", required_argument, NULL, 't' },
        { "storm-hz", required_argument, NULL, 'z' },
        { "reopen-ms", required_argument, NULL, 'r' },
        { NULL, 0, NULL, 0 },
    };
    int half = 34, slow = 33, storms = 33, c;

    while ((c = getopt_long(argc, argv, "", opts, NULL)) != -1) {
        switch (c) {
        case 'p': port = atoi(optarg); break;
        case 'h': half = atoi(optarg); break;
        case 's': slow = atoi(optarg); break;
        case 't': storms = atoi(optarg); break;
        case 'z': storm_hz = atoi(optarg); break;
        case 'r': reopen_ms = atoi(optarg); break;
        default:
            fprintf(stderr, "usage: mbhostile --port N [--half H] [--slow S] [--storm T] [--storm-hz F] "
                            "[--reopen-ms M]\n");
            return 2;
        }
    }
    int total = half + slow + storms;
    if (port <= 0 || half < 0 || slow < 0 || storms < 0 || total < 1 || total > 1000 || storm_hz < 1
        || storm_hz > 1000 || reopen_ms < 0) {
        fprintf(stderr, "mbhostile: need --port, 1..1000 connections, --storm-hz 1..1000\n");
        return 2;
    }

    sigset_t stop;
    sigemptyset(&stop);
    sigaddset(&stop, SIGTERM);
    sigaddset(&stop, SIGINT);
    pthread_sigmask(SIG_BLOCK, &stop, NULL);

    pthread_t *threads = calloc((size_t)total, sizeof *threads);
    if (!threads)
        return 1;
    for (int i = 0; i < total; i++)
        pthread_create(&threads[i], NULL, i < half ? half_frame : i < half + slow ? slow_reader : storm, NULL);
    fprintf(stderr, "mbhostile: %d half-frames, %d slow readers, %d storms at %d/s\n", half, slow, storms,
            storm_hz);

    int sig;
    sigwait(&stop, &sig);
    atomic_store(&stopping, true);
    for (int i = 0; i < total; i++)
        pthread_join(threads[i], NULL);
    printf("{\"opened\": %ld, \"drops\": %ld, \"storm_cycles\": %ld}\n", atomic_load(&opened),
           atomic_load(&drops), atomic_load(&storm_cycles));
    free(threads);
    return 0;
}
