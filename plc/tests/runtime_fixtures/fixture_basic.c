/*
 * fixture_basic.c - a hand-written program implementing plc_abi.h, standing
 * in for compiler output in the runtime tests.  It behaves like this ST:
 *
 *   CONFIGURATION Config0  RESOURCE Res0
 *     TASK Fast (INTERVAL := T#4ms);  TASK Slow (INTERVAL := T#20ms);
 *   PROGRAM Main
 *     VAR  hostBit AT %IX50.0 : BOOL; echoBit AT %QX0.1 : BOOL; alive AT %QX0.0 : BOOL := TRUE;
 *          inWord AT %IW512 : INT; echoWord AT %QW1 : INT; quotient AT %QW3 : INT;
 *          tickFirst AT %QW20 : WORD; tickLast AT %QW21 : WORD; slowCount AT %QW30 : UINT;
 *          divisor AT %MW10 : INT; keepIn AT %MW20 : INT; keepOut AT %MW21 : INT;
 *          preset AT %MW30 : INT := 4242;
 *          dIn AT %MD0 : DINT; dOut AT %MD1 : DINT; scansOut AT %MD5 : UDINT;
 *          clockMs AT %MD6 : UDINT; tickOut AT %MD7 : UDINT;
 *          lIn AT %ML0 : LINT; lOut AT %ML1 : LINT;  END_VAR
 *     VAR RETAIN  keep : INT; scans : UDINT;  END_VAR
 *     VAR  slow : UINT;  END_VAR
 *     (Fast)  tickFirst := tick; echoBit := hostBit; echoWord := inWord + 1;
 *             dOut := dIn + 1; lOut := lIn + 1;
 *             quotient := 100 / (divisor - 7);          (* divisor = 7: division by zero *)
 *             (divisor = 13: loops forever; divisor = 14: loops for 1.5 s -- watchdog tests)
 *             IF keepIn <> 0 THEN keep := keepIn; END_IF; keepOut := keep;
 *             scans := scans + 1; scansOut := scans; clockMs := clock in ms; tickOut := tick;
 *             tickLast := tick;
 *     (Slow)  slowCount := slowCount + 1;
 *
 * Compile-time knobs (a wrapper file may #define them before #including this
 * one): FIXTURE_BASE_TICK_NS (default 4 ms, Fast = 1 tick, Slow = 5 ticks),
 * FIXTURE_LAYOUT_HASH, FIXTURE_BAD_LOCATED (declares %MW30 as LINT),
 * FIXTURE_ABI_VERSION.  (A retained layout that changes is tests/c_unit/test_retain.c's.)
 */
#define _POSIX_C_SOURCE 200809L      /* clock_gettime */
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#include <time.h>

#include "plc_abi.h"

#ifndef FIXTURE_BASE_TICK_NS
#define FIXTURE_BASE_TICK_NS 4000000u
#endif
#ifndef FIXTURE_LAYOUT_HASH
#define FIXTURE_LAYOUT_HASH 0x5eed0001u
#endif
#ifndef FIXTURE_ABI_VERSION
#define FIXTURE_ABI_VERSION PLC_ABI_VERSION
#endif
#ifdef FIXTURE_BAD_LOCATED           /* a LINT at a word address: the runtime must refuse it */
#define PRESET_TYPE PLC_T_LINT
#else
#define PRESET_TYPE PLC_T_INT
#endif

/* Located variables: a pointer each, pointed at private storage by init(). */
static void *p_host_bit, *p_echo_bit, *p_alive, *p_in_word, *p_echo_word, *p_quotient, *p_tick_first,
    *p_tick_last, *p_slow_count, *p_divisor, *p_keep_in, *p_keep_out, *p_preset, *p_d_in, *p_d_out,
    *p_scans_out, *p_clock_ms, *p_tick_out, *p_l_in, *p_l_out;

