/*
 * test_varpath.c - varpath.c alone: a path resolved to storage through a
 * program's variable and located tables, values parsed and shown in JSON.
 *
 * The program below is a table written by hand the way the compiler writes
 * it; where a path reaches inside an aggregate, the address varpath computes
 * from the type name is compared with the address the C compiler gives the
 * same member (offsetof through a real struct), so a layout rule that differs
 * from C's shows as a wrong address, never a silently wrong value.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "check.h"
#include "monitor.h"

/* ------------------------------------------------------------ the program */

typedef struct { int16_t a; plc_bool_t b; } st_pair_t;                /* ST_PAIR{A:INT;B:BOOL} */
typedef struct { plc_bool_t f; double d; int8_t s; } st_mix_t;        /* 1, pad 7, 8, 1, pad 7: 24 bytes */
typedef struct { int16_t tool; st_mix_t mix[2]; } st_nest_t;         /* TOOL at 0, MIX at 8: 56 bytes */
typedef struct {
    // cppcheck-suppress unusedStructMember ; the layout of ST_TEXT: B places S at offset 1
    plc_bool_t b;
    plc_string_t s; int16_t i; int32_t e;
} st_text_t;                                                          /* STRING aligned 1 */

#define PAIR "ST_PAIR{A:INT;B:BOOL}"
#define MIX "ST_MIX{F:BOOL;D:LREAL;S:SINT}"
#define MODE "E_MODE(AUTO,MANUAL)"

static int16_t gain;
static st_pair_t pairs[3];
static int32_t grid[2][3];                                            /* ARRAY[0..1,1..3] OF DINT */
static st_nest_t nest;
static st_text_t text;
static int32_t mode;
static plc_string_t label;
static int32_t counter_count, spare_count;
static int16_t limit;
static uint8_t blob[6];                                               /* its type name says 4 bytes: refused */
static int16_t echo;
static plc_bool_t button;
static uint8_t raw_byte;
static void *echo_ptr = &echo, *button_ptr = &button, *raw_ptr = &raw_byte;

#define P "CONFIG0.RES0.INST0."

static plc_var_t vars[] = {
    { P "GAIN", PLC_T_INT, 0, 0, &gain, sizeof gain, "INT" },
    { P "PAIRS", PLC_T_OTHER, 0, 0, pairs, sizeof pairs, "ARRAY[1..3] OF " PAIR },
    { P "GRID", PLC_T_OTHER, 0, 0, grid, sizeof grid, "ARRAY[0..1,1..3] OF DINT" },
    { P "NEST", PLC_T_OTHER, 0, 0, &nest, sizeof nest, "ST_NEST{TOOL:INT;MIX:ARRAY[1..2] OF " MIX "}" },
    { P "TEXT", PLC_T_OTHER, 0, 0, &text, sizeof text, "ST_TEXT{B:BOOL;S:STRING;I:INT;E:" MODE "}" },
    { P "MODE", PLC_T_ENUM, 0, 0, &mode, sizeof mode, MODE },
    { P "LABEL", PLC_T_STRING, 0, 0, &label, sizeof label, "STRING" },
    { P "COUNTER.COUNT", PLC_T_DINT, 0, 0, &counter_count, 4, "DINT" },
    { P "SPARE.COUNT", PLC_T_DINT, 0, 0, &spare_count, 4, "DINT" },
    { P "LIMIT", PLC_T_INT, 0, 1, &limit, sizeof limit, "INT" },
    { P "BLOB", PLC_T_OTHER, 0, 0, blob, sizeof blob, "ARRAY[1..2] OF INT" },
    { P "ECHO", PLC_T_INT, 0, 0, &echo, sizeof echo, "INT" },
};

static const plc_located_t located[] = {
    { "%IX0.0", P "BUTTON", 'I', 'X', PLC_T_BOOL, 0, 0, &button_ptr, 0 },
    { "%QW1", P "ECHO", 'Q', 'W', PLC_T_INT, 1, 0, &echo_ptr, 0 },
    { "%MB0", P "RAW", 'M', 'B', PLC_T_OTHER, 0, 0, &raw_ptr, 0 },
};

