/*
 * test_retain.c - retain.c on its own: the RETAIN store of a program table
 * written by hand, saved to and restored from files in a temporary directory.
 *
 * Linked with image.c and scan_core.c (retained registers live in the program
 * image), logcap.c for log_msg() (what the store says is checked line by line)
 * and io_wrap.c, through which every fsync() and rename() of a save passes
 * (their order is checked, and any of them can be made to fail).  The files
 * are read back here with a decoder of the layout documented at the top of
 * retain.c, written independently of it.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <ftw.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "check.h"
#include "io_wrap.h"
#include "logcap.h"
#include "runtime.h"

#define M "CONFIG0.RES0.MAIN."
#define POCKET_TYPE "ARRAY[1..3] OF ST_POCKET{TOOL:INT;VALID:BOOL}"
#define SECOND 1000000000ull

/* ------------------------------------------------------------ programs */

/* The storage of every program version's variables; zeroed between runs (a fresh process). */
typedef struct { int16_t tool; plc_bool_t valid; } pocket_t;
static struct storage {
    int16_t keep, b, scratch, limit;
    uint32_t scans;
    int32_t scans_dint, extra, distance;
    plc_string_t name;
    pocket_t pockets[3];
    int16_t tool, pocket1;
    int64_t big;
    plc_bool_t lamp;
} st;

static void *tool_p = &st.tool, *pocket1_p = &st.pocket1, *distance_p = &st.distance, *big_p = &st.big,
            *lamp_p = &st.lamp;

/* A program table as the compiler writes it: variables and located variables, with their RETAIN marks. */
typedef struct fake {
    plc_var_t vars[12];
    plc_located_t located[8];
    plc_program_t prog;
} fake_t;

static void add_var(fake_t *f, const char *path, uint16_t type, const char *type_name, void *addr, uint32_t size,
                    uint8_t retain)
{
    f->vars[f->prog.n_vars++] = (plc_var_t){ path, type, retain, 0, addr, size, type_name };
    f->prog.vars = f->vars;
}

static void add_located(fake_t *f, const char *address, const char *var, char area, char size, uint16_t type,
                        uint32_t index, void **ptr, uint8_t retain)
{
    f->located[f->prog.n_located++] = (plc_located_t){ address, var, area, size, type, index, 0, ptr, retain };
    f->prog.located = f->located;
}

static void begin(fake_t *f, uint32_t layout_hash)
{
    memset(f, 0, sizeof *f);
    f->prog.abi_version = PLC_ABI_VERSION;
    f->prog.config_name = "CONFIG0";
    f->prog.layout_hash = layout_hash;
}

/* Every kind of retained item: elementary, STRING, an array of structs, located registers; and what is not kept. */
static const plc_program_t *program_full(fake_t *f)
{
    begin(f, 0);
    add_var(f, M "KEEP", PLC_T_INT, "INT", &st.keep, 2, 1);
    add_var(f, M "SCANS", PLC_T_UDINT, "UDINT", &st.scans, 4, 1);
    add_var(f, M "NAME", PLC_T_STRING, "STRING", &st.name, sizeof st.name, 1);
    add_var(f, M "POCKETS", PLC_T_OTHER, POCKET_TYPE, st.pockets, sizeof st.pockets, 1);
    add_var(f, M "SCRATCH", PLC_T_INT, "INT", &st.scratch, 2, 0);           /* not RETAIN */
    add_var(f, M "LIMIT", PLC_T_INT, "INT", &st.limit, 2, 1);               /* RETAIN CONSTANT: not kept */
    f->vars[f->prog.n_vars - 1].constant = 1;
    add_located(f, "%MW0", M "TOOL", 'M', 'W', PLC_T_INT, 0, &tool_p, 1);
    add_located(f, "%MD1", M "DISTANCE", 'M', 'D', PLC_T_DINT, 1, &distance_p, 1);
    add_located(f, "%QX0.0", M "LAMP", 'Q', 'X', PLC_T_BOOL, 0, &lamp_p, 1);   /* a coil: cannot be kept */
    return &f->prog;
}

/* The smallest program with a variable and a register (the loops over every byte of its file). */
static const plc_program_t *program_small(fake_t *f, uint32_t layout_hash)
{
    begin(f, layout_hash);
    add_var(f, M "KEEP", PLC_T_INT, "INT", &st.keep, 2, 1);
    add_located(f, "%MW0", M "TOOL", 'M', 'W', PLC_T_INT, 0, &tool_p, 1);
    return &f->prog;
}

/* Version A and version B of a program upgrade. */
static const plc_program_t *program_a(fake_t *f)
{
    begin(f, 0);
    add_var(f, M "KEEP", PLC_T_INT, "INT", &st.keep, 2, 1);
    add_var(f, M "SCANS", PLC_T_UDINT, "UDINT", &st.scans, 4, 1);
    add_var(f, M "B", PLC_T_INT, "INT", &st.b, 2, 1);
    add_located(f, "%MW0", M "TOOL", 'M', 'W', PLC_T_INT, 0, &tool_p, 1);
    add_located(f, "%MW16", M "POCKET1", 'M', 'W', PLC_T_INT, 16, &pocket1_p, 1);
    return &f->prog;
}

static const plc_program_t *program_b(fake_t *f)
{
    begin(f, 0);
    add_var(f, M "KEEP", PLC_T_INT, "INT", &st.keep, 2, 1);                      /* the same */
    add_var(f, M "SCANS", PLC_T_DINT, "DINT", &st.scans_dint, 4, 1);             /* retyped: same size */
    add_var(f, M "NEW", PLC_T_DINT, "DINT", &st.extra, 4, 1);                    /* added; B removed */
    add_located(f, "%MW0", M "SPINDLE", 'M', 'W', PLC_T_INT, 0, &tool_p, 1);     /* TOOL renamed */
    add_located(f, "%MW20", M "POCKET1", 'M', 'W', PLC_T_INT, 20, &pocket1_p, 1);    /* moved */
    return &f->prog;
}

/* ------------------------------------------------------------ files */

static char root[PATH_MAX / 2];          /* short enough for every path below it */

static int remove_one(const char *path, const struct stat *sb, int flag, struct FTW *ftw)
{
    (void)sb;
    (void)flag;
    (void)ftw;
    return remove(path);
}

static void remove_root(void)
{
    if (root[0])
        nftw(root, remove_one, 16, FTW_DEPTH | FTW_PHYS);
}

