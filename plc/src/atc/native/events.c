/*
 * events.c - what the toolchanger does, told on the runtime's log.
 *
 * The tool-changer application's events (monitor.h's events section): `plc
 * run` of the project links this file into the runtime in place of the
 * toolchain's events_none.c (atc.plugin, the toolchain's RunSetup.observer).
 * It writes a description of the register map (--events FILE): the
 * signals with their table, address and type, the state names of the coded
 * signals and the text of every reason code.  At the end of each scan the
 * scan thread reads the signals it knows by name from the program image
 * (a few dozen bytes, no lock) and compares them with the previous scan;
 * a change becomes a log line (the log thread writes it, the scan never waits):
 *
 *   tool change T3 -> T7 requested / done in 4.212 s / ended without completion
 *   prepare tool 7 (pocket 7) requested / done in 0.81 s / answered without pre-positioning
 *   fault -103 CHANGE_INTERRUPTED raised: <text> / cleared
 *   abort from the host: reason 8 TASK_ABORT
 *   E-stop: chain opened / released
 *   changer IDLE -> HOMING; carousel homed at pocket 1
 *   host link lost / restored; host left (its last heartbeat 65535: a clean exit)
 *   sequence PUT started / ended
 *   procedure 0 started / ended: DONE / ended: ERRORS (-201 SEQ_WAITIN_TIMEOUT) / failed... (user procedures)
 *
 * A signal the description lacks is simply not watched (an older map, or
 * OpenPLC's names): the runtime knows roles, the map says where they live.
 * The status line gets the tool in the spindle, the changer state by name and
 * the latched fault (events_status(), from atomics the scan thread sets).
 *
 * Description lines (tab-separated, '#' comments):
 *   signal NAME TABLE ADDRESS TYPE     TABLE: coil|discrete_input|input_register|holding_register
 *   state  NAME VALUE LABEL            names of a coded signal's values
 *   reason CODE NAME TEXT              reason_codes.toml
 */
#define _GNU_SOURCE
#include <inttypes.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "monitor.h"

enum role {
    R_TOOL_IN_SPINDLE, R_CHANGER_STATE, R_FAULT_REASON, R_TOOL_CHANGE, R_TOOL_CHANGED, R_TOOL_PREPARE,
    R_TOOL_PREPARED, R_PREP_NUMBER, R_PREP_POCKET, R_TOOL_NUMBER, R_EMC_ABORT, R_EMC_REASON, R_ESTOP_OK,
    R_HOST_LINK_OK, R_CAROUSEL_HOMED, R_CURRENT_POCKET, R_SEQ_KIND, R_IOV_STATE, R_SIMULATED_PLANT,
    R_SIM_ESTOP, R_RESTART_FIT, R_POCKET_COUNT, R_POCKET_TOOL1, R_UNCERTAIN_TOOL, R_HOST_HEARTBEAT,
    R_PROC_BUSY, R_PROC_ID, R_PROC_LAST_ID, R_PROC_LAST_RESULT, R_PROC_LAST_REASON, R_PROC_FAIL_COUNT,
    R_ESTOP_CLOSED,
    R_COUNT
};

static const char *const role_signal[R_COUNT] = {
    "ToolInSpindle", "ChangerState", "FaultReason", "ToolChange", "ToolChanged", "ToolPrepare",
    "ToolPrepared", "ToolPrepNumber", "ToolPrepPocket", "ToolNumber", "EmcAbort", "EmcReason", "EStopOk",
    "HostLinkOk", "CarouselHomed", "CurrentPocket", "SeqKind", "IovState", "SimulatedPlant", "SimEStop",
    "RestartFit", "PocketCount", "PocketTool1", "UncertainTool", "HostHeartbeat",
    "ProcBusy", "ProcId", "ProcLastId", "ProcLastResult", "ProcLastReason", "ProcFailCount",
    NULL,   /* derived: the E-stop chain as the application sees it */
};

/* LinuxCNC's emc-abort reasons (docs/iov2.md). */
static const struct { int code; const char *name; } cnc_reasons[] = {
    { 1, "TASK_EXEC_ERROR" }, { 2, "AUX_ESTOP" }, { 3, "MOTION_OR_IO_RCS_ERROR" }, { 4, "TASK_STATE_OFF" },
    { 5, "TASK_STATE_ESTOP_RESET" }, { 6, "TASK_STATE_ESTOP" }, { 7, "TASK_STATE_NOT_ON" }, { 8, "TASK_ABORT" },
    { 9, "INTERPRETER_ERROR" }, { 10, "INTERPRETER_ERROR_MDI" }, { 100, "USER" },
    { 101, "ABORT_BY_TOOLCHANGER_FAULT" },
};

