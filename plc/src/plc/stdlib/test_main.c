/*
 * test_main.c - the scan-cycle test runner linked with a test build.
 *
 * Every scan goes through the scan core that the soft-PLC runtime uses
 * (native/runtime/scan_core.c): input latch, forced values, tasks due,
 * output publication.  The runner only swaps the runtime's two outside
 * parts: the clock is simulated, and the I/O image is plain memory (direct
 * I/O, no network).  The task is the test body: before every scan the runner
 * writes the scan number and the time into the test's ST_TestContext, the
 * core sets the program clock and calls the body once, then the runner
 * advances the clock by CycleTime (+ Advance).  Each test runs on a fresh,
 * freshly initialised instance.  Results go to stdout as one line per event
 * for `plc test` to format:
 *
 *   BEGIN <index>
 *   ASSERT <site> <message>\t<expected>\t<actual>
 *   FAULT <kind> <site-less position: file\tline\tcol\tpou>
 *   END <index> <PASS|FAIL|NOASSERT|BUDGET|HANG|FAULT> <scans> <clock-ns> <asserts> <failures>
 *
 * A test that ends without a failed assert passes only if it executed at
 * least one: NOASSERT is a test that checked nothing (its asserts, if any,
 * sit in branches never taken).
 *
 * Usage: test_main [--timeout SECONDS] [--max-failures N] INDEX...
 */
#define _POSIX_C_SOURCE 200809L
#include <setjmp.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/time.h>

#include "plc_abi.h"
#include "scan_core.h"

#define FIELD(ctx, off, type) (*(type *)((char *)(ctx) + plc_test_ctx_layout.off))

static sigjmp_buf hang_jump;
static volatile sig_atomic_t in_test;
static unsigned max_failures = 20;
static unsigned printed_failures;

static void on_alarm(int sig) {
    (void)sig;
    if (in_test) siglongjmp(hang_jump, 1);
}

static void print_text(const plc_string_t *s) {
    for (unsigned i = 0; i < s->len && i < PLC_STRING_MAX; i++) {
        char c = s->body[i];
        if (c == '\t') fputs("\\t", stdout);
        else if (c == '\n') fputs("\\n", stdout);
        else if (c == '\r') fputs("\\r", stdout);
        else if (c == '\\') fputs("\\\\", stdout);
        else putchar(c);
    }
}

void plc_on_assert(int32_t site, int ok, const void *ctx) {
    if (ok || ctx == NULL) return;
    if (printed_failures++ >= max_failures) return;
    printf("ASSERT %d ", (int)site);
    print_text(&FIELD(ctx, last_message, plc_string_t));
    putchar('\t');
    print_text(&FIELD(ctx, last_expected, plc_string_t));
    putchar('\t');
    print_text(&FIELD(ctx, last_actual, plc_string_t));
    putchar('\n');
}

/* The test being run, as the scan core's task. */
typedef struct test_task {
    const plc_test_t *test;
    void *self;
    void *ctx;
} test_task_t;

static int run_test_body(void *arg, uint64_t tick) {
    test_task_t *task = arg;
    (void)tick;
    return task->test->body(task->self, task->ctx);
}

static plc_image_t image;    /* direct I/O: the image is plain memory */

static void arm_timer(long seconds) {
    struct itimerval it;
    memset(&it, 0, sizeof it);
    it.it_value.tv_sec = seconds;
    setitimer(ITIMER_REAL, &it, NULL);
}

static void run_test(uint32_t index, long timeout) {
    const plc_test_t *t = &plc_tests[index];
    void *self = calloc(1, t->size);
    void *ctx = calloc(1, plc_test_ctx_layout.size);
    if (self == NULL || ctx == NULL) {
        printf("END %u FAULT 0 0 0 0\n", index);
        free(self);
        free(ctx);
        return;
    }
    plc_program.init();
    t->init(self);
    plc_scan_t core;
    char err[256];
    memset(&image, 0, sizeof image);
    if (plc_scan_bind(&core, &plc_program, &image, NULL, NULL, err, sizeof err) != 0) {
        printf("FAULT 0 %s\t0\t0\t?\nEND %u FAULT 0 0 0 0\n", err, index);
        free(self);
        free(ctx);
        return;
    }
    test_task_t task = { t, self, ctx };
    core.run = run_test_body;
    core.run_ctx = &task;
    FIELD(ctx, cycle_time, int64_t) = 4000000;   /* T#4ms */
    FIELD(ctx, budget, uint32_t) = 100000;
    printed_failures = 0;
    printf("BEGIN %u\n", index);
    fflush(stdout);

    int64_t clock = 0;
    uint32_t scan = 0;
    const char *status = "PASS";
    volatile int hung = 0;
    in_test = 1;
    arm_timer(timeout);
    if (sigsetjmp(hang_jump, 1) != 0) {
        hung = 1;
    }
    while (!hung) {
        scan++;
        FIELD(ctx, scan, uint32_t) = scan;
        FIELD(ctx, now, int64_t) = clock;
        int rc = plc_scan_step(&core, clock);
        if (rc != 0) {
            const plc_fault_t *f = plc_program.fault;
            printf("FAULT %d %s\t%d\t%d\t%s\n", rc, f->file ? f->file : "?", (int)f->line, (int)f->col,
                   f->pou ? f->pou : "?");
            status = "FAULT";
            break;
        }
        if (FIELD(ctx, done, uint8_t)) break;
        if (scan >= FIELD(ctx, budget, uint32_t)) {
            status = "BUDGET";
            break;
        }
        int64_t step = FIELD(ctx, cycle_time, int64_t) + FIELD(ctx, advance, int64_t);
        FIELD(ctx, advance, int64_t) = 0;
        clock += step > 0 ? step : 0;
    }
    arm_timer(0);
    in_test = 0;
    if (hung) status = "HANG";
    uint32_t failures = FIELD(ctx, failures, uint32_t);
    uint32_t asserts = FIELD(ctx, asserts, uint32_t);
    if (strcmp(status, "PASS") == 0 && failures > 0) status = "FAIL";
    if (strcmp(status, "PASS") == 0 && asserts == 0) status = "NOASSERT";
    printf("END %u %s %u %lld %u %u\n", index, status, scan, (long long)clock, asserts, failures);
    fflush(stdout);
    plc_scan_free(&core);
    free(self);
    free(ctx);
}

int main(int argc, char **argv) {
    long timeout = 20;
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_alarm;
    sigaction(SIGALRM, &sa, NULL);
    int i = 1;
    for (; i < argc && strncmp(argv[i], "--", 2) == 0; i += 2) {
        if (i + 1 >= argc) break;
        if (strcmp(argv[i], "--timeout") == 0) timeout = strtol(argv[i + 1], NULL, 10);
        else if (strcmp(argv[i], "--max-failures") == 0) max_failures = (unsigned)strtoul(argv[i + 1], NULL, 10);
    }
    if (i >= argc) {
        for (uint32_t k = 0; k < plc_n_tests; k++) run_test(k, timeout);
    } else {
        for (; i < argc; i++) {
            unsigned long k = strtoul(argv[i], NULL, 10);
            if (k < plc_n_tests) run_test((uint32_t)k, timeout);
        }
    }
    return 0;
}
