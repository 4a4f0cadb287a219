/*
 * varpath.c - a variable path resolved to storage, values parsed and shown.
 *
 * The program's variable table names every variable of every instance (FB
 * internals included) down to the aggregates; below that, struct fields and
 * array elements are found from the table's full type name
 * ("ARRAY[1..40] OF ST_SEQSTEP{OPCODE:E_SEQOPCODE(OPEND,...);LINE:INT;...}"),
 * laid out with the C rules the generated code is compiled with (each member
 * at its natural alignment, a struct padded to its largest member).  The
 * layout computed for a table entry must give the size the generated code
 * reports (sizeof), or the path below it is refused: a wrong offset is never
 * read or written.
 */
#define _GNU_SOURCE
#include <ctype.h>
#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "monitor.h"

/* --------------------------------------------------------- elementary */

typedef struct elem_type {
    const char *name;
    uint16_t type;
    uint32_t size;
    uint32_t align;
} elem_type_t;

static const elem_type_t elem_types[] = {
    { "BOOL", PLC_T_BOOL, 1, 1 },   { "SINT", PLC_T_SINT, 1, 1 },   { "INT", PLC_T_INT, 2, 2 },
    { "DINT", PLC_T_DINT, 4, 4 },   { "LINT", PLC_T_LINT, 8, 8 },   { "USINT", PLC_T_USINT, 1, 1 },
    { "UINT", PLC_T_UINT, 2, 2 },   { "UDINT", PLC_T_UDINT, 4, 4 }, { "ULINT", PLC_T_ULINT, 8, 8 },
    { "BYTE", PLC_T_BYTE, 1, 1 },   { "WORD", PLC_T_WORD, 2, 2 },   { "DWORD", PLC_T_DWORD, 4, 4 },
    { "LWORD", PLC_T_LWORD, 8, 8 }, { "REAL", PLC_T_REAL, 4, 4 },   { "LREAL", PLC_T_LREAL, 8, 8 },
    { "TIME", PLC_T_TIME, 8, 8 },   { "DATE", PLC_T_DATE, 8, 8 },   { "TOD", PLC_T_TOD, 8, 8 },
    { "TIME_OF_DAY", PLC_T_TOD, 8, 8 }, { "DT", PLC_T_DT, 8, 8 },   { "DATE_AND_TIME", PLC_T_DT, 8, 8 },
    { "STRING", PLC_T_STRING, sizeof(plc_string_t), 1 },
};

static const elem_type_t *elem_by_name(const char *s, size_t n)
{
    for (size_t i = 0; i < sizeof elem_types / sizeof elem_types[0]; i++)
        if (strlen(elem_types[i].name) == n && strncmp(elem_types[i].name, s, n) == 0)
            return &elem_types[i];
    return NULL;
}

static uint32_t elem_size(uint16_t type)
{
    for (size_t i = 0; i < sizeof elem_types / sizeof elem_types[0]; i++)
        if (elem_types[i].type == type)
            return elem_types[i].size;
    return type == PLC_T_ENUM ? 4 : 0;
}

/* ------------------------------------------------------------ layouts */

/* One type in a type name: where it starts and ends, what it is. */
typedef struct tdesc {
    const char *s, *end;
    enum { TD_ELEM, TD_ENUM, TD_ARRAY, TD_STRUCT } kind;
    uint16_t type;
    uint32_t size, align;
    /* arrays */
    int ndims;
    long lo[4], hi[4];
    const char *elem;            /* element type text */
    /* structs: fields between '{' and '}' */
    const char *fields;
} tdesc_t;

static int parse_type(const char *s, tdesc_t *t);

static size_t ident_len(const char *s)
{
    size_t n = 0;
    while (isalnum((unsigned char)s[n]) || s[n] == '_')
        n++;
    return n;
}

/* The end of a balanced group that opens at *s ('(' '[' '{'). */
static const char *skip_group(const char *s)
{
    int depth = 0;
    for (; *s; s++) {
        if (*s == '(' || *s == '[' || *s == '{')
            depth++;
        else if (*s == ')' || *s == ']' || *s == '}') {
            if (--depth == 0)
                return s + 1;
        }
    }
    return NULL;
}

