/*
 * plc_rt.h - support code that generated programs include (never hosts).
 *
 * Everything here reproduces OpenPLC's MATIEC semantics without C undefined
 * behaviour: integers wrap, `/` truncates, MOD 0 is 0, REAL_TO_INT rounds half
 * to even.  Where MATIEC is undefined (integer division by zero, index out of
 * bounds) we call plc_raise(), which the generated unit defines: it records a
 * fault and unwinds to the scan entry.
 */
#ifndef PLC_RT_H
#define PLC_RT_H

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "plc_abi.h"

#if defined(__GNUC__) || defined(__clang__)
#define PLC_UNUSED __attribute__((unused))
#else
#define PLC_UNUSED
#endif

/* Defined by the generated unit: records the fault at `site` and unwinds. */
static void plc_raise(int kind, int32_t site);

/* ----------------------------------------------------------------- integers -- */
/* Arithmetic on the unsigned type of the same width, then back: wraps, no UB.
 * 8- and 16-bit values are promoted to 32 bits first so products cannot
 * overflow `int`. */
#define PLC_ADD(T, U, a, b) ((T)(U)((uint64_t)(U)(a) + (uint64_t)(U)(b)))
#define PLC_SUB(T, U, a, b) ((T)(U)((uint64_t)(U)(a) - (uint64_t)(U)(b)))
#define PLC_MUL(T, U, a, b) ((T)(U)((uint64_t)(U)(a) * (uint64_t)(U)(b)))
#define PLC_NEG(T, U, a) ((T)(U)(0u - (uint64_t)(U)(a)))

#define PLC_DEFINE_DIV(NAME, T, MINV)                                              \
    static inline T plc_div_##NAME(T a, T b, int32_t site) {                       \
        if (b == 0) { plc_raise(PLC_FAULT_DIV_ZERO, site); return 0; }              \
        if ((MINV) != 0 && a == (T)(MINV) && b == (T)-1) return a;                  \
        return (T)(a / b);                                                          \
    }                                                                               \
    static inline T plc_mod_##NAME(T a, T b) {                                      \
        if (b == 0) return 0;                                                       \
        if ((MINV) != 0 && b == (T)-1) return 0;                                    \
        return (T)(a % b);                                                          \
    }

PLC_DEFINE_DIV(i8, int8_t, INT8_MIN)
PLC_DEFINE_DIV(i16, int16_t, INT16_MIN)
PLC_DEFINE_DIV(i32, int32_t, INT32_MIN)
PLC_DEFINE_DIV(i64, int64_t, INT64_MIN)
PLC_DEFINE_DIV(u8, uint8_t, 0)
PLC_DEFINE_DIV(u16, uint16_t, 0)
PLC_DEFINE_DIV(u32, uint32_t, 0)
PLC_DEFINE_DIV(u64, uint64_t, 0)

/* Array index: the zero-based offset, or a fault when out of bounds. */
static inline int64_t plc_idx(int64_t i, int64_t lo, int64_t hi, int32_t site) {
    if (i < lo || i > hi) { plc_raise(PLC_FAULT_INDEX, site); return 0; }
    return i - lo;
}

/* Shifts and rotations on unsigned bit strings of `bits` width. */
static inline uint64_t plc_mask(int bits) { return bits >= 64 ? ~(uint64_t)0 : (((uint64_t)1 << bits) - 1); }
static inline uint64_t plc_shl(uint64_t v, int64_t n, int bits) {
    if (n <= 0) return v & plc_mask(bits);
    return n >= bits ? 0 : (v << n) & plc_mask(bits);
}
static inline uint64_t plc_shr(uint64_t v, int64_t n, int bits) {
    if (n <= 0) return v & plc_mask(bits);
    return n >= bits ? 0 : (v & plc_mask(bits)) >> n;
}
static inline uint64_t plc_rol(uint64_t v, int64_t n, int bits) {
    v &= plc_mask(bits);
    n %= bits;
    if (n < 0) n += bits;
    if (n == 0) return v;
    return ((v << n) | (v >> (bits - n))) & plc_mask(bits);
}
static inline uint64_t plc_ror(uint64_t v, int64_t n, int bits) {
    v &= plc_mask(bits);
    n %= bits;
    if (n < 0) n += bits;
    if (n == 0) return v;
    return ((v >> n) | (v << (bits - n))) & plc_mask(bits);
}