static plc_program_t prog = {
    .abi_version = PLC_ABI_VERSION, .config_name = "CONFIG0", .located = located,
    .n_located = sizeof located / sizeof located[0], .vars = vars, .n_vars = sizeof vars / sizeof vars[0],
};

/* ------------------------------------------------------------ paths */

typedef struct good_path {
    const char *path;
    const char *canonical;
    void *addr;
    uint32_t size;
    uint16_t type;
} good_path_t;

static void paths_resolve_to_the_address_the_c_compiler_gives(void)
{
    const good_path_t rows[] = {
        { P "GAIN", P "GAIN", &gain, 2, PLC_T_INT },
        { "inst0.gain", P "GAIN", &gain, 2, PLC_T_INT },                    /* a unique tail, any case */
        { "RES0.INST0.GAIN", P "GAIN", &gain, 2, PLC_T_INT },
        { "INST0.PAIRS", P "PAIRS", pairs, sizeof pairs, PLC_T_OTHER },
        { "INST0.PAIRS[1]", P "PAIRS[1]", &pairs[0], sizeof pairs[0], PLC_T_OTHER },
        { "INST0.PAIRS[2].A", P "PAIRS[2].A", &pairs[1].a, 2, PLC_T_INT },
        { "inst0.pairs[3].b", P "PAIRS[3].B", &pairs[2].b, 1, PLC_T_BOOL },
        { "INST0.GRID[0,1]", P "GRID[0,1]", &grid[0][0], 4, PLC_T_DINT },
        { "INST0.GRID[0,3]", P "GRID[0,3]", &grid[0][2], 4, PLC_T_DINT },
        { "INST0.GRID[1,1]", P "GRID[1,1]", &grid[1][0], 4, PLC_T_DINT },
        { "INST0.GRID[1,3]", P "GRID[1,3]", &grid[1][2], 4, PLC_T_DINT },
        { "INST0.NEST.TOOL", P "NEST.TOOL", &nest.tool, 2, PLC_T_INT },
        { "INST0.NEST.MIX", P "NEST.MIX", nest.mix, sizeof nest.mix, PLC_T_OTHER },
        { "INST0.NEST.MIX[1].S", P "NEST.MIX[1].S", &nest.mix[0].s, 1, PLC_T_SINT },
        { "INST0.NEST.MIX[2].F", P "NEST.MIX[2].F", &nest.mix[1].f, 1, PLC_T_BOOL },
        { "INST0.NEST.MIX[2].D", P "NEST.MIX[2].D", &nest.mix[1].d, 8, PLC_T_LREAL },
        { "INST0.TEXT.S", P "TEXT.S", &text.s, sizeof text.s, PLC_T_STRING },
        { "INST0.TEXT.I", P "TEXT.I", &text.i, 2, PLC_T_INT },
        { "INST0.TEXT.E", P "TEXT.E", &text.e, 4, PLC_T_ENUM },
        { "INST0.MODE", P "MODE", &mode, 4, PLC_T_ENUM },
        { "INST0.LABEL", P "LABEL", &label, sizeof label, PLC_T_STRING },
        { "COUNTER.COUNT", P "COUNTER.COUNT", &counter_count, 4, PLC_T_DINT },
        { "%IX0.0", P "BUTTON", &button, 1, PLC_T_BOOL },
        { "%qw1", P "ECHO", &echo, 2, PLC_T_INT },
        { "INST0.BUTTON", P "BUTTON", &button, 1, PLC_T_BOOL },
    };

    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++) {
        var_ref_t ref;
        char err[256] = "";
        check_row("%s", rows[i].path);
        if (!CHECK_INT(varpath_resolve(&prog, rows[i].path, &ref, err, sizeof err), 0)) {
            CHECK_STR(err, "");
            continue;
        }
        CHECK_STR(ref.path, rows[i].canonical);
        CHECK(ref.addr == rows[i].addr);
        CHECK_UINT(ref.size, rows[i].size);
        CHECK_UINT(ref.type, rows[i].type);
    }
}