/* A new empty directory for one case; *file is its retain file. */
static void new_dir(char *dir, char *file)
{
    static unsigned n;

    if (!root[0]) {
        const char *tmp = getenv("TMPDIR");
        char tmpl[PATH_MAX], real[PATH_MAX];
        snprintf(tmpl, sizeof tmpl, "%s/c_unit_retain.XXXXXX", tmp && tmp[0] ? tmp : "/tmp");
        if (!mkdtemp(tmpl) || !realpath(tmpl, real) || strlen(real) >= sizeof root) {
            perror("mkdtemp");
            exit(2);
        }
        memcpy(root, real, strlen(real) + 1);
        atexit(remove_root);
    }
    snprintf(dir, PATH_MAX / 2 + 16, "%s/%u", root, ++n);
    if (mkdir(dir, 0755) != 0) {
        perror(dir);
        exit(2);
    }
    snprintf(file, PATH_MAX, "%.*s/plc.retain", PATH_MAX / 2 + 16, dir);
}

static uint8_t *read_bytes(const char *path, size_t *len)
{
    FILE *f = fopen(path, "rb");
    uint8_t *buf = NULL;
    long n;

    *len = 0;
    if (!f)
        return NULL;
    if (fseek(f, 0, SEEK_END) == 0 && (n = ftell(f)) >= 0 && fseek(f, 0, SEEK_SET) == 0) {
        buf = malloc((size_t)n + 1);
        if (buf && fread(buf, 1, (size_t)n, f) == (size_t)n)
            *len = (size_t)n;
    }
    fclose(f);
    return buf;
}

static void write_bytes(const char *path, const uint8_t *data, size_t len)
{
    FILE *f = fopen(path, "wb");

    if (!f || fwrite(data, 1, len, f) != len) {
        perror(path);
        exit(2);
    }
    fclose(f);
}

static bool exists(const char *path)
{
    return access(path, F_OK) == 0;
}

static uint32_t le32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static void put_le32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

/* The CRC of a file made right again after a change (damage the CRC cannot see). */
static void fix_crc(uint8_t *data, size_t len)
{
    put_le32(data + len - 4, crc32_update(0, data, len - 4));
}

/* ------------------------------------------------------------ decoding */

#define MAX_SAVED 16

typedef struct saved {
    uint8_t flags;
    char path[96], type[96], where[24];
    const uint8_t *value;
    uint32_t size;
    const uint8_t *raw;           /* the whole entry */
    size_t raw_len;
} saved_t;

typedef struct decoded {
    uint8_t *bytes;
    size_t len;
    uint32_t version, count;
    uint64_t generation;
    unsigned n;
    saved_t e[MAX_SAVED];
} decoded_t;

static void text(char *out, size_t n, const uint8_t *p, size_t len)
{
    snprintf(out, n, "%.*s", (int)len, (const char *)p);
}

/* Read a version 2 file; false (with a message) when it is not one this decoder can check. */
static bool decode(const char *path, decoded_t *d)
{
    memset(d, 0, sizeof *d);
    d->bytes = read_bytes(path, &d->len);
    if (!CHECK(d->bytes && d->len >= 32) || !CHECK_MEM(d->bytes, "ATCPLCR1", 8))
        return false;
    d->version = le32(d->bytes + 8);
    d->count = le32(d->bytes + 12);
    d->generation = le32(d->bytes + 16) | (uint64_t)le32(d->bytes + 20) << 32;
    if (!CHECK_UINT(d->version, 2) || !CHECK_UINT(le32(d->bytes + 24), d->len - 32)
        || !CHECK_UINT(le32(d->bytes + d->len - 4), crc32_update(0, d->bytes, d->len - 4)))
        return false;
    size_t at = 28;
    for (uint32_t i = 0; i < d->count && i < MAX_SAVED; i++) {
        const uint8_t *h = d->bytes + at;
        saved_t *s = &d->e[d->n++];
        size_t p = (size_t)(h[2] | h[3] << 8), t = (size_t)(h[4] | h[5] << 8), w = (size_t)(h[6] | h[7] << 8);
        s->flags = h[0];
        s->size = le32(h + 8);
        text(s->path, sizeof s->path, h + 12, p);
        text(s->type, sizeof s->type, h + 12 + p, t);
        text(s->where, sizeof s->where, h + 12 + p + t, w);
        s->value = h + 12 + p + t + w;
        s->raw = h;
        s->raw_len = 12 + p + t + w + s->size;
        at += s->raw_len;
    }
    return CHECK_UINT(d->n, d->count) && CHECK_UINT(at, d->len - 4);
}

static void release(decoded_t *d)
{
    free(d->bytes);
    d->bytes = NULL;
}

static const saved_t *saved_named(const decoded_t *d, const char *path)
{
    for (unsigned i = 0; i < d->n; i++)
        if (strcmp(d->e[i].path, path) == 0)
            return &d->e[i];
    return NULL;
}

/* ------------------------------------------------------------ runs */

/* A runtime as main.c builds it, as far as the retain store sees it: the program, the options, the image. */
static runtime_t *start(const plc_program_t *prog, const char *file, const char *registers, int interval_ms,
                        int *rc)
{
    runtime_t *rt = calloc(1, sizeof *rt);

    if (!rt) {
        perror("calloc");
        exit(2);
    }
    rt->prog = prog;
    rt->log = logcap_sink();
    rt->opt.retain_path = file;
    rt->opt.retain_interval_ms = interval_ms;
    if (registers) {
        char err[160];
        if (addr_set_parse(&rt->opt.retain_registers, registers, MAP_HOLDING, err, sizeof err) != 0) {
            fprintf(stderr, "%s\n", err);
            exit(2);
        }
        rt->opt.have_retain_registers = true;
    }
    *rc = retain_open(rt, &rt->retain);
    return rt;
}

/* The end of a run, as scan.c ends it while the program runs: the last values taken, the final save. */
static void stop(runtime_t *rt)
{
    retain_capture(rt);
    retain_close(rt);
    free(rt);
}

/* What the writer thread has done so far. */
typedef struct progress { runtime_t *rt; uint32_t saves; io_call_t call; unsigned calls; } progress_t;

static bool saves_reached(const progress_t *p)
{
    return retain_saves(p->rt->retain) >= p->saves;
}

static bool save_failed(const progress_t *p)
{
    return retain_last_failed(p->rt->retain);
}

static bool calls_reached(const progress_t *p)
{
    return io_count(p->call) >= p->calls;
}

/* Scans end at program time now, one a millisecond, until the writer has done what done() waits for: each
 * compares the values and hands a change to the writer (a trylock: when the writer holds the lock an instant,
 * the next scan tries again).  The limit, 60 s, only bounds a hang (a loaded machine, a sanitizer build). */
