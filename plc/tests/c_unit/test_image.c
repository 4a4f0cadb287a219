/*
 * test_image.c - image.c with the scan core's address map (scan_core.c):
 * where each located address lives in the program image, OpenPLC's holding
 * register map (%QW %MW, %MD and %ML high word first), host writes applied
 * between scans, the publication to the Modbus image, the address sets of
 * --writable-* and --retain-registers, the diagnostic block's words.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "check.h"
#include "logcap.h"
#include "runtime.h"

static runtime_t *new_runtime(const plc_program_t *prog)
{
    runtime_t *rt = calloc(1, sizeof *rt);

    if (rt) {
        rt->prog = prog;
        rt->log = logcap_sink();
    }
    return rt;
}

static void free_runtime(runtime_t *rt)
{
    plc_scan_free(&rt->core);
    free(rt);
}

/* ------------------------------------------------------------ address map */

typedef struct slot_row {
    const char *address;
    char area, size;
    uint32_t index;
    uint8_t bit;
    ptrdiff_t at;                 /* byte offset of the slot in the image; -1: not on the map */
    const char *why;
} slot_row_t;

#define AT(field, i) ((ptrdiff_t)(offsetof(plc_image_t, field) + (i) * sizeof(((plc_image_t *)0)->field[0])))

static void located_addresses_map_to_their_image_slots(void)
{
    const slot_row_t rows[] = {
        { "%IX0.0", 'I', 'X', 0, 0, AT(ix, 0), NULL },
        { "%IX0.7", 'I', 'X', 0, 7, AT(ix, 7), NULL },
        { "%IX1.0", 'I', 'X', 1, 0, AT(ix, 8), NULL },
        { "%IX99.7", 'I', 'X', 99, 7, AT(ix, 799), NULL },
        { "%IX100.0", 'I', 'X', 100, 0, -1, "bit outside %IX0.0-%IX99.7 / %QX0.0-%QX99.7" },
        { "%IX0.8", 'I', 'X', 0, 8, -1, "bit outside" },
        { "%QX0.0", 'Q', 'X', 0, 0, AT(qx, 0), NULL },
        { "%QX50.0", 'Q', 'X', 50, 0, AT(qx, 400), NULL },
        { "%QX99.7", 'Q', 'X', 99, 7, AT(qx, 799), NULL },
        { "%QX100.0", 'Q', 'X', 100, 0, -1, "bit outside" },
        { "%MX0.0", 'M', 'X', 0, 0, -1, "bit outside" },
        { "%IW0", 'I', 'W', 0, 0, AT(iw, 0), NULL },
        { "%IW1023", 'I', 'W', 1023, 0, AT(iw, 1023), NULL },
        { "%IW1024", 'I', 'W', 1024, 0, -1, "index above 1023" },
        { "%QW1023", 'Q', 'W', 1023, 0, AT(qw, 1023), NULL },
        { "%QW1024", 'Q', 'W', 1024, 0, -1, "index above 1023" },
        { "%MW0", 'M', 'W', 0, 0, AT(mw, 0), NULL },
        { "%MW1023", 'M', 'W', 1023, 0, AT(mw, 1023), NULL },
        { "%MW1024", 'M', 'W', 1024, 0, -1, "index above 1023" },
        { "%MD0", 'M', 'D', 0, 0, AT(md, 0), NULL },
        { "%MD1023", 'M', 'D', 1023, 0, AT(md, 1023), NULL },
        { "%MD1024", 'M', 'D', 1024, 0, -1, "index above 1023" },
        { "%ML1023", 'M', 'L', 1023, 0, AT(ml, 1023), NULL },
        { "%ML1024", 'M', 'L', 1024, 0, -1, "index above 1023" },
        { "%ID0", 'I', 'D', 0, 0, -1, "OpenPLC maps only %IX %QX %IW %QW %MW %MD %ML to Modbus" },
        { "%QD0", 'Q', 'D', 0, 0, -1, "OpenPLC maps only" },
        { "%QL0", 'Q', 'L', 0, 0, -1, "OpenPLC maps only" },
        { "%IB0", 'I', 'B', 0, 0, -1, "OpenPLC maps only" },
        { "%MB0", 'M', 'B', 0, 0, -1, "OpenPLC maps only" },
    };
    static plc_image_t image;

    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++) {
        const slot_row_t *r = &rows[i];
        plc_located_t l = { .address = r->address, .var = "V", .area = r->area, .size = r->size,
                            .index = r->index, .bit = r->bit };
        const char *why = "(not set)";
        check_row("%s", r->address);
        uint8_t *slot = plc_image_slot(&image, &l, &why);
        if (r->at < 0) {
            CHECK(slot == NULL);
            CHECK_CONTAINS(why, r->why);
        } else if (CHECK(slot != NULL)) {
            CHECK_INT(slot - (uint8_t *)&image, r->at);
            CHECK(why == NULL);
        }
    }
}

