/* logcap.c - log_msg() into memory (logcap.h). */
#define _GNU_SOURCE
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "runtime.h"
#include "logcap.h"

#define LOGCAP_SIZE (256 * 1024)

static pthread_mutex_t mu = PTHREAD_MUTEX_INITIALIZER;
static char lines[LOGCAP_SIZE];
static size_t used;
static char copy[LOGCAP_SIZE];

/* log.c's is not linked in; C has no empty struct, hence the member */
struct log_sink {
    // cppcheck-suppress unusedStructMember ; it only gives log_sink_t a definition
    int unused;
};

log_sink_t *logcap_sink(void)
{
    static log_sink_t sink;
    return &sink;
}

void log_msg(log_sink_t *ls, log_level_t level, const char *fmt, ...)
{
    static const char *const prefix[] = { [LOG_INFO] = "", [LOG_WARN] = "warning: ", [LOG_ERROR] = "error: " };
    char line[1024];
    va_list ap;
    int n;

    (void)ls;
    n = snprintf(line, sizeof line, "%s", prefix[level]);
    va_start(ap, fmt);
    vsnprintf(line + n, sizeof line - (size_t)n, fmt, ap);
    va_end(ap);
    if (getenv("LOGCAP_SHOW"))
        fprintf(stderr, "%s\n", line);
    pthread_mutex_lock(&mu);
    n = snprintf(lines + used, sizeof lines - used, "%s\n", line);
    if (n > 0)
        used += (size_t)n < sizeof lines - used ? (size_t)n : sizeof lines - used - 1;
    pthread_mutex_unlock(&mu);
}

void logcap_clear(void)
{
    pthread_mutex_lock(&mu);
    used = 0;
    lines[0] = 0;
    pthread_mutex_unlock(&mu);
}

const char *logcap_text(void)
{
    pthread_mutex_lock(&mu);
    memcpy(copy, lines, used + 1);
    pthread_mutex_unlock(&mu);
    return copy;
}

unsigned logcap_count(const char *part)
{
    unsigned n = 0;

    for (const char *p = logcap_text(); *p;) {
        const char *end = strchr(p, '\n');
        size_t len = end ? (size_t)(end - p) : strlen(p);
        char *hit = memmem(p, len, part, strlen(part));
        n += hit != NULL;
        p += len + (end != NULL);
    }
    return n;
}
