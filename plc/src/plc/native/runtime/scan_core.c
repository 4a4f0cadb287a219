/*
 * scan_core.c - the one scan core (see scan_core.h for the stages).
 *
 * Shared by the soft-PLC runtime, the `plc test` runner and the test driver;
 * C99 and libc only, no threads, locks or clocks.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scan_core.h"

/* ------------------------------------------------------------- binding */

static unsigned type_bytes(unsigned type)
{
    switch (type) {
    case PLC_T_BOOL: case PLC_T_SINT: case PLC_T_USINT: case PLC_T_BYTE:
        return 1;
    case PLC_T_INT: case PLC_T_UINT: case PLC_T_WORD:
        return 2;
    case PLC_T_DINT: case PLC_T_UDINT: case PLC_T_DWORD: case PLC_T_REAL: case PLC_T_ENUM:
        return 4;
    case PLC_T_LINT: case PLC_T_ULINT: case PLC_T_LWORD: case PLC_T_LREAL:
    case PLC_T_TIME: case PLC_T_DATE: case PLC_T_TOD: case PLC_T_DT:
        return 8;
    default:
        return 0;
    }
}

unsigned plc_located_bytes(char size)
{
    switch (size) {
    case 'X': case 'B': return 1;
    case 'W': return 2;
    case 'D': return 4;
    case 'L': return 8;
    default: return 0;
    }
}

void *plc_image_slot(plc_image_t *p, const plc_located_t *l, const char **why)
{
    unsigned n = l->index;

    *why = NULL;
    if (l->size == 'X') {
        if ((l->area != 'I' && l->area != 'Q') || n >= PLC_MAP_BITS / 8 || l->bit > 7) {
            *why = "bit outside %IX0.0-%IX99.7 / %QX0.0-%QX99.7";
            return NULL;
        }
        return l->area == 'I' ? &p->ix[n * 8 + l->bit] : &p->qx[n * 8 + l->bit];
    }
    if (n >= PLC_MAP_WORDS) {
        *why = "index above 1023";
        return NULL;
    }
    switch (l->size) {
    case 'W':
        if (l->area == 'I')
            return &p->iw[n];
        if (l->area == 'Q')
            return &p->qw[n];
        return &p->mw[n];
    case 'D':
        if (l->area == 'M')
            return &p->md[n];
        break;
    case 'L':
        if (l->area == 'M')
            return &p->ml[n];
        break;
    default:
        break;
    }
    *why = "OpenPLC maps only %IX %QX %IW %QW %MW %MD %ML to Modbus";
    return NULL;
}

static plc_binding_t *bound_at(plc_scan_t *s, const void *slot)
{
    for (uint32_t i = 0; i < s->n_bindings; i++)
        if (s->bindings[i].slot == slot)
            return &s->bindings[i];
    return NULL;
}

int plc_scan_bind(plc_scan_t *s, const plc_program_t *prog, plc_image_t *image,
                  plc_unmapped_fn unmapped, void *unmapped_ctx, char *err, size_t errlen)
{
    memset(s, 0, sizeof *s);
    s->latch_all = 1;
    s->prog = prog;
    s->image = image;
    if (prog->n_located) {
        s->bindings = calloc(prog->n_located, sizeof *s->bindings);
        if (s->bindings == NULL) {
            snprintf(err, errlen, "out of memory binding %u located variables", (unsigned)prog->n_located);
            return -1;
        }
    }
    /* Two passes, so the inputs come first: the latch of a stopped program
     * and the publication only walk the part they need. */
    for (int inputs = 1; inputs >= 0; inputs--) {
        for (uint32_t i = 0; i < prog->n_located; i++) {
            const plc_located_t *l = &prog->located[i];
            unsigned want = plc_located_bytes(l->size);
            unsigned have = type_bytes(l->type);
            const char *why;
            void *slot;
            plc_binding_t *shared;

            if ((l->area == 'I') != inputs)
                continue;
            if (want == 0 || (l->area != 'I' && l->area != 'Q' && l->area != 'M') || l->ptr == NULL ||
                *l->ptr == NULL) {
                snprintf(err, errlen, "located variable %s at %s: malformed entry (area %c, size %c)",
                         l->var, l->address, l->area ? l->area : '?', l->size ? l->size : '?');
                plc_scan_free(s);
                return -1;
            }
            if (have != want || (l->size == 'X' && l->type != PLC_T_BOOL)) {
                snprintf(err, errlen, "located variable %s at %s: its type takes %u bytes, the address %u",
                         l->var, l->address, have, want);
                plc_scan_free(s);
                return -1;
            }
            slot = plc_image_slot(image, l, &why);
            if (slot == NULL) {
                if (unmapped)
                    unmapped(unmapped_ctx, l, why);
                continue;
            }
            /* The image starts from the initial value that init() gave the variable. */
            memcpy(slot, *l->ptr, want);
            shared = bound_at(s, slot);
            if (shared != NULL) {
                /* Several PROGRAMs at one address share one variable, as in
                 * MATIEC: the program that runs last in the scan wins. */
                memcpy(shared->var, *l->ptr, want);
                *l->ptr = shared->var;
                continue;
            }
            s->bindings[s->n_bindings++] = (plc_binding_t){ *l->ptr, slot, want, i };
            s->n_inputs += l->area == 'I';
        }
    }
    return 0;
}