static bool scans_until(runtime_t *rt, uint64_t now, bool (*done)(const progress_t *), progress_t p)
{
    p.rt = rt;
    for (int i = 0; i < 60000; i++) {
        retain_after_scan(rt, now);
        if (done(&p))
            return true;
        nanosleep(&(struct timespec){ 0, 1000000 }, NULL);
    }
    return false;
}

static bool scan_and_save(runtime_t *rt, uint64_t now, uint32_t saves)
{
    return scans_until(rt, now, saves_reached, (progress_t){ .saves = saves });
}

static void reset_storage(void)
{
    memset(&st, 0, sizeof st);
}

/* ------------------------------------------------------------ cases */

static void crc32_is_the_ieee_crc(void)
{
    CHECK_UINT(crc32_update(0, "123456789", 9), 0xcbf43926u);                  /* the standard check value */
    CHECK_UINT(crc32_update(crc32_update(0, "1234", 4), "56789", 5), 0xcbf43926u);
    CHECK_UINT(crc32_update(0, "", 0), 0);
}

static void retained_values_survive_a_restart_by_path_and_type(void)
{
    char dir[PATH_MAX], file[PATH_MAX];
    fake_t f;
    decoded_t d;
    int rc;

    new_dir(dir, file);
    reset_storage();
    logcap_clear();
    runtime_t *rt = start(program_full(&f), file, NULL, 200, &rc);
    REQUIRE_INT(rc, 0);
    REQUIRE(rt->retain != NULL);
    CHECK_INT(logcap_count("does not exist yet; RETAIN variables start from their initial values"), 1);
    CHECK_INT(logcap_count("warning: retain: " M "LAMP AT %QX0.0 is declared RETAIN, but only holding registers "
                           "(%QW %MW %MD %ML) are kept"), 1);
    CHECK_INT(logcap_count("retain: 6 values (152 bytes) retained"), 1);
    st.keep = -1234;
    st.scans = 0xdeadbeefu;
    st.name.len = 3;
    memcpy(st.name.body, "T12", 4);
    st.pockets[1] = (pocket_t){ 7, 1 };
    st.scratch = 9;
    st.limit = 3;
    image_prog_set_holding(&rt->pimg, MAP_HOLD_MW + 0, 5);           /* TOOL AT %MW0 */
    rt->pimg.md[1].i = -100000;                                       /* DISTANCE AT %MD1 */
    stop(rt);
    CHECK_INT(logcap_count("up to date (1 saves this run)"), 1);

    if (decode(file, &d)) {
        const char *order[][3] = {
            { M "KEEP", "INT", "" }, { M "SCANS", "UDINT", "" }, { M "NAME", "STRING", "" },
            { M "POCKETS", POCKET_TYPE, "" }, { M "TOOL", "INT", "%MW0" }, { M "DISTANCE", "DINT", "%MD1" },
        };
        CHECK_UINT(d.n, 6);
        for (unsigned i = 0; i < d.n && i < 6; i++) {
            check_row("entry %u", i);
            CHECK_STR(d.e[i].path, order[i][0]);
            CHECK_STR(d.e[i].type, order[i][1]);
            CHECK_STR(d.e[i].where, order[i][2]);
            CHECK_UINT(d.e[i].flags, 0);
        }
        check_row("%s", "");
        CHECK_UINT(d.generation, 1);
        CHECK_MEM(d.e[0].value, &(int16_t){ -1234 }, 2);                 /* variables in native order */
        CHECK_MEM(d.e[4].value, "\x00\x05", 2);                          /* registers high byte first */
        CHECK_MEM(d.e[5].value, "\xff\xfe\x79\x60", 4);                  /* -100000, high word first */
    }
    release(&d);

    reset_storage();
    logcap_clear();
    rt = start(program_full(&f), file, NULL, 200, &rc);
    REQUIRE_INT(rc, 0);
    CHECK_INT(logcap_count("retain: restored 6 of 6 values from"), 1);
    CHECK_INT(logcap_count("(0 new, 0 kept aside now, 0 from earlier versions)"), 1);
    CHECK_INT(st.keep, -1234);
    CHECK_UINT(st.scans, 0xdeadbeefu);
    CHECK_UINT(st.name.len, 3);
    CHECK_STR(st.name.body, "T12");
    CHECK(st.pockets[1].tool == 7 && st.pockets[1].valid == 1 && st.pockets[0].tool == 0);
    CHECK_INT(st.scratch, 0);                                         /* not RETAIN: initial value */
    CHECK_INT(st.limit, 0);
    CHECK_UINT(rt->pimg.mw[0], 5);
    CHECK_INT(rt->pimg.md[1].i, -100000);
    CHECK_UINT(rt->flags, DIAG_FLAG_RETAIN_RESTORED);
    stop(rt);
}

typedef struct damage {
    const char *name;
    void (*apply)(uint8_t *data, size_t *len);
    const char *why;
} damage_t;

static void flip_body_bit(uint8_t *d, size_t *n) { (void)n; d[28] ^= 0x40; }
static void cut_last_byte(uint8_t *d, size_t *n) { (void)d; *n -= 1; }
static void empty(uint8_t *d, size_t *n) { (void)d; *n = 0; }
static void short_header(uint8_t *d, size_t *n) { (void)d; *n = 31; }
static void other_magic(uint8_t *d, size_t *n) { (void)n; memcpy(d, "XXXXXXXX", 8); }
static void version_7(uint8_t *d, size_t *n) { (void)n; d[8] = 7; }
static void one_entry_more(uint8_t *d, size_t *n) { d[12] += 1; fix_crc(d, *n); }
static void one_entry_less(uint8_t *d, size_t *n) { d[12] -= 1; fix_crc(d, *n); }
static void huge_count(uint8_t *d, size_t *n) { d[12] = 0xff; d[13] = 0xff; fix_crc(d, *n); }
static void path_too_long(uint8_t *d, size_t *n) { d[28 + 2] = 0xf0; fix_crc(d, *n); }
static void nul_in_path(uint8_t *d, size_t *n) { d[28 + 12] = 0; fix_crc(d, *n); }
static void empty_path(uint8_t *d, size_t *n) { d[28 + 2] = 0; fix_crc(d, *n); }
static void appended(uint8_t *d, size_t *n) { d[*n] = 0; *n += 1; }
static void body_length(uint8_t *d, size_t *n) { d[24] += 1; fix_crc(d, *n); }