static uint32_t round_up(uint32_t v, uint32_t a)
{
    return a ? (v + a - 1) / a * a : v;
}

/* Walk the fields of a struct: calls back with each field's name, type and offset.
 * Returns 0 after the last field, 1 when the callback stopped the walk, -1 on a bad name. */
typedef int (*field_fn)(void *ctx, const char *name, size_t nlen, const tdesc_t *ft, uint32_t offset);

static int walk_fields(const tdesc_t *t, field_fn fn, void *ctx, uint32_t *size, uint32_t *align)
{
    const char *p = t->fields;
    uint32_t off = 0, al = 1;

    while (p < t->end - 1) {
        size_t n = ident_len(p);
        if (n == 0 || p[n] != ':')
            return -1;
        tdesc_t ft;
        if (parse_type(p + n + 1, &ft) != 0)
            return -1;
        off = round_up(off, ft.align);
        if (fn && fn(ctx, p, n, &ft, off))
            return 1;
        off += ft.size;
        if (ft.align > al)
            al = ft.align;
        p = ft.end;
        if (*p == ';')
            p++;
        else if (p != t->end - 1)
            return -1;
    }
    if (size)
        *size = round_up(off, al);
    if (align)
        *align = al;
    return 0;
}

static int parse_type(const char *s, tdesc_t *t)
{
    memset(t, 0, sizeof *t);
    t->s = s;
    if (strncmp(s, "ARRAY[", 6) == 0) {
        const char *p = s + 6;
        t->kind = TD_ARRAY;
        for (;;) {
            char *end;
            if (t->ndims >= 4)
                return -1;
            t->lo[t->ndims] = strtol(p, &end, 10);
            if (end == p || strncmp(end, "..", 2) != 0)
                return -1;
            p = end + 2;
            t->hi[t->ndims] = strtol(p, &end, 10);
            if (end == p || t->hi[t->ndims] < t->lo[t->ndims])
                return -1;
            t->ndims++;
            p = end;
            if (*p == ',') {
                p++;
                continue;
            }
            if (*p != ']')
                return -1;
            p++;
            break;
        }
        if (strncmp(p, " OF ", 4) != 0)
            return -1;
        t->elem = p + 4;
        tdesc_t et;
        if (parse_type(t->elem, &et) != 0)
            return -1;
        uint64_t count = 1;
        for (int i = 0; i < t->ndims; i++)
            count *= (uint64_t)(t->hi[i] - t->lo[i] + 1);
        if (count * et.size > UINT32_MAX)
            return -1;
        t->size = (uint32_t)(count * et.size);
        t->align = et.align;
        t->end = et.end;
        return 0;
    }
    size_t n = ident_len(s);
    if (n == 0)
        return -1;
    if (s[n] == '(') {                  /* E_NAME(A,B,C) */
        t->kind = TD_ENUM;
        t->type = PLC_T_ENUM;
        t->size = t->align = 4;
        t->end = skip_group(s + n);
        return t->end ? 0 : -1;
    }
    if (s[n] == '{') {                  /* ST_NAME{F:T;...} */
        t->kind = TD_STRUCT;
        t->fields = s + n + 1;
        t->end = skip_group(s + n);
        if (!t->end)
            return -1;
        return walk_fields(t, NULL, NULL, &t->size, &t->align) == 0 ? 0 : -1;
    }
    const elem_type_t *e = elem_by_name(s, n);
    if (!e)
        return -1;
    t->kind = TD_ELEM;
    t->type = e->type;
    t->size = e->size;
    t->align = e->align;
    t->end = s + n;
    return 0;
}

/* ------------------------------------------------------------ resolve */

static void upcase(char *dst, const char *src, size_t n)
{
    size_t i = 0;
    for (; src[i] && i + 1 < n; i++)
        dst[i] = (char)toupper((unsigned char)src[i]);
    dst[i] = 0;
}