static void an_address_size_gives_its_bytes(void)
{
    CHECK_UINT(plc_located_bytes('X'), 1);
    CHECK_UINT(plc_located_bytes('B'), 1);
    CHECK_UINT(plc_located_bytes('W'), 2);
    CHECK_UINT(plc_located_bytes('D'), 4);
    CHECK_UINT(plc_located_bytes('L'), 8);
    CHECK_UINT(plc_located_bytes('Q'), 0);
}

/* A value per holding register that no two registers share. */
static uint16_t reg_value(unsigned a)
{
    return (uint16_t)(a * 7u + 1u);
}

static void holding_registers_follow_the_openplc_map(void)
{
    static plc_image_t p;

    memset(&p, 0, sizeof p);
    for (unsigned a = 0; a < MAP_HOLDING; a++)
        image_prog_set_holding(&p, a, reg_value(a));
    unsigned wrong_qw = 0, wrong_mw = 0, wrong_md = 0, wrong_ml = 0, wrong_back = 0;
    for (unsigned i = 0; i < MAP_WORDS; i++) {
        uint32_t md = (uint32_t)reg_value(MAP_HOLD_MD + 2 * i) << 16 | reg_value(MAP_HOLD_MD + 2 * i + 1);
        uint64_t ml = 0;
        for (unsigned k = 0; k < 4; k++)
            ml = ml << 16 | reg_value(MAP_HOLD_ML + 4 * i + k);
        wrong_qw += p.qw[i] != reg_value(MAP_HOLD_QW + i);
        wrong_mw += p.mw[i] != reg_value(MAP_HOLD_MW + i);
        wrong_md += p.md[i].u != md;
        wrong_ml += p.ml[i].u != ml;
    }
    for (unsigned a = 0; a < MAP_HOLDING; a++)
        wrong_back += image_prog_holding(&p, a) != reg_value(a);
    CHECK_UINT(wrong_qw, 0);                  /* registers 0..1023: %QW0..%QW1023 */
    CHECK_UINT(wrong_mw, 0);                  /* 1024..2047: %MW0..%MW1023 */
    CHECK_UINT(wrong_md, 0);                  /* 2048+2n, 2049+2n: %MDn, high word first */
    CHECK_UINT(wrong_ml, 0);                  /* 4096+4n..4099+4n: %MLn, high word first */
    CHECK_UINT(wrong_back, 0);                /* and read back the same */
    /* the boundaries, spelled out */
    CHECK_UINT(p.qw[1023], reg_value(1023));
    CHECK_UINT(p.mw[0], reg_value(1024));
    CHECK_UINT(p.mw[1023], reg_value(2047));
    CHECK_UINT(p.md[0].u >> 16, reg_value(2048));
    CHECK_UINT(p.md[1023].u & 0xffff, reg_value(4095));
    CHECK_UINT(p.ml[0].u >> 48, reg_value(4096));
    CHECK_UINT(p.ml[1023].u & 0xffff, reg_value(8191));
}

static void a_half_written_double_or_long_word_keeps_its_other_words(void)
{
    static plc_image_t p;

    p.md[40].u = 0x11112222u;
    image_prog_set_holding(&p, MAP_HOLD_MD + 81, 0x3333);            /* %MD40, low word */
    CHECK_UINT(p.md[40].u, 0x11113333u);
    image_prog_set_holding(&p, MAP_HOLD_MD + 80, 0x4444);            /* high word */
    CHECK_UINT(p.md[40].u, 0x44443333u);
    p.ml[7].u = 0x1111222233334444u;
    image_prog_set_holding(&p, MAP_HOLD_ML + 4 * 7 + 2, 0xabcd);      /* %ML7, third word */
    CHECK_UINT(p.ml[7].u, 0x11112222abcd4444u);
    CHECK_UINT(image_prog_holding(&p, MAP_HOLD_ML + 4 * 7 + 3), 0x4444);
}

/* ------------------------------------------------------------ address sets */

typedef struct set_row {
    const char *text;
    unsigned limit;
    const char *error;            /* NULL: accepted */
    unsigned count;               /* addresses in the set */
    unsigned first, last;         /* the lowest and the highest */
} set_row_t;