static void located_and_constant_variables_are_marked(void)
{
    var_ref_t ref;
    char err[256];

    REQUIRE_INT(varpath_resolve(&prog, P "ECHO", &ref, err, sizeof err), 0);
    CHECK(ref.located);                       /* a located variable's table entry: the located view wins */
    CHECK_INT(ref.area, 'Q');
    CHECK_STR(ref.type_name, "INT");
    REQUIRE_INT(varpath_resolve(&prog, "%IX0.0", &ref, err, sizeof err), 0);
    CHECK(ref.located && ref.area == 'I' && !ref.constant);
    REQUIRE_INT(varpath_resolve(&prog, "INST0.LIMIT", &ref, err, sizeof err), 0);
    CHECK(ref.constant && !ref.located);
    REQUIRE_INT(varpath_resolve(&prog, "INST0.GAIN", &ref, err, sizeof err), 0);
    CHECK(!ref.constant && !ref.located);
}

typedef struct bad_path {
    const char *path;
    const char *error;
} bad_path_t;

static void invalid_paths_are_refused_with_a_sentence(void)
{
    char long_path[VP_PATH_MAX + 1];
    memset(long_path, 'A', VP_PATH_MAX);
    long_path[VP_PATH_MAX] = 0;
    const bad_path_t rows[] = {
        { "", "a variable path has 1 to 255 characters" },
        { long_path, "a variable path has 1 to 255 characters" },
        { "INST0 GAIN", "character ' ' cannot appear in a variable path" },
        { "INST0.GAIN;", "character ';' cannot appear in a variable path" },
        { "INST0.NOSUCH", "unknown variable 'INST0.NOSUCH'" },
        { "INST0.PAIRS[4].A", "index 4 outside 1..3 of '" P "PAIRS'" },
        { "INST0.PAIRS[0]", "index 0 outside 1..3 of '" P "PAIRS'" },
        { "INST0.PAIRS[-1]", "index -1 outside 1..3" },
        { "INST0.PAIRS[99999999999999999999]", "expected 1 index(es) like [1]" },
        { "INST0.PAIRS[X]", "expected 1 index(es) like [1]" },
        { "INST0.PAIRS[2", "expected ']'" },
        { "INST0.PAIRS[1]]", "cannot read ']' after '" P "PAIRS[1]'" },
        { "INST0.PAIRS[2].C", "'" P "PAIRS[2]' has no field 'C'" },
        { "INST0.PAIRS[2].", "has no field" },
        { "INST0.PAIRS.A", "'" P "PAIRS' has no fields: '.A' cannot be selected" },
        { "INST0.GRID[2,1]", "index 2 outside 0..1 of '" P "GRID'" },
        { "INST0.GRID[1,4]", "index 4 outside 1..3 of '" P "GRID'" },
        { "INST0.GRID[1]", "has 2 dimensions: give 2 indexes" },
        { "INST0.GRID[1,2,3]", "expected ']'" },
        { "INST0.GAIN.X", "'" P "GAIN' has no fields" },
        { "INST0.GAIN[1]", "'" P "GAIN' is not an array" },
        { "INST0.NEST.MIX[3].D", "index 3 outside 1..2 of '" P "NEST.MIX'" },
        { "INST0.BLOB[1]", "the layout of '" P "BLOB' (ARRAY[1..2] OF INT) is not known to the runtime: its parts "
                           "cannot be addressed" },
        { "INST0.BLOB", "the layout of '" P "BLOB' (ARRAY[1..2] OF INT) is not known to the runtime" },
        { "%IX99.9", "no located variable at %IX99.9" },
        { "%MB0", "located variable " P "RAW (%MB0) has a type the monitor cannot show" },
        { "COUNT", "'COUNT' names more than one variable: give the full path" },
    };

    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++) {
        var_ref_t ref;
        char err[256] = "";
        check_row("%.40s", rows[i].path);
        CHECK_INT(varpath_resolve(&prog, rows[i].path, &ref, err, sizeof err), -1);
        CHECK_CONTAINS(err, rows[i].error);
    }
}