/* Does table path p equal the start of want, ending there at a boundary? */
static size_t prefix_match(const char *p, const char *want)
{
    size_t n = strlen(p);
    if (strncmp(p, want, n) != 0)
        return 0;
    return (want[n] == 0 || want[n] == '.' || want[n] == '[') ? n : 0;
}

struct field_find { const char *name; size_t nlen; tdesc_t found; uint32_t offset; bool ok; };

static int find_field(void *ctx, const char *name, size_t nlen, const tdesc_t *ft, uint32_t offset)
{
    struct field_find *f = ctx;
    if (nlen == f->nlen && strncmp(name, f->name, nlen) == 0) {
        f->found = *ft;
        f->offset = offset;
        f->ok = true;
        return 1;
    }
    return 0;
}

static void fill_from_desc(var_ref_t *out, const tdesc_t *t)
{
    out->type_name = t->s;
    out->type_len = (size_t)(t->end - t->s);
    out->type = (t->kind == TD_ELEM || t->kind == TD_ENUM) ? t->type : PLC_T_OTHER;
    out->size = t->size;
}

/* Apply ".FIELD" and "[i,j]" selectors in rest to the value described by *t at out->addr. */
static int select_path(var_ref_t *out, tdesc_t t, const char *rest, char *err, size_t errlen)
{
    while (*rest) {
        if (*rest == '.') {
            if (t.kind != TD_STRUCT) {
                snprintf(err, errlen, "'%s' has no fields: '%s' cannot be selected", out->path, rest);
                return -1;
            }
            struct field_find f = { rest + 1, ident_len(rest + 1), { 0 }, 0, false };
            if (f.nlen == 0 || walk_fields(&t, find_field, &f, NULL, NULL) < 0 || !f.ok) {
                snprintf(err, errlen, "'%s' has no field '%.*s'", out->path, (int)(f.nlen ? f.nlen : 1), rest + 1);
                return -1;
            }
            out->addr = (uint8_t *)out->addr + f.offset;
            size_t len = strlen(out->path);
            snprintf(out->path + len, sizeof out->path - len, ".%.*s", (int)f.nlen, rest + 1);
            rest += 1 + f.nlen;
            t = f.found;
        } else if (*rest == '[') {
            if (t.kind != TD_ARRAY) {
                snprintf(err, errlen, "'%s' is not an array: '%s' cannot be selected", out->path, rest);
                return -1;
            }
            const char *p = rest + 1;
            tdesc_t et;
            if (parse_type(t.elem, &et) != 0)
                goto bad_type;
            uint64_t index = 0;
            size_t len = strlen(out->path);
            snprintf(out->path + len, sizeof out->path - len, "[");
            for (int d = 0; d < t.ndims; d++) {
                char *end;
                errno = 0;
                long i = strtol(p, &end, 10);
                if (end == p || errno) {
                    snprintf(err, errlen, "'%s': expected %d index(es) like [%ld] in '%s'", out->path, t.ndims,
                             t.lo[d], rest);
                    return -1;
                }
                if (i < t.lo[d] || i > t.hi[d]) {
                    *strrchr(out->path, '[') = 0;
                    snprintf(err, errlen, "index %ld outside %ld..%ld of '%s'", i, t.lo[d], t.hi[d], out->path);
                    return -1;
                }
                index = index * (uint64_t)(t.hi[d] - t.lo[d] + 1) + (uint64_t)(i - t.lo[d]);
                len = strlen(out->path);
                snprintf(out->path + len, sizeof out->path - len, "%s%ld", d ? "," : "", i);
                p = end;
                if (d + 1 < t.ndims) {
                    if (*p != ',') {
                        snprintf(err, errlen, "'%s' has %d dimensions: give %d indexes", out->path, t.ndims,
                                 t.ndims);
                        return -1;
                    }
                    p++;
                }
            }
            if (*p != ']') {
                snprintf(err, errlen, "'%s': expected ']' in '%s'", out->path, rest);
                return -1;
            }
            len = strlen(out->path);
            snprintf(out->path + len, sizeof out->path - len, "]");
            out->addr = (uint8_t *)out->addr + index * et.size;
            rest = p + 1;
            t = et;
        } else {
            snprintf(err, errlen, "cannot read '%s' after '%s'", rest, out->path);
            return -1;
        }
    }
    fill_from_desc(out, &t);
    return 0;
bad_type:
    snprintf(err, errlen, "the layout of '%s' cannot be read from its type", out->path);
    return -1;
}