#define HOST_BIT   (*(plc_bool_t *)p_host_bit)
#define ECHO_BIT   (*(plc_bool_t *)p_echo_bit)
#define ALIVE      (*(plc_bool_t *)p_alive)
#define IN_WORD    (*(int16_t *)p_in_word)
#define ECHO_WORD  (*(int16_t *)p_echo_word)
#define QUOTIENT   (*(int16_t *)p_quotient)
#define TICK_FIRST (*(uint16_t *)p_tick_first)
#define TICK_LAST  (*(uint16_t *)p_tick_last)
#define SLOW_COUNT (*(uint16_t *)p_slow_count)
#define DIVISOR    (*(int16_t *)p_divisor)
#define KEEP_IN    (*(int16_t *)p_keep_in)
#define KEEP_OUT   (*(int16_t *)p_keep_out)
#define PRESET     (*(int16_t *)p_preset)
#define D_IN       (*(int32_t *)p_d_in)
#define D_OUT      (*(int32_t *)p_d_out)
#define SCANS_OUT  (*(uint32_t *)p_scans_out)
#define CLOCK_MS   (*(uint32_t *)p_clock_ms)
#define TICK_OUT   (*(uint32_t *)p_tick_out)
#define L_IN       (*(int64_t *)p_l_in)
#define L_OUT      (*(int64_t *)p_l_out)

static struct {
    plc_bool_t host_bit, echo_bit, alive;
    int16_t in_word, echo_word, quotient;
    uint16_t tick_first, tick_last, slow_count;
    int16_t divisor, keep_in, keep_out, preset;
    int32_t d_in, d_out;
    uint32_t scans_out, clock_ms, tick_out;
    int64_t l_in, l_out;
} own;

/* Ordinary and retained variables. */
static int16_t keep;
static uint32_t scans;
static uint16_t slow;
static int64_t clock_ns;
static plc_fault_t fault;

static const plc_task_t tasks[] = {
    { "FAST", FIXTURE_BASE_TICK_NS, 1, 1 },
    { "SLOW", 5u * FIXTURE_BASE_TICK_NS, 5, 2 },
};

#define LOC(addr, var, area, size, type, index, bit, ptr) \
    { addr, "CONFIG0.RES0.MAIN." var, area, size, type, index, bit, &ptr, 0 }

static const plc_located_t located[] = {
    LOC("%IX50.0", "HOSTBIT", 'I', 'X', PLC_T_BOOL, 50, 0, p_host_bit),
    LOC("%QX0.1", "ECHOBIT", 'Q', 'X', PLC_T_BOOL, 0, 1, p_echo_bit),
    LOC("%QX0.0", "ALIVE", 'Q', 'X', PLC_T_BOOL, 0, 0, p_alive),
    LOC("%IW512", "INWORD", 'I', 'W', PLC_T_INT, 512, 0, p_in_word),
    LOC("%QW1", "ECHOWORD", 'Q', 'W', PLC_T_INT, 1, 0, p_echo_word),
    LOC("%QW3", "QUOTIENT", 'Q', 'W', PLC_T_INT, 3, 0, p_quotient),
    LOC("%QW20", "TICKFIRST", 'Q', 'W', PLC_T_WORD, 20, 0, p_tick_first),
    LOC("%QW21", "TICKLAST", 'Q', 'W', PLC_T_WORD, 21, 0, p_tick_last),
    LOC("%QW30", "SLOWCOUNT", 'Q', 'W', PLC_T_UINT, 30, 0, p_slow_count),
    LOC("%MW10", "DIVISOR", 'M', 'W', PLC_T_INT, 10, 0, p_divisor),
    LOC("%MW20", "KEEPIN", 'M', 'W', PLC_T_INT, 20, 0, p_keep_in),
    LOC("%MW21", "KEEPOUT", 'M', 'W', PLC_T_INT, 21, 0, p_keep_out),
    LOC("%MW30", "PRESET", 'M', 'W', PRESET_TYPE, 30, 0, p_preset),
    LOC("%MD0", "DIN", 'M', 'D', PLC_T_DINT, 0, 0, p_d_in),
    LOC("%MD1", "DOUT", 'M', 'D', PLC_T_DINT, 1, 0, p_d_out),
    LOC("%MD5", "SCANSOUT", 'M', 'D', PLC_T_UDINT, 5, 0, p_scans_out),
    LOC("%MD6", "CLOCKMS", 'M', 'D', PLC_T_UDINT, 6, 0, p_clock_ms),
    LOC("%MD7", "TICKOUT", 'M', 'D', PLC_T_UDINT, 7, 0, p_tick_out),
    LOC("%ML0", "LIN", 'M', 'L', PLC_T_LINT, 0, 0, p_l_in),
    LOC("%ML1", "LOUT", 'M', 'L', PLC_T_LINT, 1, 0, p_l_out),
};