/* A type name whose layout cannot be read leaves the aggregate unaddressable (never a guessed offset). */
static void unreadable_type_names_refuse_the_parts_below_them(void)
{
    static uint8_t storage[64];
    const char *const names[] = {
        "ARRAY[1..0] OF INT",                                  /* upper bound below the lower */
        "ARRAY[1..2,1..2,1..2,1..2,1..2] OF BOOL",             /* five dimensions */
        "ARRAY[1..2] INT",
        "ARRAY[1..2] OF FOO",                                  /* unknown elementary type */
        "ST_X{A:INT",                                          /* unbalanced */
        "ST_X{A:INT;B}",                                       /* a member without a type */
        "ST_X{:INT}",
        "E_X(A,B",
        "INT8",
    };
    plc_var_t v = { P "ODD", PLC_T_OTHER, 0, 0, storage, 4, NULL };
    plc_program_t one = { .abi_version = PLC_ABI_VERSION, .vars = &v, .n_vars = 1 };

    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        var_ref_t ref;
        char err[256] = "";
        check_row("%s", names[i]);
        v.type_name = names[i];
        CHECK_INT(varpath_resolve(&one, P "ODD[1]", &ref, err, sizeof err), -1);
        CHECK_CONTAINS(err, "is not known to the runtime: its parts cannot be addressed");
        CHECK_INT(varpath_resolve(&one, P "ODD", &ref, err, sizeof err), -1);
    }
    /* the same member list with the size C gives it is addressable */
    check_row("ST_X{A:BOOL;B:LINT}");
    // cppcheck-suppress redundantAssignment ; varpath_resolve read the last one through one.vars
    v.type_name = "ST_X{A:BOOL;B:LINT}";
    v.size = 16;
    var_ref_t ref;
    char err[256] = "";
    CHECK_INT(varpath_resolve(&one, P "ODD.B", &ref, err, sizeof err), 0);
    CHECK(ref.addr == storage + 8);
    // cppcheck-suppress redundantAssignment ; varpath_resolve read 16 through one.vars
    v.size = 12;                                               /* what a packed layout would give: refused */
    CHECK_INT(varpath_resolve(&one, P "ODD.B", &ref, err, sizeof err), -1);
}

/* ------------------------------------------------------------ values */

typedef struct value_row {
    uint16_t type;
    const char *type_name;
    const char *text;
    const char *error;            /* NULL: accepted, with these bytes */
    uint8_t bytes[8];
    uint32_t n;
} value_row_t;

#define OK(t, tn, text, ...) { t, tn, text, NULL, { __VA_ARGS__ }, sizeof((uint8_t[]){ __VA_ARGS__ }) }
#define BAD(t, tn, text, why) { t, tn, text, why, { 0 }, 0 }