#define EV_LINES_PER_S 20
#define MAX_STATES 32
#define MAX_REASONS 256
#define MAX_POCKETS 50
#define HOST_LEFT_BEAT 65535    /* the last heartbeat of a host that exits cleanly (atc.host.session.LEFT_BEAT) */          /* PocketTool1..50: consecutive holding registers from PocketTool1 */

/* RestartFit bits: what the application's first scan changed to fit the retained data to the machine
 * (FB_AtcChanger, README, "Retained data on another machine") */
enum { FIT_OTHER_SIZE = 1, FIT_DROPPED = 2, FIT_NEW_POCKETS = 4, FIT_NO_POCKET = 8 };

typedef struct watched {
    bool present;
    char table;                 /* 'c' coil, 'd' discrete input, 'i' input register, 'h' holding */
    unsigned addr;
    unsigned words;             /* 1 or 2 (registers) */
    bool is_signed, is_real;
    char *states[MAX_STATES];   /* labels by value */
} watched_t;

typedef struct reason { int code; char *name; char *text; } reason_t;

struct events {
    watched_t sig[R_COUNT];
    reason_t reasons[MAX_REASONS];
    unsigned n_reasons;

    /* the retained data as restored, before the first scan fits them to the machine (RestartFit) */
    int64_t saved_tool, saved_count, saved_pocket[MAX_POCKETS + 1];

    /* scan thread (primed: read by the log thread's status line too) */
    atomic_bool primed;
    int64_t prev[R_COUNT];
    uint64_t prepare_at, change_at;
    int64_t change_from, change_to;
    bool changed_seen;

    /* state and sequence lines: at most EV_LINES_PER_S a second (a state that flips every scan must not
     * flood the log); faults, E-stop, aborts, the link and tool changes are always told */
    uint64_t window_start;
    unsigned window_lines, suppressed;

    /* status line */
    atomic_int tool, state, fault;
    atomic_bool have_tool, have_state, have_fault;
};

static int64_t read_signal(const watched_t *w, const prog_image_t *p);

/* ---------------------------------------------------------- description */

static int role_of(const char *name)
{
    for (int r = 0; r < R_COUNT; r++)
        if (role_signal[r] && strcmp(role_signal[r], name) == 0)
            return r;
    return -1;
}

/* Split line at tabs into at most max fields (the last keeps any further tabs). */
static int split_tabs(char *line, char **f, int max)
{
    int n = 0;
    line[strcspn(line, "\r\n")] = 0;
    while (n < max) {
        f[n++] = line;
        if (n == max)
            break;
        char *tab = strchr(line, '\t');
        if (!tab)
            break;
        *tab = 0;
        line = tab + 1;
    }
    return n;
}

static int parse_signal(events_t *ev, char **f, int n, char *err, size_t errlen)
{
    char *end;
    if (n != 5) {
        snprintf(err, errlen, "signal: expected NAME TABLE ADDRESS TYPE");
        return -1;
    }
    int r = role_of(f[1]);
    if (r < 0)
        return 0;
    watched_t *w = &ev->sig[r];
    const char *table = f[2], *type = f[4];
    if (!strcmp(table, "coil")) w->table = 'c';
    else if (!strcmp(table, "discrete_input")) w->table = 'd';
    else if (!strcmp(table, "input_register")) w->table = 'i';
    else if (!strcmp(table, "holding_register")) w->table = 'h';
    else {
        snprintf(err, errlen, "signal %s: unknown table '%s'", f[1], table);
        return -1;
    }
    unsigned long addr = strtoul(f[3], &end, 10);
    unsigned limit = (w->table == 'c' || w->table == 'd') ? MAP_BITS : w->table == 'i' ? MAP_WORDS : MAP_HOLDING;
    w->words = (!strcmp(type, "DINT") || !strcmp(type, "UDINT") || !strcmp(type, "DWORD") || !strcmp(type, "REAL"))
               ? 2 : 1;
    if (end == f[3] || *end || addr + w->words > limit) {
        snprintf(err, errlen, "signal %s: address '%s' outside the %s table", f[1], f[3], table);
        return -1;
    }
    w->addr = (unsigned)addr;
    w->is_signed = !strcmp(type, "INT") || !strcmp(type, "DINT");
    w->is_real = !strcmp(type, "REAL");
    w->present = true;
    return 0;
}