static const plc_var_t vars[] = {
    { "CONFIG0.RES0.MAIN.KEEP", PLC_T_INT, 1, 0, &keep, sizeof keep, "INT" },
    { "CONFIG0.RES0.MAIN.SCANS", PLC_T_UDINT, 1, 0, &scans, sizeof scans, "UDINT" },
    { "CONFIG0.RES0.MAIN.SLOW", PLC_T_UINT, 0, 0, &slow, sizeof slow, "UINT" },
};

static void fixture_init(void)
{
    memset(&own, 0, sizeof own);
    p_host_bit = &own.host_bit;
    p_echo_bit = &own.echo_bit;
    p_alive = &own.alive;
    p_in_word = &own.in_word;
    p_echo_word = &own.echo_word;
    p_quotient = &own.quotient;
    p_tick_first = &own.tick_first;
    p_tick_last = &own.tick_last;
    p_slow_count = &own.slow_count;
    p_divisor = &own.divisor;
    p_keep_in = &own.keep_in;
    p_keep_out = &own.keep_out;
    p_preset = &own.preset;
    p_d_in = &own.d_in;
    p_d_out = &own.d_out;
    p_scans_out = &own.scans_out;
    p_clock_ms = &own.clock_ms;
    p_tick_out = &own.tick_out;
    p_l_in = &own.l_in;
    p_l_out = &own.l_out;
    ALIVE = 1;
    PRESET = 4242;
    keep = 0;
    scans = 0;
    slow = 0;
    fault = (plc_fault_t){ 0 };
}

static void task_fast(uint64_t tick)
{
    volatile unsigned spin = 0;

    TICK_FIRST = (uint16_t)tick;
    /* a little work between the first and the last write of the scan */
    for (unsigned i = 0; i < 200; i++)
        spin = spin + i;
    ECHO_BIT = HOST_BIT;
    ECHO_WORD = (int16_t)(IN_WORD + 1);
    D_OUT = (int32_t)((uint32_t)D_IN + 1u);
    L_OUT = (int64_t)((uint64_t)L_IN + 1u);
    if (DIVISOR == 13 || DIVISOR == 14) {
        struct timespec t0, t;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        do {
            spin = spin + 1;
            clock_gettime(CLOCK_MONOTONIC, &t);
        } while (DIVISOR == 13 || (t.tv_sec - t0.tv_sec) * 1000 + (t.tv_nsec - t0.tv_nsec) / 1000000 < 1500);
    }
    if (DIVISOR - 7 == 0) {
        fault = (plc_fault_t){ PLC_FAULT_DIV_ZERO, "MAIN", "fixture_basic.st", 42, 27 };
        return;
    }
    QUOTIENT = (int16_t)(100 / (DIVISOR - 7));
    if (KEEP_IN != 0)
        keep = KEEP_IN;
    KEEP_OUT = keep;
    scans++;
    SCANS_OUT = scans;
    CLOCK_MS = (uint32_t)(clock_ns / 1000000);
    TICK_OUT = (uint32_t)tick;
    TICK_LAST = (uint16_t)tick;
}

static void task_slow(void)
{
    slow++;
    SLOW_COUNT = slow;
}

static int fixture_run(uint64_t tick)
{
    if (fault.kind)
        return fault.kind;
    if (tick % tasks[0].every == 0)
        task_fast(tick);
    if (fault.kind)
        return fault.kind;
    if (tick % tasks[1].every == 0)
        task_slow();
    return 0;
}

const plc_program_t plc_program = {
    .abi_version = FIXTURE_ABI_VERSION,
    .config_name = "CONFIG0",
    .base_tick_ns = FIXTURE_BASE_TICK_NS,
    .tasks = tasks,
    .n_tasks = sizeof tasks / sizeof tasks[0],
    .located = located,
    .n_located = sizeof located / sizeof located[0],
    .vars = vars,
    .n_vars = sizeof vars / sizeof vars[0],
    .layout_hash = FIXTURE_LAYOUT_HASH,
    .init = fixture_init,
    .run = fixture_run,
    .clock_ns = &clock_ns,
    .fault = &fault,
};
