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
static inline plc_string_t plc_str_hex(uint64_t v, int bits) {
    char buf[40];
    int n = snprintf(buf, sizeof buf, "16#%0*llX", bits / 4, (unsigned long long)v);
    return plc_str(buf, (size_t)n);
}
static inline plc_string_t plc_str_real(double v) {
    char buf[48];
    int n = snprintf(buf, sizeof buf, "%.7g", v);
    return plc_str(buf, (size_t)n);
}
static inline plc_string_t plc_str_lreal(double v) {
    char buf[48];
    int n = snprintf(buf, sizeof buf, "%.15g", v);
    return plc_str(buf, (size_t)n);
}
static inline plc_string_t plc_str_bool(int v) { return v ? plc_str("TRUE", 4) : plc_str("FALSE", 5); }
static inline plc_string_t plc_str_time(int64_t t) {
    char buf[64];
    int n = 0;
    uint64_t a = t < 0 ? (uint64_t)0 - (uint64_t)t : (uint64_t)t;
    n += snprintf(buf + n, sizeof buf - (size_t)n, "T#%s", t < 0 ? "-" : "");
    uint64_t d = a / 86400000000000ULL, h = a / 3600000000000ULL % 24, m = a / 60000000000ULL % 60;
    uint64_t s = a / 1000000000ULL % 60, ms = a / 1000000ULL % 1000, us = a / 1000ULL % 1000, ns = a % 1000;
    if (d) n += snprintf(buf + n, sizeof buf - (size_t)n, "%llud", (unsigned long long)d);
    if (h) n += snprintf(buf + n, sizeof buf - (size_t)n, "%lluh", (unsigned long long)h);
    if (m) n += snprintf(buf + n, sizeof buf - (size_t)n, "%llum", (unsigned long long)m);
    if (s) n += snprintf(buf + n, sizeof buf - (size_t)n, "%llus", (unsigned long long)s);
    if (ms) n += snprintf(buf + n, sizeof buf - (size_t)n, "%llums", (unsigned long long)ms);
    if (us) n += snprintf(buf + n, sizeof buf - (size_t)n, "%lluus", (unsigned long long)us);
    if (ns) n += snprintf(buf + n, sizeof buf - (size_t)n, "%lluns", (unsigned long long)ns);
    if (a == 0) n += snprintf(buf + n, sizeof buf - (size_t)n, "0s");
    return plc_str(buf, (size_t)n);
}
static inline int64_t plc_str_to_i64(plc_string_t s) { return strtoll(s.body, NULL, 10); }
static inline uint64_t plc_str_to_u64(plc_string_t s) { return strtoull(s.body, NULL, 10); }
static inline double plc_str_to_real(plc_string_t s) { return strtod(s.body, NULL); }
static inline int plc_str_to_bool(plc_string_t s) {
    return (s.len == 4 && (s.body[0] == 'T' || s.body[0] == 't')) || (s.len == 1 && s.body[0] == '1');
}

#endif /* PLC_RT_H */