static void values_are_parsed_in_the_range_of_their_type(void)
{
    const value_row_t rows[] = {
        OK(PLC_T_BOOL, "BOOL", "TRUE", 1), OK(PLC_T_BOOL, "BOOL", "true", 1), OK(PLC_T_BOOL, "BOOL", "1", 1),
        OK(PLC_T_BOOL, "BOOL", "False", 0), OK(PLC_T_BOOL, "BOOL", "0", 0),
        BAD(PLC_T_BOOL, "BOOL", "maybe", "'maybe' is not a valid BOOL value"),
        BAD(PLC_T_BOOL, "BOOL", "2", "'2' is not a valid BOOL value"),
        OK(PLC_T_SINT, "SINT", "-128", 0x80), BAD(PLC_T_SINT, "SINT", "128", "not a valid SINT value (a number in"),
        OK(PLC_T_INT, "INT", "32767", 0xff, 0x7f), OK(PLC_T_INT, "INT", "-32768", 0x00, 0x80),
        OK(PLC_T_INT, "INT", "16#7FFF", 0xff, 0x7f), OK(PLC_T_INT, "INT", "-1", 0xff, 0xff),
        BAD(PLC_T_INT, "INT", "32768", "'32768' is not a valid INT value"),
        BAD(PLC_T_INT, "INT", "40000", "'40000' is not a valid INT value"),
        BAD(PLC_T_INT, "INT", "abc", "'abc' is not a valid INT value"),
        BAD(PLC_T_INT, "INT", "", "is not a valid INT value"), BAD(PLC_T_INT, "INT", "12x", "not a valid INT"),
        OK(PLC_T_DINT, "DINT", "2147483647", 0xff, 0xff, 0xff, 0x7f),
        BAD(PLC_T_DINT, "DINT", "-2147483649", "not a valid DINT value"),
        OK(PLC_T_LINT, "LINT", "-9223372036854775808", 0, 0, 0, 0, 0, 0, 0, 0x80),
        BAD(PLC_T_LINT, "LINT", "9223372036854775808", "not a valid LINT value"),
        OK(PLC_T_USINT, "USINT", "255", 0xff), BAD(PLC_T_USINT, "USINT", "256", "not a valid USINT value"),
        BAD(PLC_T_USINT, "USINT", "-1", "not a valid USINT value"),
        OK(PLC_T_BYTE, "BYTE", "2#1010", 10), OK(PLC_T_UINT, "UINT", "8#17", 15, 0),
        BAD(PLC_T_UINT, "UINT", "65536", "not a valid UINT value"), OK(PLC_T_WORD, "WORD", "16#FFFF", 0xff, 0xff),
        OK(PLC_T_UDINT, "UDINT", "4294967295", 0xff, 0xff, 0xff, 0xff),
        BAD(PLC_T_DWORD, "DWORD", "4294967296", "not a valid DWORD value"),
        OK(PLC_T_ULINT, "ULINT", "18446744073709551615", 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff),
        BAD(PLC_T_LWORD, "LWORD", "18446744073709551616", "not a valid LWORD value"),
        OK(PLC_T_REAL, "REAL", "1.5", 0x00, 0x00, 0xc0, 0x3f),
        BAD(PLC_T_REAL, "REAL", "1e39", "'1e39' is not a valid REAL value (a number in its range)"),
        BAD(PLC_T_REAL, "REAL", "nan", "'nan' is not a valid REAL value"),
        OK(PLC_T_LREAL, "LREAL", "-2", 0, 0, 0, 0, 0, 0, 0, 0xc0),
        BAD(PLC_T_LREAL, "LREAL", "1e309", "not a valid LREAL value"),
        BAD(PLC_T_LREAL, "LREAL", "1.0.0", "not a valid LREAL value"),
        /* TIME in nanoseconds, little-endian: 1h2m3s4ms = 3 723 004 000 000 */
        OK(PLC_T_TIME, "TIME", "T#1h2m3s4ms", 0x00, 0xb7, 0x54, 0xd4, 0x62, 0x03, 0, 0),
        OK(PLC_T_TIME, "TIME", "time#1.5s", 0x00, 0x2f, 0x68, 0x59, 0, 0, 0, 0),
        OK(PLC_T_TIME, "TIME", "T#-5s", 0x00, 0x0e, 0xfa, 0xd5, 0xfe, 0xff, 0xff, 0xff),
        OK(PLC_T_TIME, "TIME", "250", 0x80, 0xb2, 0xe6, 0x0e, 0, 0, 0, 0),           /* a bare number: ms */
        OK(PLC_T_TIME, "TIME", "T#1d_2h", 0x00, 0x40, 0xc0, 0xf2, 0x20, 0x55, 0, 0),
        OK(PLC_T_TIME, "TIME", "T#100us", 0xa0, 0x86, 0x01, 0, 0, 0, 0, 0),
        BAD(PLC_T_TIME, "TIME", "T#", "'T#' is not a valid TIME value"),
        BAD(PLC_T_TIME, "TIME", "T#5x", "'T#5x' is not a valid TIME value"),
        BAD(PLC_T_TIME, "TIME", "T#200000d", "not a valid TIME value"),            /* beyond 2^63 ns */
        OK(PLC_T_ENUM, MODE, "manual", 1, 0, 0, 0), OK(PLC_T_ENUM, MODE, "AUTO", 0, 0, 0, 0),
        OK(PLC_T_ENUM, MODE, "1", 1, 0, 0, 0),
        BAD(PLC_T_ENUM, MODE, "2", "'2' is not a value of " MODE),
        BAD(PLC_T_ENUM, MODE, "AUTOMATIC", "'AUTOMATIC' is not a value of " MODE),
        BAD(PLC_T_OTHER, PAIR, "1", "only elementary values can be written (a field or an element of it can)"),
        BAD(PLC_T_DATE, "DATE", "1", "only elementary values can be written"),
    };

    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++) {
        const value_row_t *r = &rows[i];
        var_ref_t ref = { .type = r->type, .type_name = r->type_name, .type_len = strlen(r->type_name) };
        uint8_t buf[VP_VALUE_MAX];
        char err[256] = "";
        snprintf(ref.path, sizeof ref.path, "%s", "X");
        check_row("%s \"%s\"", r->type_name, r->text);
        int rc = varpath_parse_value(&ref, r->text, buf, err, sizeof err);
        if (r->error) {
            CHECK_INT(rc, -1);
            CHECK_CONTAINS(err, r->error);
        } else if (CHECK_INT(rc, 0)) {
            CHECK_MEM(buf, r->bytes, r->n);
        } else {
            CHECK_STR(err, "");
        }
    }
}