static int resolve_table_var(const plc_var_t *v, const char *rest, var_ref_t *out, char *err, size_t errlen)
{
    tdesc_t t;

    out->addr = v->addr;
    out->size = v->size;
    out->type = v->type;
    out->constant = v->constant;
    out->located = false;
    out->type_name = v->type_name;
    out->type_len = v->type_name ? strlen(v->type_name) : 0;
    snprintf(out->path, sizeof out->path, "%s", v->path);
    if (!v->type_name || parse_type(v->type_name, &t) != 0 || t.size != v->size || *t.end != 0) {
        if (*rest) {
            snprintf(err, errlen, "the layout of '%s' (%s) is not known to the runtime: its parts cannot be "
                     "addressed", v->path, v->type_name ? v->type_name : "?");
            return -1;
        }
        if (v->type == PLC_T_OTHER) {
            snprintf(err, errlen, "the layout of '%s' (%s) is not known to the runtime", v->path,
                     v->type_name ? v->type_name : "?");
            return -1;
        }
        return 0;
    }
    return select_path(out, t, rest, err, errlen);
}

static const char *located_type_name(uint16_t type)
{
    for (size_t i = 0; i < sizeof elem_types / sizeof elem_types[0]; i++)
        if (elem_types[i].type == type)
            return elem_types[i].name;
    return NULL;
}

static int resolve_located(const plc_located_t *l, var_ref_t *out, char *err, size_t errlen)
{
    out->addr = *l->ptr;
    out->type = l->type;
    out->size = elem_size(l->type);
    out->constant = false;
    out->located = true;
    out->area = l->area;
    out->type_name = located_type_name(l->type);
    out->type_len = out->type_name ? strlen(out->type_name) : 0;
    snprintf(out->path, sizeof out->path, "%s", l->var);
    if (out->size == 0 || out->addr == NULL) {
        snprintf(err, errlen, "located variable %s (%s) has a type the monitor cannot show", l->var, l->address);
        return -1;
    }
    return 0;
}

