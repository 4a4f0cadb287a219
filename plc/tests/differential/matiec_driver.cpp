/*
 * matiec_driver.cpp - steps the C that OpenPLC v3's iec2c generated, scan by scan, for the differential
 * (plc/tests/test_openplc_differential.py).  Built like OpenPLC builds it, against OpenPLC's own headers:
 *
 *     g++ -std=gnu++11 -I <OpenPLC_v3/webserver/core/lib> Config0.c Res0.c matiec_driver.cpp
 *
 * It does what OpenPLC's main loop does around the program, without threads, Modbus or a clock: the located
 * variables are plain memory (as OpenPLC's generated glueVars.cpp declares them), each scan runs
 * config_run__(tick) and then advances __CURRENT_TIME by common_ticktime__ (OpenPLC's updateTime()).
 *
 * Protocol (the same as abi_driver.c's):
 *   out:  "loc <ADDRESS>" for every located variable, then "ready"
 *   in:   one line per scan: "<ADDRESS>=<value> ..." (what the host writes before this scan; may be empty)
 *   out:  "o <value> ..." after the scan, the located variables in the order of the loc lines
 * With --quiet it answers nothing after a scan (scripts/bench_scan.py replays a recorded script under callgrind).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "iec_std_lib.h"

TIME __CURRENT_TIME;
extern unsigned long long common_ticktime__;
void config_init__(void);
void config_run__(unsigned long tick);

/* OpenPLC's library declares its TCP blocks' helpers; the program calls none of them. */
int connect_to_tcp_server(uint8_t *, uint16_t, int) { return -1; }
int send_tcp_message(uint8_t *, size_t, int) { return -1; }
int receive_tcp_message(uint8_t *, size_t, int) { return -1; }
int close_tcp_connection(int) { return -1; }

#define __LOCATED_VAR(type, name, ...) type __##name;
#include "LOCATED_VARIABLES.h"
#undef __LOCATED_VAR
#define __LOCATED_VAR(type, name, ...) type *name = &__##name;
#include "LOCATED_VARIABLES.h"
#undef __LOCATED_VAR

struct located {
    const char *name;       /* __QX10_0 */
    const char *type;       /* BOOL, INT, ... */
    void *value;
    char address[32];       /* %QX10.0 */
};

#define __LOCATED_VAR(type, name, ...) {#name, #type, &__##name, ""},
static located table[] = {
#include "LOCATED_VARIABLES.h"
};
#undef __LOCATED_VAR
static const size_t n_located = sizeof table / sizeof table[0];

static long long get(const located *l) {
    const char *t = l->type;
    if (!strcmp(t, "BOOL") || !strcmp(t, "USINT") || !strcmp(t, "BYTE")) return *(uint8_t *)l->value;
    if (!strcmp(t, "SINT")) return *(int8_t *)l->value;
    if (!strcmp(t, "INT")) return *(int16_t *)l->value;
    if (!strcmp(t, "UINT") || !strcmp(t, "WORD")) return *(uint16_t *)l->value;
    if (!strcmp(t, "DINT")) return *(int32_t *)l->value;
    if (!strcmp(t, "UDINT") || !strcmp(t, "DWORD")) return *(uint32_t *)l->value;
    return *(int64_t *)l->value;
}

static void put(const located *l, long long v) {
    const char *t = l->type;
    if (!strcmp(t, "BOOL")) *(uint8_t *)l->value = v != 0;
    else if (!strcmp(t, "USINT") || !strcmp(t, "BYTE") || !strcmp(t, "SINT")) *(uint8_t *)l->value = (uint8_t)v;
    else if (!strcmp(t, "INT") || !strcmp(t, "UINT") || !strcmp(t, "WORD")) *(uint16_t *)l->value = (uint16_t)v;
    else if (!strcmp(t, "DINT") || !strcmp(t, "UDINT") || !strcmp(t, "DWORD")) *(uint32_t *)l->value = (uint32_t)v;
    else *(int64_t *)l->value = v;
}

static located *find(const char *address) {
    for (size_t i = 0; i < n_located; i++)
        if (!strcmp(table[i].address, address))
            return &table[i];
    return NULL;
}

int main(int argc, char **argv) {
    bool quiet = argc > 1 && !strcmp(argv[1], "--quiet");
    for (size_t i = 0; i < n_located; i++) {          /* __IX0_0 -> %IX0.0 */
        snprintf(table[i].address, sizeof table[i].address, "%%%s", table[i].name + 2);
        for (char *c = table[i].address; *c; c++)
            if (*c == '_')
                *c = '.';
    }
    config_init__();
    for (size_t i = 0; i < n_located; i++)
        printf("loc %s\n", table[i].address);
    printf("ready\n");
    fflush(stdout);
    static char line[1 << 16];
    unsigned long tick = 0;
    while (fgets(line, sizeof line, stdin)) {
        char *rest = NULL;
        for (char *tok = strtok_r(line, " \n", &rest); tok; tok = strtok_r(NULL, " \n", &rest)) {
            char *eq = strchr(tok, '=');
            located *l = eq ? (*eq = '\0', find(tok)) : NULL;
            if (!l) {
                fprintf(stderr, "matiec_driver: bad write '%s'\n", tok);
                return 2;
            }
            put(l, strtoll(eq + 1, NULL, 10));
        }
        config_run__(tick++);
        __CURRENT_TIME.tv_sec += common_ticktime__ / 1000000000ULL;      /* OpenPLC's updateTime() */
        __CURRENT_TIME.tv_nsec += common_ticktime__ % 1000000000ULL;
        if (__CURRENT_TIME.tv_nsec >= 1000000000) {
            __CURRENT_TIME.tv_nsec -= 1000000000;
            __CURRENT_TIME.tv_sec += 1;
        }
        if (quiet)
            continue;
        fputs("o", stdout);
        for (size_t i = 0; i < n_located; i++)
            printf(" %lld", get(&table[i]));
        putchar('\n');
        fflush(stdout);
    }
    return 0;
}