static void strings_up_to_126_characters_are_accepted(void)
{
    var_ref_t ref = { .type = PLC_T_STRING, .type_name = "STRING", .type_len = 6 };
    uint8_t buf[VP_VALUE_MAX];
    char err[256] = "", line[PLC_STRING_MAX + 2];

    REQUIRE_INT(varpath_parse_value(&ref, "tool 7 loaded", buf, err, sizeof err), 0);
    const plc_string_t *s = (const plc_string_t *)buf;
    CHECK_UINT(s->len, 13);
    CHECK_STR(s->body, "tool 7 loaded");
    memset(line, 'x', PLC_STRING_MAX);
    line[PLC_STRING_MAX] = 0;
    CHECK_INT(varpath_parse_value(&ref, line, buf, err, sizeof err), 0);
    CHECK_UINT(s->len, PLC_STRING_MAX);
    line[PLC_STRING_MAX] = 'x';
    line[PLC_STRING_MAX + 1] = 0;
    CHECK_INT(varpath_parse_value(&ref, line, buf, err, sizeof err), -1);
    CHECK_CONTAINS(err, "a STRING holds at most 126 characters");
}

/* ------------------------------------------------------------ JSON */

static const char *json_of(const char *path, char *out, size_t n)
{
    var_ref_t ref;
    char err[256];

    if (varpath_resolve(&prog, path, &ref, err, sizeof err) != 0)
        return err[0] ? "(resolve failed)" : "";
    if (varpath_format_json(&ref, ref.addr, out, n) < 0)
        return "(did not fit)";
    return out;
}