static void address_sets_are_read_within_their_limit(void)
{
    const set_row_t rows[] = {
        { "400-799", MAP_BITS, NULL, 400, 400, 799 },
        { "512-1023,1024-2047", MAP_HOLDING, NULL, 1536, 512, 2047 },
        { "5, 10-11", MAP_BITS, NULL, 3, 5, 11 },
        { "799", MAP_BITS, NULL, 1, 799, 799 },
        { "0-8191", MAP_HOLDING, NULL, 8192, 0, 8191 },
        { "", MAP_BITS, NULL, 0, 0, 0 },
        { " , ", MAP_BITS, NULL, 0, 0, 0 },
        { "800", MAP_BITS, "range 800-800 in '800' is outside 0-799", 0, 0, 0 },
        { "700-900", MAP_BITS, "range 700-900 in '700-900' is outside 0-799", 0, 0, 0 },
        { "8192", MAP_HOLDING, "is outside 0-8191", 0, 0, 0 },
        { "5-3", MAP_BITS, "range 5-3 in '5-3' is outside 0-799", 0, 0, 0 },
        { "12x", MAP_HOLDING, "cannot read '12x': expected addresses like 400-799,1024", 0, 0, 0 },
        { "-5", MAP_HOLDING, "cannot read '-5'", 0, 0, 0 },
        { "5-", MAP_HOLDING, "cannot read '5-'", 0, 0, 0 },
        { "1;2", MAP_HOLDING, "cannot read '1;2'", 0, 0, 0 },
        { "none", MAP_HOLDING, "cannot read 'none'", 0, 0, 0 },
    };

    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++) {
        const set_row_t *r = &rows[i];
        addr_set_t s;
        char err[160] = "";
        memset(&s, 0, sizeof s);
        check_row("'%s' below %u", r->text, r->limit);
        int rc = addr_set_parse(&s, r->text, r->limit, err, sizeof err);
        if (r->error) {
            CHECK_INT(rc, -1);
            CHECK_CONTAINS(err, r->error);
            continue;
        }
        if (!CHECK_INT(rc, 0)) {
            CHECK_STR(err, "");
            continue;
        }
        unsigned count = 0, first = 0, last = 0;
        for (unsigned a = 0; a < MAP_HOLDING; a++)
            if (addr_set_has(&s, a)) {
                if (count++ == 0)
                    first = a;
                last = a;
            }
        CHECK_UINT(count, r->count);
        CHECK_UINT(first, r->first);
        CHECK_UINT(last, r->last);
    }
}

/* ------------------------------------------------------------ scan boundaries */

static void host_writes_reach_the_program_image_once_between_scans(void)
{
    static const plc_program_t none = { .abi_version = PLC_ABI_VERSION };
    runtime_t *rt = new_runtime(&none);
    REQUIRE(rt);
    bus_image_t *b = &rt->bimg;

    image_host_write_coil(b, 799, true);                              /* %QX99.7, the last coil */
    image_host_write_register(b, 8191, 0xbeef);                      /* %ML1023, its low word */
    image_host_write_register(b, 2048, 0x1234);                      /* %MD0, its high word */
    image_host_write_register(b, 1023, 7);                           /* %QW1023 */
    CHECK(b->coils[799] == 1 && b->holding[8191] == 0xbeef);         /* a client reads back what it wrote */
    CHECK(rt->pimg.qx[799] == 0 && rt->pimg.ml[1023].u == 0);        /* the program sees nothing mid-scan */
    CHECK(b->any_dirty);
    image_take_host_writes(rt);                                      /* the next scan's input latch */
    CHECK_UINT(rt->pimg.qx[799], 1);
    CHECK_UINT(rt->pimg.ml[1023].u, 0xbeef);
    CHECK_UINT(rt->pimg.md[0].u, 0x12340000u);
    CHECK_UINT(rt->pimg.qw[1023], 7);
    CHECK(!b->any_dirty && !addr_set_has(&b->dirty_coils, 799) && !addr_set_has(&b->dirty_holding, 8191));
    rt->pimg.qx[799] = 0;                                            /* the program changes it */
    rt->pimg.qw[1023] = 8;
    image_take_host_writes(rt);                                      /* nothing new: applied once only */
    CHECK_UINT(rt->pimg.qx[799], 0);
    CHECK_UINT(rt->pimg.qw[1023], 8);
    free_runtime(rt);
}

/* A program with one located variable of each mapped kind, and two the map does not have. */
static plc_bool_t lamp, button;
static int16_t status_word, setpoint, input_word;
static int32_t total;
static int64_t big;
static uint8_t private_byte;
static int16_t high_word;
static void *lamp_p = &lamp, *button_p = &button, *status_p = &status_word, *setpoint_p = &setpoint,
            *input_p = &input_word, *total_p = &total, *big_p = &big, *byte_p = &private_byte, *high_p = &high_word;