/* ------------------------------------------------------------------- reals -- */
/* REAL/LREAL to an integer: round half to even (the default rounding mode),
 * then wrap into the destination type like MATIEC's C casts do on x86-64. */
static inline int64_t plc_real_to_i64(double x) {
    if (x != x) return 0;
    double r = nearbyint(x);
    if (r >= 9223372036854775807.0) return INT64_MAX;
    if (r <= -9223372036854775808.0) return INT64_MIN;
    return (int64_t)r;
}
static inline uint64_t plc_real_to_u64(double x) {
    if (x != x || x <= -1.0) return (uint64_t)plc_real_to_i64(x);
    double r = nearbyint(x);
    if (r >= 18446744073709551615.0) return UINT64_MAX;
    return (uint64_t)r;
}
static inline int64_t plc_trunc(double x) {
    if (x != x) return 0;
    if (x >= 9223372036854775807.0) return INT64_MAX;
    if (x <= -9223372036854775808.0) return INT64_MIN;
    return (int64_t)x;
}

/* TIME <-> numbers count seconds, as OpenPLC's MATIEC does. */
#define PLC_NS_PER_S 1000000000LL
static inline int64_t plc_time_to_int(int64_t t) { return t / PLC_NS_PER_S; }
static inline double plc_time_to_real(int64_t t) { return (double)t / 1e9; }
static inline int64_t plc_int_to_time(int64_t s) { return (int64_t)((uint64_t)s * (uint64_t)PLC_NS_PER_S); }
static inline int64_t plc_real_to_time(double s) { return plc_real_to_i64(s * 1e9); }
static inline int64_t plc_time_mul(int64_t t, double k) { return plc_real_to_i64((double)t * k); }
static inline int64_t plc_time_muli(int64_t t, int64_t k) { return (int64_t)((uint64_t)t * (uint64_t)k); }
static inline int64_t plc_time_divi(int64_t t, int64_t k, int32_t site) {
    if (k == 0) { plc_raise(PLC_FAULT_DIV_ZERO, site); return 0; }
    if (t == INT64_MIN && k == -1) return t;
    return t / k;
}
static inline int64_t plc_time_divr(int64_t t, double k) { return plc_real_to_i64((double)t / k); }
#define PLC_NS_PER_DAY 86400000000000LL
static inline int64_t plc_dt_to_tod(int64_t dt) { int64_t r = dt % PLC_NS_PER_DAY; return r < 0 ? r + PLC_NS_PER_DAY : r; }
static inline int64_t plc_dt_to_date(int64_t dt) { return dt - plc_dt_to_tod(dt); }