static const damage_t damages[] = {
    { "flipped bit", flip_body_bit, "CRC mismatch: the file is corrupt" },
    { "truncated", cut_last_byte, "body length differs from the file size: the file is truncated or corrupt" },
    { "empty", empty, "size 0 bytes, not a retain file of this runtime" },
    { "shorter than a header", short_header, "size 31 bytes, not a retain file of this runtime" },
    { "magic", other_magic, "not a retain file" },
    { "version", version_7, "unknown format version" },
    { "entry count +1", one_entry_more, "malformed entry table: the file is corrupt" },
    { "entry count -1", one_entry_less, "malformed entry table: the file is corrupt" },
    { "entry count huge", huge_count, "entry count larger than the file: the file is corrupt" },
    { "path length", path_too_long, "malformed entry table: the file is corrupt" },
    { "NUL in a path", nul_in_path, "malformed entry table: the file is corrupt" },
    { "empty path", empty_path, "malformed entry table: the file is corrupt" },
    { "byte appended", appended, "body length differs from the file size" },
    { "body length", body_length, "body length differs from the file size" },
};

/* A small program's file with KEEP = 555 and TOOL = 9, as its runtime saved it. */
static uint8_t *saved_small_file(const char *file, size_t *len)
{
    fake_t f;
    int rc;

    reset_storage();
    runtime_t *rt = start(program_small(&f, 0), file, NULL, 200, &rc);
    if (rc != 0)
        return NULL;
    st.keep = 555;
    image_prog_set_holding(&rt->pimg, MAP_HOLD_MW, 9);
    stop(rt);
    return read_bytes(file, len);
}

/* Start on a damaged file: it must be named, set aside as FILE.rejected, and not one value applied. */
static void start_on_damaged(const char *file, const uint8_t *data, size_t len, const char *why)
{
    char rejected[PATH_MAX + 16], expect[PATH_MAX + 200];
    fake_t f;
    int rc;
    size_t got;

    snprintf(rejected, sizeof rejected, "%s.rejected", file);
    remove(rejected);
    write_bytes(file, data, len);
    reset_storage();
    logcap_clear();
    runtime_t *rt = start(program_small(&f, 0), file, NULL, 200, &rc);
    REQUIRE_INT(rc, 0);
    snprintf(expect, sizeof expect, "warning: retain: %s rejected (%s", file, why ? why : "");
    CHECK_INT(logcap_count(expect), 1);
    snprintf(expect, sizeof expect, "kept as %s; RETAIN variables start from their initial values", rejected);
    CHECK_INT(logcap_count(expect), 1);
    CHECK_INT(logcap_count("restored"), 0);
    CHECK_UINT(rt->flags, DIAG_FLAG_RETAIN_REJECTED);
    CHECK_INT(st.keep, 0);                                            /* nothing half-applied */
    CHECK_UINT(rt->pimg.mw[0], 0);
    uint8_t *aside = read_bytes(rejected, &got);
    if (CHECK(aside != NULL) && CHECK_UINT(got, len))
        CHECK_MEM(aside, data, len);                                  /* kept as it was found */
    free(aside);
    stop(rt);
    decoded_t d;
    if (decode(file, &d) && CHECK_UINT(d.n, 2))                       /* a fresh, valid file replaced it */
        CHECK_MEM(d.e[0].value, "\0\0", 2);
    release(&d);
}

static void a_damaged_file_is_named_set_aside_and_not_applied(void)
{
    char dir[PATH_MAX], file[PATH_MAX];
    size_t len;

    new_dir(dir, file);
    uint8_t *good = saved_small_file(file, &len);
    REQUIRE(good != NULL);
    for (size_t i = 0; i < sizeof damages / sizeof damages[0]; i++) {
        uint8_t *data = malloc(len + 1);
        size_t n = len;
        REQUIRE(data != NULL);
        memcpy(data, good, len);
        damages[i].apply(data, &n);
        check_row("%s", damages[i].name);
        start_on_damaged(file, data, n, damages[i].why);
        free(data);
    }
    free(good);
}

/* Every prefix of a good file (a write torn at any byte) and every one-bit change is refused as a whole. */
static void a_torn_or_flipped_file_is_refused_at_every_byte(void)
{
    char dir[PATH_MAX], file[PATH_MAX];
    size_t len;
    unsigned torn_applied = 0, flips_applied = 0;
    long first_torn = -1, first_flip = -1;

    new_dir(dir, file);
    uint8_t *good = saved_small_file(file, &len);
    REQUIRE(good != NULL);
    CHECK_UINT(len, 114);
    io_skip_sync(true);                       /* 2 x 114 saves: the file's content is what is tested here */
    for (size_t cut = 0; cut < len; cut++) {
        fake_t f;
        int rc;
        write_bytes(file, good, cut);
        reset_storage();
        logcap_clear();
        runtime_t *rt = start(program_small(&f, 0), file, NULL, 200, &rc);
        if (rc != 0 || rt->flags != DIAG_FLAG_RETAIN_REJECTED || st.keep != 0 || rt->pimg.mw[0] != 0) {
            torn_applied++;
            first_torn = first_torn < 0 ? (long)cut : first_torn;
        }
        stop(rt);
    }
    for (size_t at = 0; at < len; at++) {
        fake_t f;
        int rc;
        uint8_t *data = malloc(len);
        REQUIRE(data != NULL);
        memcpy(data, good, len);
        data[at] ^= (uint8_t)(1u << (at % 8));
        write_bytes(file, data, len);
        free(data);
        reset_storage();
        runtime_t *rt = start(program_small(&f, 0), file, NULL, 200, &rc);
        if (rc != 0 || rt->flags != DIAG_FLAG_RETAIN_REJECTED || st.keep != 0 || rt->pimg.mw[0] != 0) {
            flips_applied++;
            first_flip = first_flip < 0 ? (long)at : first_flip;
        }
        stop(rt);
    }
    io_skip_sync(false);
    CHECK_UINT(torn_applied, 0);
    CHECK_INT(first_torn, -1);
    CHECK_UINT(flips_applied, 0);
    CHECK_INT(first_flip, -1);
    free(good);
}