int varpath_resolve(const plc_program_t *prog, const char *path, var_ref_t *out, char *err, size_t errlen)
{
    char want[VP_PATH_MAX];
    size_t n = strlen(path);

    memset(out, 0, sizeof *out);
    if (n == 0 || n >= sizeof want) {
        snprintf(err, errlen, "a variable path has 1 to %zu characters", sizeof want - 1);
        return -1;
    }
    for (size_t i = 0; i < n; i++) {
        unsigned char c = (unsigned char)path[i];
        if (!isalnum(c) && !strchr("_.[],%-", c)) {
            snprintf(err, errlen, "character '%c' cannot appear in a variable path", isprint(c) ? c : '?');
            return -1;
        }
    }
    upcase(want, path, sizeof want);

    if (want[0] == '%') {                         /* a located address */
        for (uint32_t i = 0; i < prog->n_located; i++)
            if (strcmp(prog->located[i].address, want) == 0)
                return resolve_located(&prog->located[i], out, err, errlen);
        snprintf(err, errlen, "no located variable at %s", want);
        return -1;
    }

    /* Exact paths first (the longest table entry the path starts with), then a
     * unique entry whose path ends with the one given. */
    const plc_var_t *best = NULL;
    size_t best_len = 0;
    for (uint32_t i = 0; i < prog->n_vars; i++) {
        size_t m = prefix_match(prog->vars[i].path, want);
        if (m > best_len) {
            best = &prog->vars[i];
            best_len = m;
        }
    }
    for (uint32_t i = 0; i < prog->n_located; i++)
        if (prog->located[i].var && strcmp(prog->located[i].var, want) == 0)
            return resolve_located(&prog->located[i], out, err, errlen);
    if (best)
        return resolve_table_var(best, want + best_len, out, err, errlen);

    /* suffix: "ATC.MACHINE.ROTARY.TARGET" for "CONFIG0.RES0.ATC.MACHINE.ROTARY.TARGET" */
    const plc_var_t *hit = NULL;
    size_t hit_len = 0;
    int ties = 0;
    for (uint32_t i = 0; i < prog->n_vars; i++) {
        for (const char *dot = strchr(prog->vars[i].path, '.'); dot; dot = strchr(dot + 1, '.')) {
            size_t m = prefix_match(dot + 1, want);
            if (m == 0)
                continue;
            if (m > hit_len) {
                hit = &prog->vars[i];
                hit_len = m;
                ties = 1;
            } else if (m == hit_len) {
                ties++;
            }
            break;
        }
    }
    const plc_located_t *lhit = NULL;
    for (uint32_t i = 0; i < prog->n_located; i++) {
        const char *dot = prog->located[i].var ? strchr(prog->located[i].var, '.') : NULL;
        for (; dot; dot = strchr(dot + 1, '.'))
            if (strcmp(dot + 1, want) == 0) {
                if (lhit || (hit && hit_len == strlen(want)))
                    ties = 2;
                lhit = &prog->located[i];
                break;
            }
    }
    if (ties > 1) {
        snprintf(err, errlen, "'%s' names more than one variable: give the full path (CONFIG.RESOURCE.INSTANCE...)",
                 path);
        return -1;
    }
    if (lhit)
        return resolve_located(lhit, out, err, errlen);
    if (hit)
        return resolve_table_var(hit, want + hit_len, out, err, errlen);
    snprintf(err, errlen, "unknown variable '%s'", path);
    return -1;
}

/* -------------------------------------------------------------- values */

/* The enum's n-th name, or its index when it has none; *names set to the list. */
static int enum_index(const var_ref_t *ref, const char *text, long *out)
{
    const char *p = ref->type_name ? strchr(ref->type_name, '(') : NULL;
    const char *end = ref->type_name + ref->type_len;
    long i = 0;
    size_t tn = strlen(text);

    if (!p || p > end)
        return -1;
    p++;
    while (p < end) {
        size_t n = ident_len(p);
        if (n == tn && strncasecmp(p, text, n) == 0) {
            *out = i;
            return 0;
        }
        p += n;
        if (*p != ',')
            break;
        p++;
        i++;
    }
    return -1;
}

static int enum_name(const var_ref_t *ref, long v, const char **name, size_t *len)
{
    const char *p = ref->type_name ? strchr(ref->type_name, '(') : NULL;
    const char *end = ref->type_name + ref->type_len;
    if (!p || p > end || v < 0)
        return -1;
    p++;
    for (long i = 0; p < end; i++) {
        size_t n = ident_len(p);
        if (i == v) {
            *name = p;
            *len = n;
            return 0;
        }
        p += n;
        if (*p != ',')
            break;
        p++;
    }
    return -1;
}

/* TIME literal: T#1h2m3s4ms, TIME#..., or a plain number of milliseconds. */
static int parse_time(const char *text, int64_t *ns)
{
    const char *p = text;
    double total = 0;
    bool neg = false;

    if (strncasecmp(p, "TIME#", 5) == 0)
        p += 5;
    else if (strncasecmp(p, "T#", 2) == 0)
        p += 2;
    else {
        char *end;
        double ms = strtod(text, &end);
        if (end == text || *end || !isfinite(ms))
            return -1;
        *ns = (int64_t)llround(ms * 1e6);
        return 0;
    }
    if (*p == '-') {
        neg = true;
        p++;
    }
    if (!*p)
        return -1;
    while (*p) {
        char *end;
        double v = strtod(p, &end);
        if (end == p)
            return -1;
        p = end;
        double unit;
        if (strncasecmp(p, "ms", 2) == 0) { unit = 1e6; p += 2; }
        else if (strncasecmp(p, "us", 2) == 0) { unit = 1e3; p += 2; }
        else if (strncasecmp(p, "ns", 2) == 0) { unit = 1; p += 2; }
        else if (*p == 'd' || *p == 'D') { unit = 86400e9; p++; }
        else if (*p == 'h' || *p == 'H') { unit = 3600e9; p++; }
        else if (*p == 'm' || *p == 'M') { unit = 60e9; p++; }
        else if (*p == 's' || *p == 'S') { unit = 1e9; p++; }
        else return -1;
        total += v * unit;
        if (*p == '_')
            p++;
    }
    if (!isfinite(total) || fabs(total) > 9.2e18)
        return -1;
    *ns = (int64_t)llround(neg ? -total : total);
    return 0;
}

