/* check.c - the harness of check.h: counts checks per case, prints what differs, one result line per case. */
#include <inttypes.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "check.h"

static unsigned checks, failures;
static char row[160];

void check_row(const char *fmt, ...)
{
    va_list ap;

    va_start(ap, fmt);
    vsnprintf(row, sizeof row, fmt, ap);
    va_end(ap);
}

static bool report(bool ok, const char *file, int line, const char *fmt, ...) __attribute__((format(printf, 4, 5)));
static bool report(bool ok, const char *file, int line, const char *fmt, ...)
{
    va_list ap;

    checks++;
    if (ok)
        return true;
    failures++;
    printf("%s:%d: %s%s", file, line, row, row[0] ? ": " : "");
    va_start(ap, fmt);
    vprintf(fmt, ap);
    va_end(ap);
    printf("\n");
    return false;
}

bool check_true(bool ok, const char *what, const char *file, int line)
{
    return report(ok, file, line, "expected %s", what);
}

bool check_int(long long actual, long long expected, const char *what, const char *file, int line)
{
    return report(actual == expected, file, line, "%s: expected %lld, got %lld", what, expected, actual);
}

bool check_uint(unsigned long long actual, unsigned long long expected, const char *what, const char *file,
                int line)
{
    return report(actual == expected, file, line, "%s: expected %llu (0x%llx), got %llu (0x%llx)", what, expected,
                  expected, actual, actual);
}

bool check_str(const char *actual, const char *expected, const char *what, const char *file, int line)
{
    bool ok = actual && expected ? strcmp(actual, expected) == 0 : actual == expected;
    return report(ok, file, line, "%s: expected \"%s\", got \"%s\"", what, expected ? expected : "(null)",
                  actual ? actual : "(null)");
}

bool check_contains(const char *text, const char *part, const char *what, const char *file, int line)
{
    return report(text && strstr(text, part), file, line, "%s does not contain \"%s\"; it is:\n%s", what, part,
                  text ? text : "(null)");
}

bool check_mem(const void *actual, const void *expected, size_t n, const char *what, const char *file, int line)
{
    const uint8_t *a = actual, *e = expected;
    size_t at = 0;

    while (at < n && a[at] == e[at])
        at++;
    if (at == n)
        return report(true, file, line, "%s", what);
    return report(false, file, line, "%s: %zu bytes differ from byte %zu on: expected 0x%02x, got 0x%02x", what, n,
                  at, e[at], a[at]);
}

static bool wanted(const char *name, int argc, char **argv)
{
    if (argc < 2)
        return true;
    for (int i = 1; i < argc; i++)
        if (strcmp(argv[i], name) == 0)
            return true;
    return false;
}

int check_run(const check_case_t *cases, size_t n, int argc, char **argv)
{
    unsigned failed = 0, ran = 0;

    setvbuf(stdout, NULL, _IOLBF, 0);      /* a crash leaves every line before it on the pipe */
    if (argc == 2 && strcmp(argv[1], "--list") == 0) {
        for (size_t i = 0; i < n; i++)
            printf("%s\n", cases[i].name);
        return 0;
    }
    for (int i = 1; i < argc; i++) {
        bool known = false;
        for (size_t k = 0; k < n; k++)
            known = known || strcmp(cases[k].name, argv[i]) == 0;
        if (!known) {
            fprintf(stderr, "%s: no case named '%s' (--list lists them)\n", argv[0], argv[i]);
            return 2;
        }
    }
    for (size_t i = 0; i < n; i++) {
        if (!wanted(cases[i].name, argc, argv))
            continue;
        checks = failures = 0;
        row[0] = 0;
        printf("case %s\n", cases[i].name);
        cases[i].run();
        ran++;
        if (checks == 0)
            printf("FAIL %s (it executed no check)\n", cases[i].name);
        else if (failures)
            printf("FAIL %s (%u of %u checks failed)\n", cases[i].name, failures, checks);
        else
            printf("ok %s (%u checks)\n", cases[i].name, checks);
        failed += checks == 0 || failures != 0;
    }
    printf("%u cases, %u failed\n", ran, failed);
    return failed ? 1 : 0;
}