/* A save is: FILE.tmp written and fsync'ed, renamed over FILE, the directory fsync'ed; nothing else is left. */
static void a_save_syncs_the_file_renames_it_then_syncs_the_directory(void)
{
    char dir[PATH_MAX], file[PATH_MAX], tmp[PATH_MAX + 8];
    fake_t f;
    decoded_t d;
    io_event_t ev[8];
    int rc;

    new_dir(dir, file);
    snprintf(tmp, sizeof tmp, "%s.tmp", file);
    reset_storage();
    logcap_clear();
    io_reset();
    runtime_t *rt = start(program_small(&f, 0), file, NULL, 200, &rc);
    REQUIRE_INT(rc, 0);
    st.keep = 1;
    REQUIRE(scan_and_save(rt, 1 * SECOND, 1));                        /* the first save is not rate-limited */
    REQUIRE_INT(io_events(ev, 8), 3);
    CHECK_INT(ev[0].call, IO_FSYNC_FILE);
    CHECK_STR(ev[0].path, tmp);
    CHECK_INT(ev[1].call, IO_RENAME);
    CHECK_STR(ev[1].path, tmp);
    CHECK_STR(ev[1].to, file);
    CHECK_INT(ev[2].call, IO_FSYNC_DIR);
    CHECK_STR(ev[2].path, dir);
    CHECK(!exists(tmp));
    if (decode(file, &d)) {
        CHECK_UINT(d.generation, 1);
        CHECK_MEM(d.e[0].value, &(int16_t){ 1 }, 2);
    }
    release(&d);
    CHECK(!retain_last_failed(rt->retain));

    st.keep = 2;
    REQUIRE(scan_and_save(rt, 2 * SECOND, 2));
    CHECK_INT(io_events(ev, 8), 6);
    CHECK(ev[3].call == IO_FSYNC_FILE && ev[4].call == IO_RENAME && ev[5].call == IO_FSYNC_DIR);
    if (decode(file, &d)) {
        CHECK_UINT(d.generation, 2);
        CHECK_MEM(d.e[0].value, &(int16_t){ 2 }, 2);
    }
    release(&d);
    stop(rt);                                                         /* nothing changed since: no third save */
    CHECK_INT(io_count(IO_RENAME), 2);
    CHECK_INT(logcap_count("up to date (2 saves this run)"), 1);
    CHECK_INT(logcap_count("error:"), 0);
}

static void a_change_within_the_interval_waits_and_shutdown_saves_it(void)
{
    char dir[PATH_MAX], file[PATH_MAX];
    fake_t f;
    decoded_t d;
    int rc;

    new_dir(dir, file);
    reset_storage();
    runtime_t *rt = start(program_small(&f, 0), file, NULL, 200, &rc);
    REQUIRE_INT(rc, 0);
    st.keep = 1;
    REQUIRE(scan_and_save(rt, 10 * SECOND, 1));
    st.keep = 2;
    retain_after_scan(rt, 10 * SECOND + 199000000ull);               /* 199 ms later: held back */
    st.keep = 3;
    REQUIRE(scan_and_save(rt, 10 * SECOND + 200000000ull, 2));       /* 200 ms: handed over */
    if (decode(file, &d)) {
        CHECK_UINT(d.generation, 2);                                  /* a hand-over of keep = 2 would make it 3 */
        CHECK_MEM(d.e[0].value, &(int16_t){ 3 }, 2);
    }
    release(&d);
    st.keep = 4;
    retain_after_scan(rt, 10 * SECOND + 300000000ull);               /* held back again */
    stop(rt);                                                         /* shutdown saves what was held back */
    if (decode(file, &d)) {
        CHECK_UINT(d.generation, 3);
        CHECK_MEM(d.e[0].value, &(int16_t){ 4 }, 2);
    }
    release(&d);
}

static void capture_takes_the_values_without_saving(void)
{
    char dir[PATH_MAX], file[PATH_MAX];
    fake_t f;
    decoded_t d;
    int rc;

    new_dir(dir, file);
    reset_storage();
    io_reset();
    runtime_t *rt = start(program_small(&f, 0), file, NULL, 200, &rc);
    REQUIRE_INT(rc, 0);
    st.keep = 42;
    retain_capture(rt);                    /* scan.c at shutdown: host writes taken after the last scan */
    st.keep = 43;                          /* a later change that was never captured */
    CHECK_INT(io_count(IO_RENAME), 0);
    retain_close(rt);                      /* retain_close saves what was captured, not the storage now */
    free(rt);
    if (decode(file, &d))
        CHECK_MEM(d.e[0].value, &(int16_t){ 42 }, 2);
    release(&d);
}

typedef struct failing_step {
    const char *step;             /* as the log names it */
    io_call_t call;               /* the call failed (IO_CALLS: FILE.tmp made a directory, open fails) */
    bool renamed;                 /* the new file is in place although the save failed */
    const char *error;
} failing_step_t;

static void a_failed_save_is_reported_once_and_the_last_good_file_stays(void)
{
    const failing_step_t rows[] = {
        { "open", IO_CALLS, false, "Is a directory" },
        { "fsync", IO_FSYNC_FILE, false, "Input/output error" },
        { "rename", IO_RENAME, false, "Input/output error" },
        { "directory fsync", IO_FSYNC_DIR, true, "Input/output error" },
    };

    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++) {
        const failing_step_t *r = &rows[i];
        char dir[PATH_MAX], file[PATH_MAX], tmp[PATH_MAX + 8], line[PATH_MAX + 100];
        fake_t f;
        decoded_t d;
        int rc;

        check_row("%s", r->step);
        new_dir(dir, file);
        snprintf(tmp, sizeof tmp, "%s.tmp", file);
        reset_storage();
        logcap_clear();
        io_reset();
        runtime_t *rt = start(program_small(&f, 0), file, NULL, 200, &rc);
        REQUIRE_INT(rc, 0);
        st.keep = 1;
        REQUIRE(scan_and_save(rt, 1 * SECOND, 1));

        if (r->call == IO_CALLS)
            CHECK_INT(mkdir(tmp, 0755), 0);
        else
            io_fail(r->call, EIO);
        st.keep = 2;
        REQUIRE(scans_until(rt, 2 * SECOND, save_failed, (progress_t){ 0 }));
        snprintf(line, sizeof line, "error: retain: cannot save %s (%s: %s)", file, r->step, r->error);
        CHECK_INT(logcap_count(line), 1);
        CHECK_UINT(retain_saves(rt->retain), 1);
        if (decode(file, &d)) {                                       /* always one complete save on disk */
            CHECK_UINT(d.generation, r->renamed ? 2 : 1);
            int16_t saved = r->renamed ? 2 : 1;
            CHECK_MEM(d.e[0].value, &saved, 2);
        }
        release(&d);
        if (r->call != IO_CALLS) {                                    /* a second failure */
            st.keep = 3;
            REQUIRE(scans_until(rt, 3 * SECOND, calls_reached, (progress_t){ .call = r->call, .calls = 3 }));
            io_reset();
        } else {
            CHECK_INT(rmdir(tmp), 0);
        }
        st.keep = 4;
        REQUIRE(scan_and_save(rt, 4 * SECOND, 2));
        CHECK(!retain_last_failed(rt->retain));
        CHECK_INT(logcap_count("error: retain: cannot save"), 1);    /* one line for the whole failure streak */
        snprintf(line, sizeof line, "retain: saving to %s works again", file);
        CHECK_INT(logcap_count(line), 1);
        if (decode(file, &d))
            CHECK_MEM(d.e[0].value, &(int16_t){ 4 }, 2);
        release(&d);
        stop(rt);
    }
}