static int parse_int(const char *text, long long lo, long long hi, long long *out)
{
    char *end;
    int base = 10;
    const char *p = text;

    if (strncmp(p, "16#", 3) == 0) { base = 16; p += 3; }
    else if (strncmp(p, "2#", 2) == 0) { base = 2; p += 2; }
    else if (strncmp(p, "8#", 2) == 0) { base = 8; p += 2; }
    errno = 0;
    long long v = strtoll(p, &end, base);
    if (end == p || *end || errno || v < lo || v > hi)
        return -1;
    *out = v;
    return 0;
}

static int parse_uint(const char *text, unsigned long long hi, unsigned long long *out)
{
    char *end;
    int base = 10;
    const char *p = text;

    if (*p == '-')
        return -1;
    if (strncmp(p, "16#", 3) == 0) { base = 16; p += 3; }
    else if (strncmp(p, "2#", 2) == 0) { base = 2; p += 2; }
    else if (strncmp(p, "8#", 2) == 0) { base = 8; p += 2; }
    errno = 0;
    unsigned long long v = strtoull(p, &end, base);
    if (end == p || *end || errno || v > hi)
        return -1;
    *out = v;
    return 0;
}

int varpath_parse_value(const var_ref_t *ref, const char *text, uint8_t *buf, char *err, size_t errlen)
{
    const char *tn = located_type_name(ref->type);
    long long i;
    unsigned long long u;

    memset(buf, 0, VP_VALUE_MAX);
    switch (ref->type) {
    case PLC_T_BOOL:
        if (!strcasecmp(text, "TRUE") || !strcmp(text, "1"))
            buf[0] = 1;
        else if (!strcasecmp(text, "FALSE") || !strcmp(text, "0"))
            buf[0] = 0;
        else
            goto bad;
        return 0;
    case PLC_T_SINT:
        if (parse_int(text, INT8_MIN, INT8_MAX, &i)) goto bad_range;
        *(int8_t *)buf = (int8_t)i; return 0;
    case PLC_T_INT:
        if (parse_int(text, INT16_MIN, INT16_MAX, &i)) goto bad_range;
        { int16_t v = (int16_t)i; memcpy(buf, &v, 2); } return 0;
    case PLC_T_DINT:
        if (parse_int(text, INT32_MIN, INT32_MAX, &i)) goto bad_range;
        { int32_t v = (int32_t)i; memcpy(buf, &v, 4); } return 0;
    case PLC_T_LINT:
        if (parse_int(text, INT64_MIN, INT64_MAX, &i)) goto bad_range;
        { int64_t v = (int64_t)i; memcpy(buf, &v, 8); } return 0;
    case PLC_T_USINT: case PLC_T_BYTE:
        if (parse_uint(text, UINT8_MAX, &u)) goto bad_range;
        buf[0] = (uint8_t)u; return 0;
    case PLC_T_UINT: case PLC_T_WORD:
        if (parse_uint(text, UINT16_MAX, &u)) goto bad_range;
        { uint16_t v = (uint16_t)u; memcpy(buf, &v, 2); } return 0;
    case PLC_T_UDINT: case PLC_T_DWORD:
        if (parse_uint(text, UINT32_MAX, &u)) goto bad_range;
        { uint32_t v = (uint32_t)u; memcpy(buf, &v, 4); } return 0;
    case PLC_T_ULINT: case PLC_T_LWORD:
        if (parse_uint(text, UINT64_MAX, &u)) goto bad_range;
        memcpy(buf, &u, 8); return 0;
    case PLC_T_REAL: case PLC_T_LREAL: {
        char *end;
        double d = strtod(text, &end);
        if (end == text || *end || !isfinite(d))
            goto bad;
        if (ref->type == PLC_T_REAL) {
            float f = (float)d;
            if (!isfinite(f))
                goto bad_range;
            memcpy(buf, &f, 4);
        } else {
            memcpy(buf, &d, 8);
        }
        return 0;
    }
    case PLC_T_TIME: {
        int64_t ns;
        if (parse_time(text, &ns))
            goto bad;
        memcpy(buf, &ns, 8);
        return 0;
    }
    case PLC_T_ENUM: {
        long idx;
        const char *name;
        size_t len;
        if (enum_index(ref, text, &idx) != 0 && parse_int(text, 0, INT32_MAX, &i) == 0
                && enum_name(ref, (long)i, &name, &len) == 0)
            idx = (long)i;
        else if (enum_index(ref, text, &idx) != 0)
            idx = -1;
        if (idx >= 0) {
            int32_t v = (int32_t)idx;
            memcpy(buf, &v, 4);
            return 0;
        }
        snprintf(err, errlen, "'%s' is not a value of %.*s", text, (int)ref->type_len, ref->type_name);
        return -1;
    }
    case PLC_T_STRING: {
        size_t n = strlen(text);
        if (n > PLC_STRING_MAX) {
            snprintf(err, errlen, "a STRING holds at most %d characters", PLC_STRING_MAX);
            return -1;
        }
        plc_string_t *s = (plc_string_t *)buf;
        s->len = (uint8_t)n;
        memcpy(s->body, text, n);
        return 0;
    }
    default:
        snprintf(err, errlen, "'%s' is a %s: only elementary values can be written (a field or an element of it "
                 "can)", ref->path, ref->type == PLC_T_OTHER ? "struct or array" : "value of this type");
        return -1;
    }
bad:
    snprintf(err, errlen, "'%s' is not a valid %s value", text, tn ? tn : "valid");
    return -1;
bad_range:
    snprintf(err, errlen, "'%s' is not a valid %s value (a number in its range)", text, tn ? tn : "valid");
    return -1;
}