static int parse_line(events_t *ev, char *line, char *err, size_t errlen)
{
    char *f[5];
    int n = split_tabs(line, f, 5);

    if (f[0][0] == 0 || f[0][0] == '#')
        return 0;
    if (!strcmp(f[0], "signal"))
        return parse_signal(ev, f, n, err, errlen);
    if (!strcmp(f[0], "state") && n == 4) {
        int r = role_of(f[1]);
        long v = strtol(f[2], NULL, 10);
        if (r >= 0 && v >= 0 && v < MAX_STATES && !ev->sig[r].states[v] && !(ev->sig[r].states[v] = strdup(f[3])))
            goto nomem;
        return 0;
    }
    if (!strcmp(f[0], "reason") && n == 4) {
        if (ev->n_reasons >= MAX_REASONS)
            return 0;
        reason_t *rs = &ev->reasons[ev->n_reasons];
        rs->code = (int)strtol(f[1], NULL, 10);
        rs->name = strdup(f[2]);
        rs->text = strdup(f[3]);
        ev->n_reasons++;
        if (!rs->name || !rs->text)
            goto nomem;
        return 0;
    }
    snprintf(err, errlen, "expected a signal, state or reason line");
    return -1;
nomem:
    snprintf(err, errlen, "out of memory");
    return -1;
}

int events_open(runtime_t *rt, const char *path, events_t **out)
{
    *out = NULL;
    if (!path)
        return 0;
    FILE *f = fopen(path, "r");
    if (!f) {
        log_msg(rt->log, LOG_ERROR, "events: cannot open %s: %m", path);
        return -1;
    }
    events_t *ev = calloc(1, sizeof *ev);
    if (!ev) {
        fclose(f);
        return -1;
    }
    char line[512], err[160];
    unsigned lineno = 0;
    while (fgets(line, sizeof line, f)) {
        lineno++;
        if (parse_line(ev, line, err, sizeof err) != 0) {
            log_msg(rt->log, LOG_ERROR, "events: %s:%u: %s", path, lineno, err);
            fclose(f);
            events_close(ev);
            return -1;
        }
    }
    fclose(f);
    /* the retained data are restored by now: keep what the first scan may drop, to tell it */
    ev->saved_tool = ev->sig[R_TOOL_IN_SPINDLE].present ? read_signal(&ev->sig[R_TOOL_IN_SPINDLE], &rt->pimg) : 0;
    ev->saved_count = ev->sig[R_POCKET_COUNT].present ? read_signal(&ev->sig[R_POCKET_COUNT], &rt->pimg) : 0;
    if (ev->sig[R_POCKET_TOOL1].present && ev->sig[R_POCKET_TOOL1].table == 'h'
            && ev->sig[R_POCKET_TOOL1].addr + MAX_POCKETS <= MAP_HOLDING)
        for (int n = 1; n <= MAX_POCKETS; n++) {
            watched_t w = ev->sig[R_POCKET_TOOL1];
            w.addr += (unsigned)(n - 1);
            ev->saved_pocket[n] = read_signal(&w, &rt->pimg);
        }
    unsigned watched = 0;
    for (int r = 0; r < R_COUNT; r++)
        watched += ev->sig[r].present;
    log_msg(rt->log, LOG_INFO, "events: %u of %d application signals watched, %u reason texts (%s)", watched,
            R_COUNT, ev->n_reasons, path);
    *out = ev;
    return 0;
}

void events_close(events_t *ev)
{
    if (!ev)
        return;
    for (int r = 0; r < R_COUNT; r++)
        for (int s = 0; s < MAX_STATES; s++)
            free(ev->sig[r].states[s]);
    for (unsigned i = 0; i < ev->n_reasons; i++) {
        free(ev->reasons[i].name);
        free(ev->reasons[i].text);
    }
    free(ev);
}

/* --------------------------------------------------------------- values */