/* Version A of the program runs once and saves keep 11, scans 22, b 33 and %MW0 5, %MW16 7 to `file`. */
static void saved_by_version_a(fake_t *f, const char *file)
{
    int rc;

    reset_storage();
    runtime_t *rt = start(program_a(f), file, NULL, 200, &rc);
    REQUIRE_INT(rc, 0);
    st.keep = 11;
    st.scans = 22;
    st.b = 33;
    rt->pimg.mw[0] = 5;
    rt->pimg.mw[16] = 7;
    stop(rt);
}

static void a_layout_change_keeps_what_matches_and_sets_the_rest_aside(void)
{
    char dir[PATH_MAX], file[PATH_MAX];
    fake_t f;
    decoded_t a, b;
    int rc;

    new_dir(dir, file);
    saved_by_version_a(&f, file);
    runtime_t *rt;
    REQUIRE(decode(file, &a));

    reset_storage();
    logcap_clear();
    rt = start(program_b(&f), file, NULL, 200, &rc);
    REQUIRE_INT(rc, 0);
    CHECK_INT(st.keep, 11);                                            /* same name, same type */
    CHECK_UINT(rt->pimg.mw[0], 5);                                    /* renamed, found by address */
    CHECK_UINT(rt->pimg.mw[20], 7);                                   /* moved, found by name */
    CHECK_INT(st.scans_dint, 0);                                      /* retyped: initial value */
    CHECK_INT(st.extra, 0);                                           /* new: initial value */
    CHECK_INT(logcap_count("retain: " M "POCKET1 (INT) restored; it moved from %MW16 to %MW20"), 1);
    CHECK_INT(logcap_count("warning: retain: " M "SPINDLE (INT) restored by address %MW0, where " M "TOOL was saved "
                           "(renamed?)"), 1);
    CHECK_INT(logcap_count("warning: retain: " M "SCANS changed type from UDINT to DINT: its saved value is kept "
                           "aside in the file and " M "SCANS starts from its initial value"), 1);
    CHECK_INT(logcap_count("warning: retain: " M "B (INT) is not retained by this program: its saved value is kept "
                           "aside in the file"), 1);
    CHECK_INT(logcap_count("retain: " M "NEW (DINT) has no saved value: it starts from its initial value"), 1);
    CHECK_INT(logcap_count(M "SCANS (DINT) has no saved value"), 0);  /* said once, as a type change */
    CHECK_INT(logcap_count("warning: retain: restored 3 of 5 values from"), 1);
    CHECK_INT(logcap_count("(2 new, 2 kept aside now, 0 from earlier versions)"), 1);
    CHECK_UINT(rt->flags, DIAG_FLAG_RETAIN_RESTORED | DIAG_FLAG_RETAIN_KEPT_ASIDE);
    st.scans_dint = -9;
    stop(rt);

    if (decode(file, &b)) {
        CHECK_UINT(b.n, 7);                                           /* B's 5 entries, then 2 kept aside */
        const saved_t *scans = &b.e[5], *old_b = &b.e[6];
        CHECK_STR(scans->path, M "SCANS");
        CHECK_STR(scans->type, "UDINT");
        CHECK_UINT(scans->flags, 1);
        CHECK_STR(old_b->path, M "B");
        CHECK_UINT(old_b->flags, 1);
        const saved_t *was = saved_named(&a, M "SCANS");
        if (CHECK(was != NULL) && CHECK_UINT(scans->raw_len, was->raw_len))      /* the saved bytes, as they were */
            CHECK_MEM(scans->raw + 1, was->raw + 1, was->raw_len - 1);
        CHECK_MEM(b.e[1].value, &(int32_t){ -9 }, 4);
        CHECK_STR(b.e[3].path, M "SPINDLE");
    }
    release(&a);
    release(&b);
}

static void going_back_to_the_earlier_version_restores_what_was_set_aside(void)
{
    char dir[PATH_MAX], file[PATH_MAX];
    fake_t f;
    decoded_t d;
    int rc;

    new_dir(dir, file);
    saved_by_version_a(&f, file);
    runtime_t *rt;
    reset_storage();
    rt = start(program_b(&f), file, NULL, 200, &rc);                  /* the upgrade */
    REQUIRE_INT(rc, 0);
    st.scans_dint = -9;
    st.extra = 4;
    stop(rt);

    reset_storage();
    logcap_clear();
    rt = start(program_a(&f), file, NULL, 200, &rc);                  /* and back */
    REQUIRE_INT(rc, 0);
    CHECK_INT(st.keep, 11);
    CHECK_UINT(st.scans, 22);                                         /* from the entries kept aside */
    CHECK_INT(st.b, 33);
    CHECK_UINT(rt->pimg.mw[0], 5);
    CHECK_UINT(rt->pimg.mw[16], 7);
    CHECK_INT(logcap_count("warning: retain: " M "TOOL (INT) restored by address %MW0, where " M "SPINDLE was saved"),
              1);
    CHECK_INT(logcap_count("warning: retain: " M "SCANS changed type from DINT to UDINT: its UDINT value kept "
                           "aside earlier is restored and the DINT value is kept aside in the file"), 1);
    CHECK_INT(logcap_count("starts from its initial value"), 0);
    CHECK_INT(logcap_count("warning: retain: " M "NEW (DINT) is not retained by this program"), 1);
    CHECK_INT(logcap_count("restored 5 of 5 values from"), 1);
    CHECK_INT(logcap_count("(0 new, 2 kept aside now, 0 from earlier versions)"), 1);
    stop(rt);

    reset_storage();
    logcap_clear();
    rt = start(program_a(&f), file, NULL, 200, &rc);                  /* once more: they stay aside, flagged */
    REQUIRE_INT(rc, 0);
    CHECK_INT(logcap_count("retain: " M "SCANS (DINT) still kept aside from an earlier program version"), 1);
    CHECK_INT(logcap_count("retain: " M "NEW (DINT) still kept aside from an earlier program version"), 1);
    CHECK_INT(logcap_count("retain: restored 5 of 5 values from"), 1);
    CHECK_INT(logcap_count("(0 new, 0 kept aside now, 2 from earlier versions)"), 1);
    CHECK_INT(logcap_count("warning:"), 0);
    CHECK_UINT(rt->flags, DIAG_FLAG_RETAIN_RESTORED);
    stop(rt);
    if (decode(file, &d)) {
        CHECK_UINT(d.n, 7);
        const saved_t *extra = saved_named(&d, M "NEW");
        if (CHECK(extra != NULL)) {
            CHECK_UINT(extra->flags, 1);
            CHECK_MEM(extra->value, &(int32_t){ 4 }, 4);
        }
    }
    release(&d);
}

