/*
 * image.c - the I/O image and OpenPLC's address map.
 *
 * Two images: the program image (prog_image_t, scan_core.h), into and out of
 * which the scan core copies the program's located variables and which only
 * the scan thread touches, and the Modbus image (bus_image_t), which the
 * server reads and writes under runtime_t.lock.  They meet only at scan
 * boundaries:
 *
 *   scan start  image_take_host_writes(): host writes queued since the last
 *               scan are copied into the program image, whole requests at a
 *               time (a request is applied entirely before a scan or after).
 *   scan end    image_publish(): the program image's bits and input words
 *               and the program's own holding registers (its located %QW %MW
 *               %MD %ML) are copied to the Modbus image, then writes that
 *               arrived during the scan are laid back on top, so a client
 *               reads back what it wrote.  Other holding registers change
 *               only by host writes, which the Modbus image already holds
 *               (image_publish_all() copies everything, at start-up).
 *
 * A read therefore always sees the outputs of one complete scan.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "runtime.h"

/* ------------------------------------------------------------ addr sets */

int addr_set_parse(addr_set_t *s, const char *text, unsigned limit, char *err, size_t errlen)
{
    const char *p = text;

    while (*p) {
        char *end;
        unsigned long lo, hi;

        while (*p == ' ' || *p == ',')
            p++;
        if (!*p)
            break;
        if (*p < '0' || *p > '9')
            goto bad;
        lo = strtoul(p, &end, 10);
        hi = lo;
        p = end;
        if (*p == '-') {
            p++;
            if (*p < '0' || *p > '9')
                goto bad;
            hi = strtoul(p, &end, 10);
            p = end;
        }
        if (*p && *p != ',' && *p != ' ')
            goto bad;
        if (lo > hi || hi >= limit) {
            snprintf(err, errlen, "range %lu-%lu in '%s' is outside 0-%u", lo, hi, text, limit - 1);
            return -1;
        }
        for (unsigned long a = lo; a <= hi; a++)
            addr_set_add(s, (unsigned)a);
    }
    return 0;
bad:
    snprintf(err, errlen, "cannot read '%s': expected addresses like 400-799,1024", text);
    return -1;
}

/* -------------------------------------------------------------- binding */

static void log_unmapped(void *ctx, const plc_located_t *l, const char *why)
{
    runtime_t *rt = ctx;

    log_msg(rt->log, LOG_WARN, "%s at %s is not on the Modbus map (%s); it stays inside the program",
            l->var, l->address, why);
}

int image_bind_program(runtime_t *rt, char *err, size_t errlen)
{
    return plc_scan_bind(&rt->core, rt->prog, &rt->pimg, log_unmapped, rt, err, errlen);
}

/* ------------------------------------------------------- register codec */

uint16_t image_prog_holding(const prog_image_t *p, unsigned a)
{
    if (a < MAP_HOLD_MW)
        return p->qw[a];
    if (a < MAP_HOLD_MD)
        return p->mw[a - MAP_HOLD_MW];
    if (a < MAP_HOLD_ML) {
        unsigned k = a - MAP_HOLD_MD;
        uint32_t v = p->md[k / 2].u;
        return (uint16_t)(k % 2 == 0 ? v >> 16 : v);
    }
    unsigned k = a - MAP_HOLD_ML;
    uint64_t v = p->ml[k / 4].u;
    return (uint16_t)(v >> (16 * (3 - k % 4)));
}

void image_prog_set_holding(prog_image_t *p, unsigned a, uint16_t v)
{
    if (a < MAP_HOLD_MW) {
        p->qw[a] = v;
    } else if (a < MAP_HOLD_MD) {
        p->mw[a - MAP_HOLD_MW] = v;
    } else if (a < MAP_HOLD_ML) {
        unsigned k = a - MAP_HOLD_MD;
        uint32_t *u = &p->md[k / 2].u;
        if (k % 2 == 0)
            *u = (*u & 0x0000ffffu) | ((uint32_t)v << 16);
        else
            *u = (*u & 0xffff0000u) | v;
    } else {
        unsigned k = a - MAP_HOLD_ML;
        unsigned shift = 16 * (3 - k % 4);
        uint64_t *u = &p->ml[k / 4].u;
        *u = (*u & ~((uint64_t)0xffff << shift)) | ((uint64_t)v << shift);
    }
}

/* ------------------------------------------------------- scan boundaries */

/* The address of the lowest set bit of word w of a dirty set, cleared from *bits. */
static inline unsigned pop_lowest(uint64_t *bits, unsigned w)
{
    unsigned a = w * 64 + (unsigned)__builtin_ctzll(*bits);

    *bits &= *bits - 1;
    return a;
}

void image_take_host_writes(runtime_t *rt)
{
    bus_image_t *b = &rt->bimg;
    prog_image_t *p = &rt->pimg;

    if (!b->any_dirty)
        return;
    for (unsigned w = 0; w < MAP_BITS / 64 + 1; w++) {
        uint64_t bits = b->dirty_coils.bits[w];
        while (bits) {
            unsigned a = pop_lowest(&bits, w);
            p->qx[a] = b->pending_coils[a];
        }
        b->dirty_coils.bits[w] = 0;
    }
    for (unsigned w = 0; w < MAP_HOLDING / 64; w++) {
        uint64_t bits = b->dirty_holding.bits[w];
        while (bits) {
            unsigned a = pop_lowest(&bits, w);
            image_prog_set_holding(p, a, b->pending_holding[a]);
        }
        b->dirty_holding.bits[w] = 0;
    }
    b->any_dirty = false;
}

