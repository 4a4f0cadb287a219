/*
 * check.h - the C unit tests' own harness: named cases, typed checks that
 * print expected and actual with the source line, one line of result per case.
 *
 * A test file defines its cases as plain functions and lists them once:
 *
 *     static void retain_round_trip(void) { CHECK_INT(load(), 42); }
 *     static const check_case_t cases[] = { CASE(retain_round_trip) };
 *     CHECK_MAIN(cases)
 *
 * A failed CHECK_* is reported and the case goes on (every difference is
 * seen at once); REQUIRE* ends the case (what follows would only crash).  A
 * case that executes no check fails.  Output, one line per case after its
 * checks' messages, read by tests/test_runtime_c_unit.py:
 *
 *     case NAME
 *     test_retain.c:120: KEEP restored: expected 42, got 0
 *     FAIL NAME (1 of 7 checks failed)
 *     ok NAME (7 checks)
 *
 * Usage: BINARY [--list] [NAME...]  (no name: every case; exit 1 when one failed).
 */
#ifndef C_UNIT_CHECK_H
#define C_UNIT_CHECK_H

#include <stdbool.h>
#include <stddef.h>

typedef struct check_case {
    const char *name;
    void (*run)(void);
} check_case_t;

#define CASE(fn) { #fn, fn }

bool check_true(bool ok, const char *what, const char *file, int line);
bool check_int(long long actual, long long expected, const char *what, const char *file, int line);
bool check_uint(unsigned long long actual, unsigned long long expected, const char *what, const char *file,
                int line);
bool check_str(const char *actual, const char *expected, const char *what, const char *file, int line);
bool check_contains(const char *text, const char *part, const char *what, const char *file, int line);
bool check_mem(const void *actual, const void *expected, size_t n, const char *what, const char *file, int line);
int check_run(const check_case_t *cases, size_t n, int argc, char **argv);

#define CHECK(cond) check_true((cond), #cond, __FILE__, __LINE__)
#define CHECK_INT(actual, expected) check_int((long long)(actual), (long long)(expected), #actual, __FILE__, __LINE__)
#define CHECK_UINT(actual, expected) \
    check_uint((unsigned long long)(actual), (unsigned long long)(expected), #actual, __FILE__, __LINE__)
#define CHECK_STR(actual, expected) check_str((actual), (expected), #actual, __FILE__, __LINE__)
#define CHECK_CONTAINS(text, part) check_contains((text), (part), #text, __FILE__, __LINE__)
#define CHECK_MEM(actual, expected, n) check_mem((actual), (expected), (n), #actual, __FILE__, __LINE__)

/* The same, ending the case when they fail. */
#define REQUIRE(cond) do { if (!CHECK(cond)) return; } while (0)
#define REQUIRE_INT(actual, expected) do { if (!CHECK_INT(actual, expected)) return; } while (0)

/* A table-driven case names the row it is checking: messages are prefixed with it until the next call. */
void check_row(const char *fmt, ...) __attribute__((format(printf, 1, 2)));

#define CHECK_MAIN(cases) \
    int main(int argc, char **argv) { return check_run(cases, sizeof cases / sizeof cases[0], argc, argv); }

#endif /* C_UNIT_CHECK_H */