static const plc_located_t mapped[] = {
    { "%QX0.1", "MAIN.LAMP", 'Q', 'X', PLC_T_BOOL, 0, 1, &lamp_p, 0 },
    { "%IX0.0", "MAIN.BUTTON", 'I', 'X', PLC_T_BOOL, 0, 0, &button_p, 0 },
    { "%QW3", "MAIN.STATUS", 'Q', 'W', PLC_T_INT, 3, 0, &status_p, 0 },
    { "%MW5", "MAIN.SETPOINT", 'M', 'W', PLC_T_INT, 5, 0, &setpoint_p, 0 },
    { "%IW7", "MAIN.INPUT", 'I', 'W', PLC_T_INT, 7, 0, &input_p, 0 },
    { "%MD1", "MAIN.TOTAL", 'M', 'D', PLC_T_DINT, 1, 0, &total_p, 0 },
    { "%ML2", "MAIN.BIG", 'M', 'L', PLC_T_LINT, 2, 0, &big_p, 0 },
    { "%IB0", "MAIN.PRIVATE", 'I', 'B', PLC_T_BYTE, 0, 0, &byte_p, 0 },
    { "%MW2000", "MAIN.HIGH", 'M', 'W', PLC_T_INT, 2000, 0, &high_p, 0 },
};

static const plc_program_t mapped_prog = {
    .abi_version = PLC_ABI_VERSION, .located = mapped, .n_located = sizeof mapped / sizeof mapped[0],
};

static void addresses_off_the_map_stay_inside_the_program_and_are_logged(void)
{
    runtime_t *rt = new_runtime(&mapped_prog);
    char err[200] = "";
    REQUIRE(rt);

    logcap_clear();
    CHECK_INT(image_bind_program(rt, err, sizeof err), 0);
    CHECK_UINT(rt->core.n_bindings, 7);
    CHECK_UINT(rt->core.n_inputs, 2);
    CHECK_INT(logcap_count("warning: MAIN.PRIVATE at %IB0 is not on the Modbus map (OpenPLC maps only"), 1);
    CHECK_INT(logcap_count("warning: MAIN.HIGH at %MW2000 is not on the Modbus map (index above 1023); it stays "
                           "inside the program"), 1);
    free_runtime(rt);
}

static void publication_copies_the_programs_registers_high_word_first(void)
{
    runtime_t *rt = new_runtime(&mapped_prog);
    char err[200] = "";
    REQUIRE(rt);
    bus_image_t *b = &rt->bimg;

    status_word = 11;                                                /* initial values go into the image */
    REQUIRE_INT(image_bind_program(rt, err, sizeof err), 0);
    CHECK_UINT(rt->pimg.qw[3], 11);
    image_publish_all(rt);
    CHECK_UINT(b->holding[3], 11);

    b->holding[MAP_HOLD_MW + 6] = 77;       /* %MW6: no variable; the Modbus image holds a host's value */
    lamp = 1;
    status_word = -2;
    setpoint = 300;
    total = 0x12345678;
    big = 0x0102030405060708;
    plc_scan_publish_outputs(&rt->core);                             /* the program's outputs into the image */
    image_publish(rt);
    CHECK_UINT(b->coils[1], 1);
    CHECK_UINT(b->holding[3], 0xfffe);
    CHECK_UINT(b->holding[MAP_HOLD_MW + 5], 300);
    CHECK_UINT(b->holding[MAP_HOLD_MD + 2], 0x1234);
    CHECK_UINT(b->holding[MAP_HOLD_MD + 3], 0x5678);
    CHECK_UINT(b->holding[MAP_HOLD_ML + 8], 0x0102);
    CHECK_UINT(b->holding[MAP_HOLD_ML + 11], 0x0708);
    CHECK_UINT(b->holding[MAP_HOLD_MW + 6], 77);                     /* not the program's: left alone */

    /* a host write during the scan is what a client reads back, until the next latch hands it over */
    image_host_write_register(b, MAP_HOLD_MW + 5, 999);
    image_publish(rt);
    CHECK_UINT(b->holding[MAP_HOLD_MW + 5], 999);
    CHECK_UINT(rt->pimg.mw[5], 300);
    image_take_host_writes(rt);
    CHECK_UINT(rt->pimg.mw[5], 999);

    image_publish_all(rt);                                           /* start-up: every register from the program */
    CHECK_UINT(b->holding[MAP_HOLD_MW + 6], 0);
    free_runtime(rt);
}

