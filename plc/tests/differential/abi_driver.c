/*
 * abi_driver.c - steps a program `plc build` generated, scan by scan, through plc_abi.h, for the differential
 * (plc/tests/test_openplc_differential.py); the counterpart of matiec_driver.cpp, with the same protocol:
 *
 *   out:  "loc <ADDRESS>" for every located variable, then "ready"
 *   in:   one line per scan: "<ADDRESS>=<value> ..." (what the host writes before this scan; may be empty)
 *   out:  "o <value> ..." after the scan, the located variables in the order of the loc lines;
 *         "fault <kind>" instead when the program faulted
 *
 * Scan n (from 0) runs the tasks of tick n with the clock at n base ticks, as OpenPLC's loop does.
 * With --quiet it answers nothing after a scan (scripts/bench_scan.py replays a recorded script under callgrind).
 */
#define _POSIX_C_SOURCE 200809L      /* strtok_r */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "plc_abi.h"

#define MAX_LOCATED 4096

static uint64_t storage[MAX_LOCATED];

static long long get(const plc_located_t *l) {
    const void *v = *l->ptr;
    switch ((plc_type_t)l->type) {
    case PLC_T_BOOL: case PLC_T_USINT: case PLC_T_BYTE: return *(const uint8_t *)v;
    case PLC_T_SINT: return *(const int8_t *)v;
    case PLC_T_INT: return *(const int16_t *)v;
    case PLC_T_UINT: case PLC_T_WORD: return *(const uint16_t *)v;
    case PLC_T_DINT: case PLC_T_ENUM: return *(const int32_t *)v;
    case PLC_T_UDINT: case PLC_T_DWORD: return *(const uint32_t *)v;
    default: return *(const int64_t *)v;
    }
}

static void put(const plc_located_t *l, long long x) {
    void *v = *l->ptr;
    switch ((plc_type_t)l->type) {
    case PLC_T_BOOL: *(uint8_t *)v = x != 0; break;
    case PLC_T_USINT: case PLC_T_BYTE: case PLC_T_SINT: *(uint8_t *)v = (uint8_t)x; break;
    case PLC_T_INT: case PLC_T_UINT: case PLC_T_WORD: *(uint16_t *)v = (uint16_t)x; break;
    case PLC_T_DINT: case PLC_T_ENUM: case PLC_T_UDINT: case PLC_T_DWORD: *(uint32_t *)v = (uint32_t)x; break;
    default: *(int64_t *)v = x; break;
    }
}

static const plc_located_t *find(const char *address) {
    for (uint32_t i = 0; i < plc_program.n_located; i++)
        if (!strcmp(plc_program.located[i].address, address))
            return &plc_program.located[i];
    return NULL;
}

int main(int argc, char **argv) {
    const plc_program_t *p = &plc_program;
    int quiet = argc > 1 && !strcmp(argv[1], "--quiet");
    if (p->n_located > MAX_LOCATED) {
        fprintf(stderr, "abi_driver: %u located variables, %d at most\n", (unsigned)p->n_located, MAX_LOCATED);
        return 2;
    }
    for (uint32_t i = 0; i < p->n_located; i++)
        *p->located[i].ptr = &storage[i];
    *p->clock_ns = 0;
    p->init();
    for (uint32_t i = 0; i < p->n_located; i++)
        printf("loc %s\n", p->located[i].address);
    printf("ready\n");
    fflush(stdout);
    static char line[1 << 16];
    uint64_t tick = 0;
    while (fgets(line, sizeof line, stdin)) {
        char *rest = NULL;
        for (char *tok = strtok_r(line, " \n", &rest); tok; tok = strtok_r(NULL, " \n", &rest)) {
            char *eq = strchr(tok, '=');
            const plc_located_t *l = eq ? (*eq = '\0', find(tok)) : NULL;
            if (!l) {
                fprintf(stderr, "abi_driver: bad write '%s'\n", tok);
                return 2;
            }
            put(l, strtoll(eq + 1, NULL, 10));
        }
        *p->clock_ns = (int64_t)(tick * p->base_tick_ns);
        int rc = p->run(tick++);
        if (quiet) {
            continue;
        } else if (rc) {
            printf("fault %d\n", rc);
        } else {
            fputs("o", stdout);
            for (uint32_t i = 0; i < p->n_located; i++)
                printf(" %lld", get(&p->located[i]));
            putchar('\n');
        }
        fflush(stdout);
    }
    return 0;
}