static void aggregates_become_json_arrays_and_objects(void)
{
    char out[1024];

    memset(pairs, 0, sizeof pairs);
    pairs[1] = (st_pair_t){ 7, 1 };
    pairs[2].a = -1;
    CHECK_STR(json_of("INST0.PAIRS", out, sizeof out), "[{\"A\":0,\"B\":false},{\"A\":7,\"B\":true},"
                                                        "{\"A\":-1,\"B\":false}]");
    CHECK_STR(json_of("INST0.PAIRS[2]", out, sizeof out), "{\"A\":7,\"B\":true}");
    for (int i = 0; i < 6; i++)
        grid[i / 3][i % 3] = i + 1;
    CHECK_STR(json_of("INST0.GRID", out, sizeof out), "[1,2,3,4,5,6]");      /* row after row, flattened */
    memset(&nest, 0, sizeof nest);
    nest.tool = 3;
    nest.mix[1] = (st_mix_t){ 1, 0.25, -2 };
    CHECK_STR(json_of("INST0.NEST", out, sizeof out), "{\"TOOL\":3,\"MIX\":[{\"F\":false,\"D\":0,\"S\":0},"
                                                       "{\"F\":true,\"D\":0.25,\"S\":-2}]}");
    memset(&text, 0, sizeof text);
    text.e = 1;
    CHECK_STR(json_of("INST0.TEXT.E", out, sizeof out), "\"MANUAL\"");
}

static void elementary_values_in_json(void)
{
    char out[256];

    mode = 1;
    CHECK_STR(json_of("INST0.MODE", out, sizeof out), "\"MANUAL\"");
    mode = 5;                                                /* no name: the number */
    CHECK_STR(json_of("INST0.MODE", out, sizeof out), "5");
    label = (plc_string_t){ .len = 7 };
    memcpy(label.body, "a\"b\\c\nd", 7);
    CHECK_STR(json_of("INST0.LABEL", out, sizeof out), "\"a\\\"b\\\\c\\u000ad\"");
    nest.mix[0].d = NAN;
    CHECK_STR(json_of("INST0.NEST.MIX[1].D", out, sizeof out), "null");
    gain = -32768;
    CHECK_STR(json_of("INST0.GAIN", out, sizeof out), "-32768");

    var_ref_t t = { .type = PLC_T_TIME, .type_name = "TIME", .type_len = 4, .size = 8 };
    int64_t ns = 1500000000;
    CHECK_INT(varpath_format_json(&t, (const uint8_t *)&ns, out, sizeof out), 10);
    CHECK_STR(out, "\"T#1500ms\"");
}

static void json_that_does_not_fit_is_refused_whole(void)
{
    char out[64];
    var_ref_t ref;
    char err[256];
    const char *full = "[{\"A\":0,\"B\":false},{\"A\":7,\"B\":true},{\"A\":-1,\"B\":false}]";
    size_t len = strlen(full);

    memset(pairs, 0, sizeof pairs);
    pairs[1] = (st_pair_t){ 7, 1 };
    pairs[2].a = -1;
    REQUIRE_INT(varpath_resolve(&prog, "INST0.PAIRS", &ref, err, sizeof err), 0);
    CHECK_INT(varpath_format_json(&ref, ref.addr, out, len + 1), (int)len);
    CHECK_STR(out, full);
    CHECK_INT(varpath_format_json(&ref, ref.addr, out, len), -1);             /* no room for the NUL */
    CHECK_INT(varpath_format_json(&ref, ref.addr, out, 10), -1);
    CHECK_INT(varpath_format_json(&ref, ref.addr, out, 0), -1);
}

static const check_case_t cases[] = {
    CASE(paths_resolve_to_the_address_the_c_compiler_gives),
    CASE(located_and_constant_variables_are_marked),
    CASE(invalid_paths_are_refused_with_a_sentence),
    CASE(unreadable_type_names_refuse_the_parts_below_them),
    CASE(values_are_parsed_in_the_range_of_their_type),
    CASE(strings_up_to_126_characters_are_accepted),
    CASE(aggregates_become_json_arrays_and_objects),
    CASE(elementary_values_in_json),
    CASE(json_that_does_not_fit_is_refused_whole),
};

CHECK_MAIN(cases)