void plc_scan_free(plc_scan_t *s)
{
    free(s->bindings);
    s->bindings = NULL;
    s->n_bindings = s->n_inputs = 0;
}

void plc_scan_restart(plc_scan_t *s)
{
    s->latch_all = 1;
    s->tick = 0;
    s->scans = 0;
    s->fault = 0;
}

/* ---------------------------------------------------------------- copy */

/* Located variables are 1, 2, 4 or 8 bytes: a fixed-size copy each, no memcpy call. */
static inline void copy_value(void *to, const void *from, uint32_t size)
{
    switch (size) {
    case 1: *(uint8_t *)to = *(const uint8_t *)from; break;
    case 2: memcpy(to, from, 2); break;
    case 4: memcpy(to, from, 4); break;
    default: memcpy(to, from, 8); break;
    }
}

/* ---------------------------------------------------------------- stages */

void plc_scan_latch_inputs(plc_scan_t *s)
{
    uint32_t n = s->n_inputs;

    if (s->io.read_inputs && s->io.read_inputs(s->io.ctx, s->image))
        s->latch_all = 1;
    /* Inputs; and outputs and memory when the world wrote them since the last scan. */
    if (s->latch_all) {
        n = s->n_bindings;
        s->latch_all = 0;
    }
    for (uint32_t i = 0; i < n; i++)
        copy_value(s->bindings[i].var, s->bindings[i].slot, s->bindings[i].size);
}

void plc_scan_force_inputs(plc_scan_t *s)
{
    if (s->hooks.after_inputs)
        s->hooks.after_inputs(s->hooks.ctx);
}

void plc_scan_reflect_inputs(plc_scan_t *s)
{
    for (uint32_t i = 0; i < s->n_inputs; i++)
        copy_value(s->bindings[i].slot, s->bindings[i].var, s->bindings[i].size);
}

int plc_scan_run_tasks(plc_scan_t *s, int64_t now_ns)
{
    if (s->fault == 0) {
        int rc;

        *s->prog->clock_ns = now_ns;
        rc = s->run ? s->run(s->run_ctx, s->tick) : s->prog->run(s->tick);
        if (rc != 0)
            s->fault = rc;
    }
    s->tick++;
    return s->fault;
}

void plc_scan_publish_outputs(plc_scan_t *s)
{
    const int running = s->fault == 0;

    if (s->hooks.before_outputs)
        s->hooks.before_outputs(s->hooks.ctx);
    if (running) {
        for (uint32_t i = s->n_inputs; i < s->n_bindings; i++)
            copy_value(s->bindings[i].slot, s->bindings[i].var, s->bindings[i].size);
    } else {
        /* Safe state: every coil FALSE; %QW keep their last values in the image. */
        memset(s->image->qx, 0, sizeof s->image->qx);
    }
    if (s->io.write_outputs)
        s->io.write_outputs(s->io.ctx, s->image, running);
    s->scans++;
    if (s->hooks.scan_done)
        s->hooks.scan_done(s->hooks.ctx, s->scans);
}

int plc_scan_step(plc_scan_t *s, int64_t now_ns)
{
    plc_scan_latch_inputs(s);
    plc_scan_force_inputs(s);
    plc_scan_run_tasks(s, now_ns);
    plc_scan_publish_outputs(s);
    return s->fault;
}