/* The holding registers of %MDn and %MLn, high word first. */
static void put_md(bus_image_t *b, unsigned i, uint32_t d)
{
    uint16_t *r = &b->holding[MAP_HOLD_MD + 2 * i];

    r[0] = (uint16_t)(d >> 16);
    r[1] = (uint16_t)d;
}

static void put_ml(bus_image_t *b, unsigned i, uint64_t l)
{
    uint16_t *r = &b->holding[MAP_HOLD_ML + 4 * i];

    r[0] = (uint16_t)(l >> 48);
    r[1] = (uint16_t)(l >> 32);
    r[2] = (uint16_t)(l >> 16);
    r[3] = (uint16_t)l;
}

/* Writes that arrived during this scan stay visible until applied. */
static void overlay_pending(bus_image_t *b)
{
    for (unsigned w = 0; w < MAP_BITS / 64 + 1; w++) {
        uint64_t bits = b->dirty_coils.bits[w];
        while (bits) {
            unsigned a = pop_lowest(&bits, w);
            b->coils[a] = b->pending_coils[a];
        }
    }
    for (unsigned w = 0; w < MAP_HOLDING / 64; w++) {
        uint64_t bits = b->dirty_holding.bits[w];
        while (bits) {
            unsigned a = pop_lowest(&bits, w);
            b->holding[a] = b->pending_holding[a];
        }
    }
}

void image_publish_all(runtime_t *rt)
{
    bus_image_t *b = &rt->bimg;
    const prog_image_t *p = &rt->pimg;

    memcpy(b->coils, p->qx, MAP_BITS);
    memcpy(b->discrete, p->ix, MAP_BITS);
    memcpy(b->input_regs, p->iw, sizeof p->iw);
    memcpy(&b->holding[MAP_HOLD_QW], p->qw, sizeof p->qw);
    memcpy(&b->holding[MAP_HOLD_MW], p->mw, sizeof p->mw);
    for (unsigned i = 0; i < MAP_WORDS; i++) {
        put_md(b, i, p->md[i].u);
        put_ml(b, i, p->ml[i].u);
    }
    if (b->any_dirty)
        overlay_pending(b);
}

void image_publish(runtime_t *rt)
{
    bus_image_t *b = &rt->bimg;
    const prog_image_t *p = &rt->pimg;
    const plc_scan_t *core = &rt->core;

    /* Bits and input words: the I/O layer may change any of them. */
    memcpy(b->coils, p->qx, MAP_BITS);
    memcpy(b->discrete, p->ix, MAP_BITS);
    memcpy(b->input_regs, p->iw, sizeof p->iw);
    /* Holding registers: only the program's; the others change only by host
     * writes, which the Modbus image already holds.  Where a binding's slot
     * lies in the image says which register it is. */
    for (uint32_t i = core->n_inputs; i < core->n_bindings; i++) {
        const char *slot = core->bindings[i].slot;

        if (slot >= (const char *)p->qw && slot < (const char *)(p->qw + MAP_WORDS))
            b->holding[MAP_HOLD_QW + (size_t)((const uint16_t *)slot - p->qw)] = *(const uint16_t *)slot;
        else if (slot >= (const char *)p->mw && slot < (const char *)(p->mw + MAP_WORDS))
            b->holding[MAP_HOLD_MW + (size_t)((const uint16_t *)slot - p->mw)] = *(const uint16_t *)slot;
        else if (slot >= (const char *)p->md && slot < (const char *)(p->md + MAP_WORDS))
            put_md(b, (unsigned)((const plc_slot32_t *)slot - p->md), ((const plc_slot32_t *)slot)->u);
        else if (slot >= (const char *)p->ml && slot < (const char *)(p->ml + MAP_WORDS))
            put_ml(b, (unsigned)((const plc_slot64_t *)slot - p->ml), ((const plc_slot64_t *)slot)->u);
        /* else a coil: copied above */
    }
    if (b->any_dirty)
        overlay_pending(b);
}

void image_make_outputs_safe(prog_image_t *p)
{
    memset(p->qx, 0, sizeof p->qx);
}

void image_host_write_coil(bus_image_t *b, unsigned a, bool on)
{
    b->coils[a] = on;
    b->pending_coils[a] = on;
    addr_set_add(&b->dirty_coils, a);
    b->any_dirty = true;
}

void image_host_write_register(bus_image_t *b, unsigned a, uint16_t v)
{
    b->holding[a] = v;
    b->pending_holding[a] = v;
    addr_set_add(&b->dirty_holding, a);
    b->any_dirty = true;
}

/* ------------------------------------------------------- diagnostic block */

void diag_put16(bus_image_t *b, unsigned off, uint16_t v)
{
    b->input_regs[DIAG_BASE + off] = v;
}

void diag_put32(bus_image_t *b, unsigned off, uint32_t v)
{
    b->input_regs[DIAG_BASE + off] = (uint16_t)(v >> 16);
    b->input_regs[DIAG_BASE + off + 1] = (uint16_t)v;
}

void diag_put64(bus_image_t *b, unsigned off, uint64_t v)
{
    diag_put32(b, off, (uint32_t)(v >> 32));
    diag_put32(b, off + 2, (uint32_t)v);
}

uint32_t diag_get32(const bus_image_t *b, unsigned off)
{
    return ((uint32_t)b->input_regs[DIAG_BASE + off] << 16) | b->input_regs[DIAG_BASE + off + 1];
}

uint64_t diag_get64(const bus_image_t *b, unsigned off)
{
    return ((uint64_t)diag_get32(b, off) << 32) | diag_get32(b, off + 2);
}