static int64_t read_signal(const watched_t *w, const prog_image_t *p)
{
    switch (w->table) {
    case 'c': return p->qx[w->addr];
    case 'd': return p->ix[w->addr];
    case 'i': return w->is_signed ? (int16_t)p->iw[w->addr] : p->iw[w->addr];
    default: break;
    }
    uint32_t raw = image_prog_holding(p, w->addr);
    if (w->words == 2)
        raw = (raw << 16) | image_prog_holding(p, w->addr + 1);
    if (w->is_real) {
        float f;
        memcpy(&f, &raw, 4);
        return (int64_t)f;
    }
    if (w->words == 1)
        return w->is_signed ? (int16_t)raw : (int64_t)(uint16_t)raw;
    return w->is_signed ? (int32_t)raw : (int64_t)raw;
}

static const reason_t *reason_of(const events_t *ev, int64_t code)
{
    for (unsigned i = 0; i < ev->n_reasons; i++)
        if (ev->reasons[i].code == code)
            return &ev->reasons[i];
    return NULL;
}

static const char *cnc_reason(int64_t code)
{
    for (size_t i = 0; i < sizeof cnc_reasons / sizeof cnc_reasons[0]; i++)
        if (cnc_reasons[i].code == code)
            return cnc_reasons[i].name;
    return "?";
}

static const char *state_label(const events_t *ev, int role, int64_t v, char *buf, size_t n)
{
    if (v >= 0 && v < MAX_STATES && ev->sig[role].states[v])
        return ev->sig[role].states[v];
    snprintf(buf, n, "%" PRId64, v);
    return buf;
}

/* ------------------------------------------------------------ the scan */

static bool ev_budget(events_t *ev, runtime_t *rt, uint64_t now)
{
    if (now - ev->window_start >= 1000000000u) {
        if (ev->suppressed)
            log_msg(rt->log, LOG_WARN, "events: %u more application events in %.1f s not shown (at most %d lines "
                    "a second)", ev->suppressed, (double)(now - ev->window_start) / 1e9, EV_LINES_PER_S);
        ev->window_start = now;
        ev->window_lines = 0;
        ev->suppressed = 0;
    }
    if (ev->window_lines >= EV_LINES_PER_S) {
        ev->suppressed++;
        return false;
    }
    ev->window_lines++;
    return true;
}

#define EV_LOG(level, ...) do { if (ev_budget(ev, rt, now)) log_msg(log, level, __VA_ARGS__); } while (0)

#define HAS(r) (ev->sig[r].present)
#define ROSE(r) (HAS(r) && cur[r] && !ev->prev[r])
#define FELL(r) (HAS(r) && !cur[r] && ev->prev[r])
#define CHANGED(r) (HAS(r) && cur[r] != ev->prev[r])

/* The first scan fitted retained data saved on another machine (another pocket count) to this one: say what
 * it changed and what the operator has to do (README, "Retained data on another machine"). */
static void tell_restart_fit(const events_t *ev, log_sink_t *log, const int64_t *cur)
{
    int64_t fit = cur[R_RESTART_FIT], count = HAS(R_POCKET_COUNT) ? cur[R_POCKET_COUNT] : 0;
    if (fit & FIT_OTHER_SIZE) {
        if (ev->saved_count > 0)
            log_msg(log, LOG_WARN, "retained data: the pocket table was saved on a machine with %" PRId64
                    " pockets; this one has %" PRId64, ev->saved_count, count);
        else
            log_msg(log, LOG_WARN, "retained data: the pocket table was saved without its pocket count (an older "
                    "version) and does not fit this machine's %" PRId64 " pockets", count);
    }
    if ((fit & FIT_DROPPED) && count >= 1 && count < MAX_POCKETS) {
        char tools[256];
        size_t used = 0;
        int first = 0, last = 0;
        tools[0] = 0;
        for (int n = (int)count + 1; n <= MAX_POCKETS; n++) {
            if (!ev->saved_pocket[n])
                continue;
            first = first ? first : n;
            last = n;
            if (used >= sizeof tools - 32)
                continue;
            if (ev->saved_pocket[n] < 0)
                used += (size_t)snprintf(tools + used, sizeof tools - used, "%spocket %d: the uncertain tool",
                                         used ? ", " : "", n);
            else
                used += (size_t)snprintf(tools + used, sizeof tools - used, "%sT%" PRId64, used ? ", " : "",
                                         ev->saved_pocket[n]);
        }
        log_msg(log, LOG_WARN, "retained data: pockets %d..%d are not on this machine: what they held (%s) is "
                "dropped from the pocket table", first, last, tools);
    }
    if (fit & FIT_NEW_POCKETS)
        log_msg(log, LOG_INFO, "retained data: the pockets the saved table did not have start as on a first start "
                "(pocket n holds tool n, up to %" PRId64 ")", count);
    if (fit & FIT_NO_POCKET)
        log_msg(log, LOG_ERROR, "retained data: tool %" PRId64 " in the spindle has no pocket on this machine; "
                "every change is refused until the operator takes it out of the spindle and confirms an empty "
                "spindle (plc host confirm 0; Recovery %s)", ev->saved_tool,
                HAS(R_UNCERTAIN_TOOL) && cur[R_UNCERTAIN_TOOL] == ev->saved_tool ? "asks for it" : "?");
}