/* A file of format version 1 as the first release wrote it for program_small: one block, a layout hash. */
static size_t v1_file(uint8_t *out, uint32_t layout_hash, int16_t keep, uint16_t tool, size_t extra)
{
    uint8_t word[4];
    uint32_t h;
    size_t n = 28;

    put_le32(word, layout_hash);
    h = crc32_update(0, word, 4);
    h = crc32_update(h, M "KEEP", strlen(M "KEEP") + 1);
    put_le32(word, PLC_T_INT);
    h = crc32_update(h, word, 4);
    put_le32(word, 2);
    h = crc32_update(h, word, 4);
    put_le32(word, MAP_HOLD_MW);                                      /* the register of TOOL AT %MW0 */
    h = crc32_update(h, word, 4);
    memcpy(out, "ATCPLCR1", 8);
    put_le32(out + 8, 1);
    put_le32(out + 12, h);
    put_le32(out + 16, 5);
    put_le32(out + 20, 0);
    memcpy(out + n, &keep, 2);
    out[n + 2] = (uint8_t)(tool >> 8);
    out[n + 3] = (uint8_t)tool;
    n += 4;
    memset(out + n, 0, extra);
    n += extra;
    put_le32(out + 24, (uint32_t)(n - 28));
    put_le32(out + n, crc32_update(0, out, n));
    return n + 4;
}

static void a_file_of_format_version_1_is_read_once_when_its_layout_is_this_programs(void)
{
    char dir[PATH_MAX], file[PATH_MAX];
    uint8_t data[64];
    fake_t f;
    decoded_t d;
    int rc;

    new_dir(dir, file);
    size_t size = v1_file(data, 0x5eed0001u, -4321, 12, 0);
    write_bytes(file, data, size);
    reset_storage();
    logcap_clear();
    runtime_t *rt = start(program_small(&f, 0x5eed0001u), file, NULL, 200, &rc);
    REQUIRE_INT(rc, 0);
    CHECK_INT(logcap_count("retain: restored 2 values from"), 1);
    CHECK_INT(logcap_count("(format version 1; saved as version 2 from now on)"), 1);
    CHECK_INT(st.keep, -4321);
    CHECK_UINT(rt->pimg.mw[0], 12);
    CHECK_UINT(rt->flags, DIAG_FLAG_RETAIN_RESTORED);
    stop(rt);
    if (decode(file, &d) && CHECK_UINT(d.n, 2)) {
        CHECK_MEM(d.e[0].value, &(int16_t){ -4321 }, 2);
        CHECK_STR(d.e[1].where, "%MW0");
    }
    release(&d);

    const struct { const char *name; uint32_t hash; size_t extra; bool bad_crc; const char *why; } rows[] = {
        { "another program", 0x0badcafeu, 0, false, "format version 1 file saved by a different program" },
        { "another size", 0x5eed0001u, 2, false, "format version 1 file of a different size: saved by a different "
                                                 "program" },
        { "flipped bit", 0x5eed0001u, 0, true, "CRC mismatch: the file is corrupt" },
    };
    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++) {
        size_t n = v1_file(data, rows[i].hash, 55, 3, rows[i].extra);
        if (rows[i].bad_crc)
            data[29] ^= 1;
        check_row("%s", rows[i].name);
        start_on_damaged(file, data, n, rows[i].why);
    }
}

/* One runtime per file: a second one is refused and told the holder's pid; the kernel frees a killed holder's. */
static void a_second_owner_of_the_retain_file_is_refused(void)
{
    char dir[PATH_MAX], file[PATH_MAX], lock[PATH_MAX + 8], line[PATH_MAX * 2 + 120], pid_text[32];
    int ready[2], release_fd[2], rc;
    fake_t f;

    new_dir(dir, file);
    snprintf(lock, sizeof lock, "%s.lock", file);
    REQUIRE(pipe(ready) == 0 && pipe(release_fd) == 0);
    fflush(stdout);
    pid_t holder = fork();
    REQUIRE(holder >= 0);
    if (holder == 0) {                                               /* the first runtime */
        close(ready[0]);
        close(release_fd[1]);
        runtime_t *rt = start(program_small(&f, 0), file, NULL, 200, &rc);
        char c = 'r';
        if (rc != 0 || write(ready[1], &c, 1) != 1)
            _exit(3);
        while (read(release_fd[0], &c, 1) > 0) {
        }
        stop(rt);
        _exit(0);
    }
    close(ready[1]);
    close(release_fd[0]);
    char c;
    REQUIRE_INT(read(ready[0], &c, 1), 1);                           /* the holder has the store open */

    logcap_clear();
    runtime_t *rt = start(program_small(&f, 0), file, NULL, 200, &rc);
    CHECK_INT(rc, -1);
    CHECK(rt->retain == NULL);
    snprintf(line, sizeof line, "error: retain: %s is in use by another runtime (pid %ld holds %s); give each "
             "runtime its own retain file", file, (long)holder, lock);
    CHECK_INT(logcap_count(line), 1);
    free(rt);
    size_t n;
    char *held = (char *)read_bytes(lock, &n);
    snprintf(pid_text, sizeof pid_text, "%ld\n", (long)holder);
    if (CHECK(held != NULL) && CHECK_UINT(n, strlen(pid_text)))
        CHECK_MEM(held, pid_text, n);
    free(held);

    kill(holder, SIGKILL);                                           /* the kernel drops a dead process's lock */
    int status;
    CHECK_INT(waitpid(holder, &status, 0), holder);
    CHECK(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL);
    close(ready[0]);
    close(release_fd[1]);

    logcap_clear();
    rt = start(program_small(&f, 0), file, NULL, 200, &rc);
    CHECK_INT(rc, 0);
    CHECK(rt->retain != NULL);
    held = (char *)read_bytes(lock, &n);
    snprintf(pid_text, sizeof pid_text, "%ld\n", (long)getpid());
    if (CHECK(held != NULL) && CHECK_UINT(n, strlen(pid_text)))
        CHECK_MEM(held, pid_text, n);
    free(held);
    stop(rt);
    CHECK(exists(lock));                 /* it stays: two runtimes must never lock two different inodes */
}

