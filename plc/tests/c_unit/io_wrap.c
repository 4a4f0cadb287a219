/* io_wrap.c - the wrapped fsync() and rename() of io_wrap.h. */
#define _GNU_SOURCE
#include <errno.h>
#include <pthread.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "io_wrap.h"

#define IO_MAX_EVENTS 64

int __real_fsync(int fd);
int __real_rename(const char *from, const char *to);
int __wrap_fsync(int fd);
int __wrap_rename(const char *from, const char *to);

static pthread_mutex_t mu = PTHREAD_MUTEX_INITIALIZER;
static io_event_t events[IO_MAX_EVENTS];
static unsigned n_events, counts[IO_CALLS];
static int fail_with[IO_CALLS];
static bool skip_sync;

void io_reset(void)
{
    pthread_mutex_lock(&mu);
    n_events = 0;
    memset(counts, 0, sizeof counts);
    memset(fail_with, 0, sizeof fail_with);
    pthread_mutex_unlock(&mu);
}

unsigned io_events(io_event_t *out, unsigned max)
{
    pthread_mutex_lock(&mu);
    unsigned n = n_events < max ? n_events : max;
    memcpy(out, events, n * sizeof *out);
    n = n_events;
    pthread_mutex_unlock(&mu);
    return n;
}

unsigned io_count(io_call_t call)
{
    pthread_mutex_lock(&mu);
    unsigned n = counts[call];
    pthread_mutex_unlock(&mu);
    return n;
}

void io_fail(io_call_t call, int err)
{
    pthread_mutex_lock(&mu);
    fail_with[call] = err;
    pthread_mutex_unlock(&mu);
}

void io_skip_sync(bool skip)
{
    pthread_mutex_lock(&mu);
    skip_sync = skip;
    pthread_mutex_unlock(&mu);
}

/* Record one call; returns the errno to fail it with, 0 to do it. */
static int record(io_call_t call, const char *path, const char *to)
{
    pthread_mutex_lock(&mu);
    if (n_events < IO_MAX_EVENTS) {
        io_event_t *e = &events[n_events++];
        e->call = call;
        snprintf(e->path, sizeof e->path, "%s", path);
        snprintf(e->to, sizeof e->to, "%s", to ? to : "");
    }
    counts[call]++;
    int err = fail_with[call];
    pthread_mutex_unlock(&mu);
    return err;
}

int __wrap_fsync(int fd)
{
    char link[64], path[PATH_MAX] = "?";
    struct stat st;

    snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
    ssize_t n = readlink(link, path, sizeof path - 1);
    path[n > 0 ? n : 1] = 0;
    bool dir = fstat(fd, &st) == 0 && S_ISDIR(st.st_mode);
    int err = record(dir ? IO_FSYNC_DIR : IO_FSYNC_FILE, path, NULL);
    if (err) {
        errno = err;
        return -1;
    }
    pthread_mutex_lock(&mu);
    bool skip = skip_sync;
    pthread_mutex_unlock(&mu);
    return skip ? 0 : __real_fsync(fd);
}

int __wrap_rename(const char *from, const char *to)
{
    int err = record(IO_RENAME, from, to);

    if (err) {
        errno = err;
        return -1;
    }
    return __real_rename(from, to);
}