static void a_located_type_that_does_not_fit_its_address_is_refused(void)
{
    static int32_t dint;
    static int16_t word;
    static void *dint_p = &dint, *word_p = &word, *none_p = NULL;
    const struct { plc_located_t l; const char *error; } rows[] = {
        { { "%MW3", "MAIN.PRESET", 'M', 'W', PLC_T_DINT, 3, 0, &dint_p, 0 },
          "located variable MAIN.PRESET at %MW3: its type takes 4 bytes, the address 2" },
        { { "%QX0.0", "MAIN.FLAG", 'Q', 'X', PLC_T_INT, 0, 0, &word_p, 0 },
          "located variable MAIN.FLAG at %QX0.0: its type takes 2 bytes, the address 1" },
        { { "%QB0", "MAIN.B", 'Q', 'B', PLC_T_BYTE, 0, 0, &none_p, 0 },
          "located variable MAIN.B at %QB0: malformed entry (area Q, size B)" },
        { { "%ZW0", "MAIN.Z", 'Z', 'W', PLC_T_INT, 0, 0, &word_p, 0 }, "malformed entry (area Z, size W)" },
        { { "%MQ0", "MAIN.Q", 'M', 'Q', PLC_T_INT, 0, 0, &word_p, 0 }, "malformed entry (area M, size Q)" },
    };

    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++) {
        plc_program_t one = { .abi_version = PLC_ABI_VERSION, .located = &rows[i].l, .n_located = 1 };
        runtime_t *rt = new_runtime(&one);
        char err[200] = "";
        REQUIRE(rt);
        check_row("%s", rows[i].l.address);
        CHECK_INT(image_bind_program(rt, err, sizeof err), -1);
        CHECK_CONTAINS(err, rows[i].error);
        CHECK(rt->core.bindings == NULL);                            /* nothing half-bound */
        free_runtime(rt);
    }
}

static void safe_outputs_clear_every_coil_and_keep_the_words(void)
{
    static plc_image_t p;

    memset(p.qx, 1, sizeof p.qx);
    p.qw[0] = 5;                                                     /* the tool in the spindle */
    p.ix[3] = 1;
    image_make_outputs_safe(&p);
    unsigned on = 0;
    for (unsigned i = 0; i < MAP_BITS; i++)
        on += p.qx[i];
    CHECK_UINT(on, 0);
    CHECK_UINT(p.qw[0], 5);
    CHECK_UINT(p.ix[3], 1);
}

static void the_diagnostic_block_holds_wide_values_high_word_first(void)
{
    static bus_image_t b;

    diag_put16(&b, DIAG_VERSION, 1);
    diag_put32(&b, DIAG_BASE_TICK_US, 0x00012345u);
    diag_put64(&b, DIAG_SCAN_COUNT, 0x1122334455667788u);
    CHECK_UINT(b.input_regs[DIAG_BASE], 1);
    CHECK_UINT(b.input_regs[DIAG_BASE + DIAG_BASE_TICK_US], 0x0001);
    CHECK_UINT(b.input_regs[DIAG_BASE + DIAG_BASE_TICK_US + 1], 0x2345);
    CHECK_UINT(b.input_regs[DIAG_BASE + DIAG_SCAN_COUNT], 0x1122);
    CHECK_UINT(b.input_regs[DIAG_BASE + DIAG_SCAN_COUNT + 3], 0x7788);
    CHECK_UINT(diag_get32(&b, DIAG_BASE_TICK_US), 0x00012345u);
    CHECK_UINT(diag_get64(&b, DIAG_SCAN_COUNT), 0x1122334455667788u);
    CHECK_UINT(b.input_regs[DIAG_BASE - 1], 0);                      /* %IW1023 untouched */
}

static const check_case_t cases[] = {
    CASE(located_addresses_map_to_their_image_slots),
    CASE(an_address_size_gives_its_bytes),
    CASE(holding_registers_follow_the_openplc_map),
    CASE(a_half_written_double_or_long_word_keeps_its_other_words),
    CASE(address_sets_are_read_within_their_limit),
    CASE(host_writes_reach_the_program_image_once_between_scans),
    CASE(addresses_off_the_map_stay_inside_the_program_and_are_logged),
    CASE(publication_copies_the_programs_registers_high_word_first),
    CASE(a_located_type_that_does_not_fit_its_address_is_refused),
    CASE(safe_outputs_clear_every_coil_and_keep_the_words),
    CASE(the_diagnostic_block_holds_wide_values_high_word_first),
};

CHECK_MAIN(cases)