/* ----------------------------------------------------------------- strings -- */
static inline plc_string_t plc_str(const char *s, size_t n) {
    plc_string_t r;
    memset(&r, 0, sizeof r);
    if (n > PLC_STRING_MAX) n = PLC_STRING_MAX;
    r.len = (uint8_t)n;
    memcpy(r.body, s, n);
    r.body[n] = 0;
    return r;
}
static inline plc_string_t plc_str_empty(void) {
    plc_string_t r;
    memset(&r, 0, sizeof r);
    return r;
}
static inline plc_string_t plc_str_limit(plc_string_t s, size_t max) {
    if (s.len > max) { s.len = (uint8_t)max; s.body[max] = 0; }
    return s;
}
static inline int plc_str_cmp(plc_string_t a, plc_string_t b) {
    size_t n = a.len < b.len ? a.len : b.len;
    int c = memcmp(a.body, b.body, n);
    if (c != 0) return c;
    return (a.len > b.len) - (a.len < b.len);
}
static inline int16_t plc_len(plc_string_t s) { return (int16_t)s.len; }
static inline plc_string_t plc_concat(plc_string_t a, plc_string_t b) {
    size_t room = PLC_STRING_MAX - a.len;
    size_t n = b.len < room ? b.len : room;
    memcpy(a.body + a.len, b.body, n);
    a.len = (uint8_t)(a.len + n);
    a.body[a.len] = 0;
    return a;
}
static inline plc_string_t plc_left(plc_string_t s, int64_t l) {
    if (l < 0) l = 0;
    if (l < s.len) { s.len = (uint8_t)l; s.body[l] = 0; }
    return s;
}
static inline plc_string_t plc_right(plc_string_t s, int64_t l) {
    if (l < 0) l = 0;
    if (l >= s.len) return s;
    return plc_str(s.body + (s.len - l), (size_t)l);
}
static inline plc_string_t plc_mid(plc_string_t s, int64_t l, int64_t p) {
    if (p < 1 || p > s.len || l <= 0) return plc_str_empty();
    int64_t avail = s.len - (p - 1);
    return plc_str(s.body + (p - 1), (size_t)(l < avail ? l : avail));
}
static inline plc_string_t plc_insert(plc_string_t a, plc_string_t b, int64_t p) {
    if (p < 0) p = 0;
    if (p > a.len) p = a.len;
    return plc_concat(plc_concat(plc_left(a, p), b), plc_right(a, a.len - p));
}
static inline plc_string_t plc_delete(plc_string_t s, int64_t l, int64_t p) {
    if (p < 1 || p > s.len || l <= 0) return s;
    int64_t end = p - 1 + l;
    if (end > s.len) end = s.len;
    return plc_concat(plc_left(s, p - 1), plc_right(s, s.len - end));
}
static inline plc_string_t plc_replace(plc_string_t a, plc_string_t b, int64_t l, int64_t p) {
    return plc_insert(plc_delete(a, l, p), b, p < 1 ? 0 : p - 1);
}
static inline int16_t plc_find(plc_string_t a, plc_string_t b) {
    if (b.len == 0 || b.len > a.len) return 0;
    for (int i = 0; i + b.len <= a.len; i++)
        if (memcmp(a.body + i, b.body, b.len) == 0) return (int16_t)(i + 1);
    return 0;
}
static inline plc_string_t plc_str_i64(int64_t v) {
    char buf[32];
    int n = snprintf(buf, sizeof buf, "%lld", (long long)v);
    return plc_str(buf, (size_t)n);
}
static inline plc_string_t plc_str_u64(uint64_t v) {
    char buf[32];
    int n = snprintf(buf, sizeof buf, "%llu", (unsigned long long)v);
    return plc_str(buf, (size_t)n);
}
/* Bit strings print as OpenPLC's MATIEC prints them: lower-case hex, no padding ("16#beef"). */
static inline plc_string_t plc_str_hex(uint64_t v, int bits) {
    char buf[40];
    (void)bits;
    int n = snprintf(buf, sizeof buf, "16#%llx", (unsigned long long)v);
    return plc_str(buf, (size_t)n);
}
/* REAL and LREAL both print with ten significant digits, as MATIEC does. */
static inline plc_string_t plc_str_real(double v) {
    char buf[48];
    int n = snprintf(buf, sizeof buf, "%.10g", v);
    return plc_str(buf, (size_t)n);
}
static inline plc_string_t plc_str_lreal(double v) { return plc_str_real(v); }
static inline plc_string_t plc_str_bool(int v) { return v ? plc_str("TRUE", 4) : plc_str("FALSE", 5); }
/* TIME in MATIEC's format: T#<d>d<h>h<m>m<s>s<ms>ms, ending after the last
 * non-zero part (T#0d, T#0d1h, T#0d0h0m1s500ms); every part is a truncated
 * quotient, so a negative time carries its sign on each part, as in MATIEC. */