void events_after_scan(events_t *ev, runtime_t *rt, uint64_t now)
{
    int64_t cur[R_COUNT];
    char a[24], b[24];
    log_sink_t *log = rt->log;

    if (!ev)
        return;
    if (ev->suppressed && now - ev->window_start >= 1000000000u)
        ev_budget(ev, rt, now);                  /* tell what was left out once the flood is over */
    for (int r = 0; r < R_COUNT; r++)
        cur[r] = HAS(r) ? read_signal(&ev->sig[r], &rt->pimg) : 0;
    /* The simulated plant has no E-stop chain of its own: the SimEStop command opens it. */
    ev->sig[R_ESTOP_CLOSED].present = HAS(R_ESTOP_OK);
    cur[R_ESTOP_CLOSED] = (HAS(R_SIMULATED_PLANT) && cur[R_SIMULATED_PLANT]) ? !cur[R_SIM_ESTOP] : cur[R_ESTOP_OK];

    if (!atomic_load(&ev->primed)) {
        atomic_store(&ev->primed, true);
        memcpy(ev->prev, cur, sizeof cur);
        if (HAS(R_TOOL_IN_SPINDLE) || HAS(R_CHANGER_STATE))
            log_msg(log, LOG_INFO, "changer: tool %" PRId64 " in the spindle, state %s", cur[R_TOOL_IN_SPINDLE],
                    state_label(ev, R_CHANGER_STATE, cur[R_CHANGER_STATE], a, sizeof a));
        if (HAS(R_FAULT_REASON) && cur[R_FAULT_REASON]) {
            const reason_t *rs = reason_of(ev, cur[R_FAULT_REASON]);
            log_msg(log, LOG_ERROR, "fault %" PRId64 " %s latched: %s", cur[R_FAULT_REASON], rs ? rs->name : "?",
                    rs ? rs->text : "(not in reason_codes.toml)");
        }
        if (HAS(R_ESTOP_CLOSED) && !cur[R_ESTOP_CLOSED])
            log_msg(log, LOG_WARN, "E-stop: the E-stop chain is open");
        if (HAS(R_RESTART_FIT) && cur[R_RESTART_FIT])
            tell_restart_fit(ev, log, cur);
        goto publish;
    }

    if (FELL(R_ESTOP_CLOSED))
        log_msg(log, LOG_WARN, "E-stop: the E-stop chain opened (carousel outputs off)");
    if (ROSE(R_ESTOP_CLOSED))
        log_msg(log, LOG_INFO, "E-stop released: the E-stop chain is closed");
    /* A host that exits cleanly writes 65535 as its last heartbeat (a running one never does): it left. */
    if (FELL(R_HOST_LINK_OK) && HAS(R_HOST_HEARTBEAT) && cur[R_HOST_HEARTBEAT] == HOST_LEFT_BEAT)
        log_msg(log, LOG_INFO, "host left: its last heartbeat was %d (a clean exit)", HOST_LEFT_BEAT);
    else if (FELL(R_HOST_LINK_OK))
        log_msg(log, LOG_WARN, "host link lost: no heartbeat change from the host");
    if (ROSE(R_HOST_LINK_OK))
        log_msg(log, LOG_INFO, "host link restored");
    if (ROSE(R_EMC_ABORT))
        log_msg(log, LOG_WARN, "abort from the host: reason %" PRId64 " %s", cur[R_EMC_REASON],
                cnc_reason(cur[R_EMC_REASON]));

    if (ROSE(R_TOOL_PREPARE)) {
        ev->prepare_at = now;
        log_msg(log, LOG_INFO, "prepare tool %" PRId64 " (pocket %" PRId64 ") requested", cur[R_PREP_NUMBER],
                cur[R_PREP_POCKET]);
    }
    /* iov2 answers every prepare, a faulted changer's too: "done" only for one the changer saw complete */
    if (ROSE(R_TOOL_PREPARED) && ev->prepare_at) {
        const double took = (double)(now - ev->prepare_at) / 1e9;
        if (HAS(R_FAULT_REASON) && cur[R_FAULT_REASON]) {
            const reason_t *rs = reason_of(ev, cur[R_FAULT_REASON]);
            log_msg(log, LOG_WARN, "prepare tool %" PRId64 " answered after %.3f s without pre-positioning: fault %"
                    PRId64 " %s", cur[R_PREP_NUMBER], took, cur[R_FAULT_REASON], rs ? rs->name : "?");
        } else if (HAS(R_CAROUSEL_HOMED) && !cur[R_CAROUSEL_HOMED]) {
            log_msg(log, LOG_WARN, "prepare tool %" PRId64 " answered after %.3f s without pre-positioning: carousel "
                    "not homed", cur[R_PREP_NUMBER], took);
        } else {
            log_msg(log, LOG_INFO, "prepare tool %" PRId64 " done in %.3f s", cur[R_PREP_NUMBER], took);
        }
    }

    if (ROSE(R_TOOL_CHANGE)) {
        ev->change_at = now;
        ev->changed_seen = false;
        ev->change_from = cur[R_TOOL_IN_SPINDLE];
        ev->change_to = HAS(R_PREP_NUMBER) ? cur[R_PREP_NUMBER] : cur[R_TOOL_NUMBER];   /* M6 loads the prepared tool */
        log_msg(log, LOG_INFO, "tool change T%" PRId64 " -> T%" PRId64 " requested", ev->change_from, ev->change_to);
    }
    if (ROSE(R_TOOL_CHANGED) && ev->change_at) {
        ev->changed_seen = true;
        log_msg(log, LOG_INFO, "tool change T%" PRId64 " -> T%" PRId64 " done in %.3f s", ev->change_from,
                cur[R_TOOL_IN_SPINDLE], (double)(now - ev->change_at) / 1e9);
    }
    if (FELL(R_TOOL_CHANGE) && ev->change_at) {
        if (!ev->changed_seen)
            log_msg(log, LOG_WARN, "tool change T%" PRId64 " -> T%" PRId64 " ended without completion after %.3f s"
                    " (tool %" PRId64 " in the spindle)", ev->change_from, ev->change_to,
                    (double)(now - ev->change_at) / 1e9, cur[R_TOOL_IN_SPINDLE]);
        ev->change_at = 0;
    }

    if (CHANGED(R_FAULT_REASON)) {
        if (ev->prev[R_FAULT_REASON]) {
            const reason_t *was = reason_of(ev, ev->prev[R_FAULT_REASON]);
            log_msg(log, LOG_INFO, "fault %" PRId64 " %s cleared", ev->prev[R_FAULT_REASON], was ? was->name : "?");
        }
        if (cur[R_FAULT_REASON]) {
            const reason_t *rs = reason_of(ev, cur[R_FAULT_REASON]);
            log_msg(log, LOG_ERROR, "fault %" PRId64 " %s raised: %s", cur[R_FAULT_REASON], rs ? rs->name : "?",
                    rs ? rs->text : "(not in reason_codes.toml)");
        }
    }
    if (CHANGED(R_CHANGER_STATE)) {
        const char *from = state_label(ev, R_CHANGER_STATE, ev->prev[R_CHANGER_STATE], a, sizeof a);
        const char *to = state_label(ev, R_CHANGER_STATE, cur[R_CHANGER_STATE], b, sizeof b);
        EV_LOG(LOG_INFO, "changer %s -> %s", from, to);
        /* homing by the state's name (the map gives E_AtcState's names): always told */
        bool was = strcasestr(from, "homing") != NULL, is = strcasestr(to, "homing") != NULL;
        if (is && !was)
            log_msg(log, LOG_INFO, "homing started");
        if (was && !is)
            log_msg(log, HAS(R_CAROUSEL_HOMED) && !cur[R_CAROUSEL_HOMED] ? LOG_WARN : LOG_INFO,
                    "homing ended: carousel %s, pocket %" PRId64 " at the change position",
                    HAS(R_CAROUSEL_HOMED) && !cur[R_CAROUSEL_HOMED] ? "NOT homed" : "homed", cur[R_CURRENT_POCKET]);
    }
    if (ROSE(R_CAROUSEL_HOMED))
        EV_LOG(LOG_INFO, "homing done: carousel homed, pocket %" PRId64 " at the change position",
                cur[R_CURRENT_POCKET]);
    if (FELL(R_CAROUSEL_HOMED))
        EV_LOG(LOG_WARN, "carousel no longer homed (position unknown)");
    if (CHANGED(R_SEQ_KIND)) {
        if (ev->prev[R_SEQ_KIND])
            EV_LOG(LOG_INFO, "sequence %s ended",
                    state_label(ev, R_SEQ_KIND, ev->prev[R_SEQ_KIND], a, sizeof a));
        if (cur[R_SEQ_KIND])
            EV_LOG(LOG_INFO, "sequence %s started", state_label(ev, R_SEQ_KIND, cur[R_SEQ_KIND], b, sizeof b));
    }
    /* the user procedures (docs/procedures.md): start, failure (also one passed over), end with its result */
    if (ROSE(R_PROC_BUSY))
        log_msg(log, LOG_INFO, "procedure %" PRId64 " started", cur[R_PROC_ID]);
    if (CHANGED(R_PROC_FAIL_COUNT) && cur[R_PROC_FAIL_COUNT] > ev->prev[R_PROC_FAIL_COUNT]) {
        const reason_t *rs = reason_of(ev, cur[R_PROC_LAST_REASON]);
        int64_t id = cur[R_PROC_BUSY] ? cur[R_PROC_ID] : cur[R_PROC_LAST_ID];
        if (cur[R_PROC_BUSY])       /* passed over (stop_on_error false): the reason is not published yet */
            log_msg(log, LOG_WARN, "procedure %" PRId64 " failed a step and goes on", id);
        else
            log_msg(log, LOG_WARN, "procedure %" PRId64 " failed: reason %" PRId64 " %s", id,
                    cur[R_PROC_LAST_REASON], rs ? rs->name : "?");
    }
    if (FELL(R_PROC_BUSY)) {
        const reason_t *rs = reason_of(ev, cur[R_PROC_LAST_REASON]);
        char why[64] = "";
        if (cur[R_PROC_LAST_REASON])
            snprintf(why, sizeof why, " (%" PRId64 " %s)", cur[R_PROC_LAST_REASON], rs ? rs->name : "?");
        log_msg(log, cur[R_PROC_LAST_REASON] ? LOG_WARN : LOG_INFO, "procedure %" PRId64 " ended: %s%s",
                cur[R_PROC_LAST_ID], state_label(ev, R_PROC_LAST_RESULT, cur[R_PROC_LAST_RESULT], a, sizeof a), why);
    }
    memcpy(ev->prev, cur, sizeof cur);

publish:
    atomic_store(&ev->tool, (int)cur[R_TOOL_IN_SPINDLE]);
    atomic_store(&ev->state, (int)cur[R_CHANGER_STATE]);
    atomic_store(&ev->fault, (int)cur[R_FAULT_REASON]);
    atomic_store(&ev->have_tool, HAS(R_TOOL_IN_SPINDLE));
    atomic_store(&ev->have_state, HAS(R_CHANGER_STATE));
    atomic_store(&ev->have_fault, HAS(R_FAULT_REASON));
}

int events_fault(events_t *ev)
{
    return ev && atomic_load(&ev->have_fault) ? atomic_load(&ev->fault) : 0;
}

void events_status(events_t *ev, char *out, size_t n)
{
    int k = 0;

    if (n)
        out[0] = 0;
    if (!ev || !atomic_load(&ev->primed))
        return;
    if (atomic_load(&ev->have_tool))
        k += snprintf(out + k, n - (size_t)k, " | tool %d", atomic_load(&ev->tool));
    if (atomic_load(&ev->have_state) && k >= 0 && (size_t)k < n) {
        char a[24];
        k += snprintf(out + k, n - (size_t)k, " | changer %s",
                      state_label(ev, R_CHANGER_STATE, atomic_load(&ev->state), a, sizeof a));
    }
    if (atomic_load(&ev->have_fault) && k >= 0 && (size_t)k < n) {
        int f = atomic_load(&ev->fault);
        const reason_t *rs = f ? reason_of(ev, f) : NULL;
        if (f)
            snprintf(out + k, n - (size_t)k, " | fault %d %s", f, rs ? rs->name : "?");
        else
            snprintf(out + k, n - (size_t)k, " | no fault");
    }
}