/* ------------------------------------------------------------ to JSON */

typedef struct jbuf { char *p; size_t n, k; bool full; } jbuf_t;

static void jput(jbuf_t *j, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void jput(jbuf_t *j, const char *fmt, ...)
{
    va_list ap;
    if (j->full)
        return;
    va_start(ap, fmt);
    int w = vsnprintf(j->p + j->k, j->n - j->k, fmt, ap);
    va_end(ap);
    if (w < 0 || (size_t)w >= j->n - j->k)
        j->full = true;
    else
        j->k += (size_t)w;
}

static void jstring(jbuf_t *j, const char *s, size_t n)
{
    jput(j, "\"");
    for (size_t i = 0; i < n; i++) {
        unsigned char c = (unsigned char)s[i];
        if (c == '"' || c == '\\')
            jput(j, "\\%c", c);
        else if (c < 0x20 || c >= 0x7f)
            jput(j, "\\u%04x", c);
        else
            jput(j, "%c", c);
    }
    jput(j, "\"");
}

static void format_elem(jbuf_t *j, uint16_t type, const char *type_name, size_t type_len, const uint8_t *d)
{
    switch (type) {
    case PLC_T_BOOL: jput(j, "%s", d[0] ? "true" : "false"); break;
    case PLC_T_SINT: jput(j, "%d", *(const int8_t *)d); break;
    case PLC_T_USINT: case PLC_T_BYTE: jput(j, "%u", d[0]); break;
    case PLC_T_INT: { int16_t v; memcpy(&v, d, 2); jput(j, "%d", v); break; }
    case PLC_T_UINT: case PLC_T_WORD: { uint16_t v; memcpy(&v, d, 2); jput(j, "%u", v); break; }
    case PLC_T_DINT: { int32_t v; memcpy(&v, d, 4); jput(j, "%" PRId32, v); break; }
    case PLC_T_UDINT: case PLC_T_DWORD: { uint32_t v; memcpy(&v, d, 4); jput(j, "%" PRIu32, v); break; }
    case PLC_T_LINT: { int64_t v; memcpy(&v, d, 8); jput(j, "%" PRId64, v); break; }
    case PLC_T_ULINT: case PLC_T_LWORD: { uint64_t v; memcpy(&v, d, 8); jput(j, "%" PRIu64, v); break; }
    case PLC_T_REAL: { float v; memcpy(&v, d, 4); if (isfinite(v)) jput(j, "%.9g", v); else jput(j, "null"); break; }
    case PLC_T_LREAL: { double v; memcpy(&v, d, 8); if (isfinite(v)) jput(j, "%.17g", v); else jput(j, "null"); break; }
    case PLC_T_TIME: { int64_t v; memcpy(&v, d, 8); jput(j, "\"T#%.6gms\"", (double)v / 1e6); break; }
    case PLC_T_DATE: case PLC_T_TOD: case PLC_T_DT: { int64_t v; memcpy(&v, d, 8); jput(j, "%" PRId64, v); break; }
    case PLC_T_STRING: {
        const plc_string_t *s = (const plc_string_t *)d;
        jstring(j, s->body, s->len > PLC_STRING_MAX ? PLC_STRING_MAX : s->len);
        break;
    }
    case PLC_T_ENUM: {
        int32_t v;
        memcpy(&v, d, 4);
        var_ref_t r = { .type_name = type_name, .type_len = type_len };
        const char *name;
        size_t len;
        if (enum_name(&r, v, &name, &len) == 0)
            jstring(j, name, len);
        else
            jput(j, "%" PRId32, v);
        break;
    }
    default: jput(j, "null"); break;
    }
}

static void format_desc(jbuf_t *j, const tdesc_t *t, const uint8_t *d);

struct field_fmt { jbuf_t *j; const uint8_t *d; bool first; };

static int format_field(void *ctx, const char *name, size_t nlen, const tdesc_t *ft, uint32_t offset)
{
    struct field_fmt *f = ctx;
    jput(f->j, "%s", f->first ? "" : ",");
    f->first = false;
    jstring(f->j, name, nlen);
    jput(f->j, ":");
    format_desc(f->j, ft, f->d + offset);
    return f->j->full;
}

static void format_desc(jbuf_t *j, const tdesc_t *t, const uint8_t *d)
{
    if (t->kind == TD_ELEM || t->kind == TD_ENUM) {
        format_elem(j, t->type, t->s, (size_t)(t->end - t->s), d);
    } else if (t->kind == TD_ARRAY) {
        tdesc_t et;
        uint64_t count = 1;
        if (parse_type(t->elem, &et) != 0) {
            jput(j, "null");
            return;
        }
        for (int i = 0; i < t->ndims; i++)
            count *= (uint64_t)(t->hi[i] - t->lo[i] + 1);
        jput(j, "[");
        for (uint64_t i = 0; i < count && !j->full; i++) {
            jput(j, "%s", i ? "," : "");
            format_desc(j, &et, d + i * et.size);
        }
        jput(j, "]");
    } else {
        struct field_fmt f = { j, d, true };
        jput(j, "{");
        walk_fields(t, format_field, &f, NULL, NULL);
        jput(j, "}");
    }
}

int varpath_format_json(const var_ref_t *ref, const uint8_t *data, char *out, size_t n)
{
    jbuf_t j = { out, n, 0, false };
    tdesc_t t;

    if (n == 0)
        return -1;
    out[0] = 0;
    if (ref->type != PLC_T_OTHER) {
        format_elem(&j, ref->type, ref->type_name, ref->type_len, data);
    } else if (ref->type_name && parse_type(ref->type_name, &t) == 0) {
        format_desc(&j, &t, data);
    } else {
        jput(&j, "null");
    }
    return j.full ? -1 : (int)j.k;
}