static inline plc_string_t plc_str_time(int64_t t) {
    char buf[96];
    long long sec = (long long)(t / PLC_NS_PER_S), ns = (long long)(t % PLC_NS_PER_S);
    long long d = sec / 86400, rem = sec % 86400;
    long long h = rem / 3600, m = rem % 3600 / 60, s = rem % 60;
    int n;
    if (rem == 0 && ns == 0)
        n = snprintf(buf, sizeof buf, "T#%lldd", d);
    else if (rem % 3600 == 0 && ns == 0)
        n = snprintf(buf, sizeof buf, "T#%lldd%lldh", d, h);
    else if (s == 0 && ns == 0)
        n = snprintf(buf, sizeof buf, "T#%lldd%lldh%lldm", d, h, m);
    else if (ns == 0)
        n = snprintf(buf, sizeof buf, "T#%lldd%lldh%lldm%llds", d, h, m, s);
    else
        n = snprintf(buf, sizeof buf, "T#%lldd%lldh%lldm%llds%gms", d, h, m, s, (double)ns / 1e6);
    return plc_str(buf, (size_t)n);
}
/* Civil date (proleptic Gregorian) of a day number counted from 1970-01-01. */
static inline void plc_civil(int64_t days, long long *y, int *mo, int *dd) {
    int64_t z = days + 719468;
    int64_t era = (z >= 0 ? z : z - 146096) / 146097;
    int64_t doe = z - era * 146097;                                  /* 0..146096 */
    int64_t yoe = (doe - doe / 1460 + doe / 36524 - doe / 146096) / 365;
    int64_t doy = doe - (365 * yoe + yoe / 4 - yoe / 100);          /* 0..365, from March 1st */
    int64_t mp = (5 * doy + 2) / 153;
    *dd = (int)(doy - (153 * mp + 2) / 5 + 1);
    *mo = (int)(mp < 10 ? mp + 3 : mp - 9);
    *y = (long long)(yoe + era * 400 + (*mo <= 2));
}
/* "HH:MM:SS", or "HH:MM:SS.ffffff" when there is a fraction (MATIEC's format). */
static inline int plc_fmt_tod(char *buf, size_t size, int64_t ns_of_day) {
    long long sec = (long long)(ns_of_day / PLC_NS_PER_S), frac = (long long)(ns_of_day % PLC_NS_PER_S);
    if (frac == 0)
        return snprintf(buf, size, "%02lld:%02lld:%02lld", sec / 3600, sec / 60 % 60, sec % 60);
    return snprintf(buf, size, "%02lld:%02lld:%09.6f", sec / 3600, sec / 60 % 60, (double)(sec % 60) + (double)frac / 1e9);
}
static inline plc_string_t plc_str_tod(int64_t t) {
    char buf[64];
    int n = snprintf(buf, sizeof buf, "TOD#");
    n += plc_fmt_tod(buf + n, sizeof buf - (size_t)n, plc_dt_to_tod(t));
    return plc_str(buf, (size_t)n);
}
static inline plc_string_t plc_str_date(int64_t t) {
    char buf[64];
    long long y;
    int mo, dd;
    plc_civil((plc_dt_to_date(t) / PLC_NS_PER_DAY), &y, &mo, &dd);
    int n = snprintf(buf, sizeof buf, "D#%04lld-%02d-%02d", y, mo, dd);
    return plc_str(buf, (size_t)n);
}
static inline plc_string_t plc_str_dt(int64_t t) {
    char buf[80];
    long long y;
    int mo, dd;
    plc_civil((plc_dt_to_date(t) / PLC_NS_PER_DAY), &y, &mo, &dd);
    int n = snprintf(buf, sizeof buf, "DT#%04lld-%02d-%02d-", y, mo, dd);
    n += plc_fmt_tod(buf + n, sizeof buf - (size_t)n, plc_dt_to_tod(t));
    return plc_str(buf, (size_t)n);
}
static inline int64_t plc_str_to_i64(plc_string_t s) { return strtoll(s.body, NULL, 10); }
static inline uint64_t plc_str_to_u64(plc_string_t s) { return strtoull(s.body, NULL, 10); }
static inline double plc_str_to_real(plc_string_t s) { return strtod(s.body, NULL); }
static inline int plc_str_to_bool(plc_string_t s) {
    return (s.len == 4 && (s.body[0] == 'T' || s.body[0] == 't')) || (s.len == 1 && s.body[0] == '1');
}

#endif /* PLC_RT_H */