static void retained_registers_are_entries_named_by_path_or_address(void)
{
    char dir[PATH_MAX], file[PATH_MAX];
    fake_t f;
    int rc;

    begin(&f, 0);
    add_var(&f, M "KEEP", PLC_T_INT, "INT", &st.keep, 2, 1);
    add_located(&f, "%MW0", M "TOOL", 'M', 'W', PLC_T_INT, 0, &tool_p, 1);
    add_located(&f, "%MD1", M "DISTANCE", 'M', 'D', PLC_T_DINT, 1, &distance_p, 0);
    add_located(&f, "%ML0", M "BIG", 'M', 'L', PLC_T_LINT, 0, &big_p, 0);
    /* %QW5, %MW76-77, the high word of %MD1 only, the four words of %ML0 */
    const char *registers = "5,1100-1101,2050,4096-4099";

    new_dir(dir, file);
    reset_storage();
    runtime_t *rt = start(&f.prog, file, registers, 200, &rc);
    REQUIRE_INT(rc, 0);
    char *dump = NULL;
    size_t len = 0;
    FILE *out = open_memstream(&dump, &len);
    REQUIRE(out != NULL);
    CHECK_INT(retain_describe(rt, out), 0);
    fclose(out);
    CHECK_STR(dump, "retain\t" M "KEEP\tINT\t-\t2\n"
                    "retain\t%QW5\tWORD\t%QW5\t2\n"
                    "retain\t" M "TOOL\tINT\t%MW0\t2\n"
                    "retain\t%MW76\tWORD\t%MW76\t2\n"
                    "retain\t%MW77\tWORD\t%MW77\t2\n"
                    "retain\tHR2050\tWORD\tHR2050\t2\n"                 /* a part of DISTANCE: its own entry */
                    "retain\t" M "BIG\tLINT\t%ML0\t8\n"                 /* every register of BIG: one entry */
                    "located\t%MW0\t" M "TOOL\tINT\tRETAIN\n"
                    "located\t%MD1\t" M "DISTANCE\tDINT\t-\n"
                    "located\t%ML0\t" M "BIG\tLINT\t-\n");
    free(dump);
    rt->pimg.qw[5] = 0x0505;
    rt->pimg.mw[76] = 76;
    rt->pimg.mw[77] = 77;
    rt->pimg.mw[78] = 78;                                             /* not retained */
    rt->pimg.md[1].u = 0x12345678u;
    rt->pimg.ml[0].u = 0x0102030405060708u;
    stop(rt);

    reset_storage();
    rt = start(&f.prog, file, registers, 200, &rc);
    REQUIRE_INT(rc, 0);
    CHECK_UINT(rt->pimg.qw[5], 0x0505);
    CHECK(rt->pimg.mw[76] == 76 && rt->pimg.mw[77] == 77);
    CHECK_UINT(rt->pimg.mw[78], 0);
    CHECK_UINT(rt->pimg.md[1].u, 0x12340000u);                        /* only the retained high word */
    CHECK_UINT(rt->pimg.ml[0].u, 0x0102030405060708u);
    stop(rt);
}

static void without_retained_data_or_a_file_nothing_is_written(void)
{
    char dir[PATH_MAX], file[PATH_MAX], line[PATH_MAX + 80];
    fake_t f;
    int rc;
    size_t n;

    new_dir(dir, file);
    write_bytes(file, (const uint8_t *)"another program's", 17);
    begin(&f, 0);
    add_var(&f, M "SCRATCH", PLC_T_INT, "INT", &st.scratch, 2, 0);
    logcap_clear();
    runtime_t *rt = start(&f.prog, file, NULL, 200, &rc);
    CHECK_INT(rc, 0);
    CHECK(rt->retain == NULL);
    snprintf(line, sizeof line, "retain: the program has no RETAIN data; %s stays as it is", file);
    CHECK_INT(logcap_count(line), 1);
    uint8_t *kept = read_bytes(file, &n);
    if (CHECK(kept != NULL) && CHECK_UINT(n, 17))
        CHECK_MEM(kept, "another program's", 17);
    free(kept);
    retain_close(rt);                                                 /* no store: nothing to do */
    free(rt);

    logcap_clear();
    rt = start(program_small(&f, 0), NULL, NULL, 200, &rc);
    CHECK_INT(rc, 0);
    CHECK(rt->retain == NULL);
    CHECK_INT(logcap_count("retain: no retain file given; RETAIN values will not survive a restart"), 1);
    retain_after_scan(rt, SECOND);
    retain_close(rt);
    free(rt);
}

static void a_retain_file_in_a_missing_directory_stops_the_start(void)
{
    char dir[PATH_MAX], file[PATH_MAX], missing[PATH_MAX + 16], line[PATH_MAX + 120];
    fake_t f;
    int rc;

    new_dir(dir, file);
    snprintf(missing, sizeof missing, "%s/nope/plc.retain", dir);
    logcap_clear();
    runtime_t *rt = start(program_small(&f, 0), missing, NULL, 200, &rc);
    CHECK_INT(rc, -1);
    CHECK(rt->retain == NULL);
    snprintf(line, sizeof line, "error: retain: directory %s/nope of the retain file does not exist or is not "
             "writable", dir);
    CHECK_INT(logcap_count(line), 1);
    free(rt);
}

static const check_case_t cases[] = {
    CASE(crc32_is_the_ieee_crc),
    CASE(retained_values_survive_a_restart_by_path_and_type),
    CASE(a_damaged_file_is_named_set_aside_and_not_applied),
    CASE(a_torn_or_flipped_file_is_refused_at_every_byte),
    CASE(a_save_syncs_the_file_renames_it_then_syncs_the_directory),
    CASE(a_change_within_the_interval_waits_and_shutdown_saves_it),
    CASE(capture_takes_the_values_without_saving),
    CASE(a_failed_save_is_reported_once_and_the_last_good_file_stays),
    CASE(a_layout_change_keeps_what_matches_and_sets_the_rest_aside),
    CASE(going_back_to_the_earlier_version_restores_what_was_set_aside),
    CASE(a_file_of_format_version_1_is_read_once_when_its_layout_is_this_programs),
    CASE(a_second_owner_of_the_retain_file_is_refused),
    CASE(retained_registers_are_entries_named_by_path_or_address),
    CASE(without_retained_data_or_a_file_nothing_is_written),
    CASE(a_retain_file_in_a_missing_directory_stops_the_start),
};

CHECK_MAIN(cases)
