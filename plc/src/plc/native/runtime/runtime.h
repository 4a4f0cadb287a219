/*
 * runtime.h - the soft-PLC runtime's own declarations.
 *
 * One runtime struct (runtime_t) is built by main.c and passed explicitly to
 * every part; nothing below keeps state in globals.  The parts and their jobs:
 *
 *   scan_core.c      the one scan core shared with `plc test` and the test
 *                    driver: input latch, forced values, tasks, publication
 *   image.c          the two I/O images (program side and Modbus side), the
 *                    OpenPLC address map, host writes applied between scans
 *   scan.c           the periodic scan loop around the core, its clock and
 *                    its statistics
 *   modbus_server.c  Modbus/TCP server thread on libmodbus
 *   retain.c         RETAIN variables saved atomically and restored at start
 *   io_sim.c/io_none.c/io_modbus.c  the physical side of the image, behind io_layer_t
 *                    (io_modbus.c: remote I/O devices polled by their own threads)
 *   watchdog.c       forces outputs safe when run() never returns
 *   realtime.c       priorities, priority-inheriting mutexes, lock-free wake-ups
 *                    (README, "Threads, priorities and locks")
 *   notify.c         tells a service manager (systemd) ready, alive, stopping
 *   log.c            log lines and the live status line
 *   monitor.c, force.c, varpath.c, events.c  watch, write and force over a
 *                    Unix socket; the application's events (monitor.h)
 *   main.c           options, start-up and orderly shutdown
 *
 * Data flow of one scan (scan_core.h):  io inputs -> program image <- host
 *   writes (queued) -> located variables latched -> forced values -> run(tick)
 *   -> located %Q/%M variables -> program image -> Modbus image (published)
 *   -> io outputs.
 */
#ifndef PLC_RUNTIME_H
#define PLC_RUNTIME_H

#include <pthread.h>
#include <semaphore.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>
#include <stddef.h>
#include <stdio.h>

#include "plc_abi.h"
#include "scan_core.h"

#define RT_NAME "plc-runtime"
#define RT_VERSION "0.1.0"

/* ------------------------------------------------------------ address map */

/* OpenPLC's address map (docs/openplc-addressing.md). */
#define MAP_BITS        PLC_MAP_BITS    /* %IX0.0..%IX99.7, %QX0.0..%QX99.7 */
/* %IX49.6: TRUE while any variable is forced (the monitor's `force`), set by the
 * runtime after the forces are laid on every scan: inputs are then not the
 * machine's, and the program must not believe them (docs/position-integrity.md). */
#define FORCES_ACTIVE_BIT 398
#define MAP_WORDS       PLC_MAP_WORDS   /* %IW, %QW, %MW, %MD, %ML: 1024 each */
#define MAP_HOLD_QW     0u      /* holding registers of %QW0.. */
#define MAP_HOLD_MW     1024u   /* holding registers of %MW0.. */
#define MAP_HOLD_MD     2048u   /* %MDn at 2048+2n (high word first) */
#define MAP_HOLD_ML     4096u   /* %MLn at 4096+4n (high word first) */
#define MAP_HOLDING     8192u   /* number of holding registers */

/*
 * Diagnostic block: input registers 1024..1087, just past %IW1023, so no
 * located variable of any program can overlap it (OpenPLC has no input
 * registers there).  32-bit values take two registers, 64-bit four, high word
 * first like %MD.  Times are microseconds.  See DIAG_* below for the layout.
 */
#define DIAG_BASE       1024u
#define DIAG_COUNT      64u

/*
 * I/O device block (--io modbus): input registers 1088.., IO_DIAG_WORDS per
 * remote I/O device in configuration order.  See IO_DIAG_* below.
 */
#define IO_MAX_DEVICES  16u
#define IO_DIAG_WORDS   8u
#define IO_DIAG_BASE    (DIAG_BASE + DIAG_COUNT)
#define MAP_INPUT_REGS  (IO_DIAG_BASE + IO_MAX_DEVICES * IO_DIAG_WORDS)

enum diag_offset {
    DIAG_VERSION = 0,          /* layout version, 1 */
    DIAG_STATE = 1,            /* plc_state_t */
    DIAG_FAULT_KIND = 2,       /* plc_fault_kind_t of the fault that stopped the program */
    DIAG_FAULT_LINE = 3,       /* source line of the fault (saturated to 65535) */
    DIAG_FAULT_COL = 4,        /* source column of the fault */
    DIAG_FLAGS = 5,            /* DIAG_FLAG_* bits */
    DIAG_BASE_TICK_US = 6,     /* u32: scan period */
    DIAG_SCAN_COUNT = 8,       /* u64: scans run since start */
    DIAG_SCAN_LAST_US = 12,    /* u32 each: scan (execution) time */
    DIAG_SCAN_MIN_US = 14,
    DIAG_SCAN_MAX_US = 16,
    DIAG_SCAN_MEAN_US = 18,
    DIAG_SCAN_P99_US = 20,
    DIAG_WAKE_LAST_US = 22,    /* u32 each: wake-up latency after the deadline */
    DIAG_WAKE_MIN_US = 24,
    DIAG_WAKE_MAX_US = 26,
    DIAG_WAKE_MEAN_US = 28,
    DIAG_WAKE_P99_US = 30,
    DIAG_OVERRUNS = 32,        /* u32: scans that ended after the next deadline */
    DIAG_CLIENTS = 34,         /* u16: Modbus clients connected */
    DIAG_REQUESTS = 36,        /* u32: Modbus requests answered */
    DIAG_EXCEPTIONS = 38,      /* u32: of those, exception responses */
    DIAG_REFUSED = 40,         /* u32: connections refused (allowlist, limit, TLS handshake or role) */
    DIAG_RETAIN_SAVES = 42,    /* u32: retain files written */
    DIAG_SCAN_P50_US = 44,     /* u32 */
    DIAG_WAKE_P50_US = 46,     /* u32 */
    DIAG_UPTIME_S = 48,        /* u32: seconds since the scan loop started */
    DIAG_SKIPPED = 50,         /* u32: deadlines skipped after long overruns */
    DIAG_APP_FAULT = 54,       /* i16: the application's latched fault code (events_fault), 0 = none */
    DIAG_WRITES = 56,          /* u32: Modbus write requests served */
    DIAG_WRITES_REFUSED = 58,  /* u32: Modbus write requests answered with an exception (role, read-only,
                                  a coil or register the client's role may not write, a bad value) */
    DIAG_DROPPED = 52          /* u32: connections the server closed (frame timeout, slow
                                  reader, slot reclaimed, not Modbus, socket error) */
};

enum io_diag_offset {
    IO_DIAG_STATE = 0,         /* io_device_state_t */
    IO_DIAG_LAST_ERROR = 1,    /* io_error_t of the last failed transaction */
    IO_DIAG_GOOD = 2,          /* u32: complete poll cycles */
    IO_DIAG_TIMEOUTS = 4,      /* u16 each (saturated): transactions with no answer in time */
    IO_DIAG_GARBAGE = 5,       /*   answers that were not valid Modbus (CRC, length, wrong unit...) */
    IO_DIAG_EXCEPTIONS = 6,    /*   Modbus exception answers */
    IO_DIAG_RECONNECTS = 7     /*   connections (re)opened */
};

typedef enum io_device_state {
    IO_DEVICE_UNUSED = 0,      /* no device configured at this index */
    IO_DEVICE_WAITING = 1,     /* configured, no complete input yet */
    IO_DEVICE_OK = 2,          /* inputs fresh (younger than its max age) */
    IO_DEVICE_LOST = 3         /* inputs too old: status input TRUE, its outputs safe */
} io_device_state_t;

typedef enum io_error {
    IO_ERROR_NONE = 0, IO_ERROR_TIMEOUT = 1, IO_ERROR_GARBAGE = 2, IO_ERROR_EXCEPTION = 3, IO_ERROR_CONNECTION = 4
} io_error_t;

#define DIAG_FLAG_REALTIME        0x0001u  /* scan thread runs SCHED_FIFO */
#define DIAG_FLAG_RETAIN_RESTORED 0x0002u  /* retained values restored at start */
#define DIAG_FLAG_RETAIN_REJECTED 0x0004u  /* retain file found but rejected */
#define DIAG_FLAG_RETAIN_ERROR    0x0008u  /* the last retain save failed */
#define DIAG_FLAG_SIM_IO          0x0010u  /* io layer is "sim" */
#define DIAG_FLAG_RETAIN_KEPT_ASIDE 0x0020u /* saved values this program does not use were kept aside */

typedef enum plc_state {
    PLC_STATE_STARTING = 0,
    PLC_STATE_RUNNING = 1,
    PLC_STATE_FAULTED = 2,     /* program stopped, outputs safe, Modbus serving */
    PLC_STATE_STOPPING = 3
} plc_state_t;

/* Fault kinds of the runtime's own, beyond plc_fault_kind_t. */
#define RT_FAULT_WATCHDOG 90   /* run() did not return within --watchdog ms */
#define RT_FAULT_UNKNOWN 99    /* run() returned a kind plc_fault_kind_t does not name */

/* ---------------------------------------------------------------- ranges */

/* A set of table addresses as a bitmap (host-writable ranges, retained). */
typedef struct addr_set {
    uint64_t bits[MAP_HOLDING / 64];
} addr_set_t;

static inline void addr_set_add(addr_set_t *s, unsigned a)
{
    s->bits[a / 64] |= (uint64_t)1 << (a % 64);
}

static inline bool addr_set_has(const addr_set_t *s, unsigned a)
{
    return (s->bits[a / 64] >> (a % 64)) & 1u;
}

/* Parse "400-799,1024,2048-4095" into *s; addresses must be < limit.
 * Returns 0, or -1 with a message in err. */
int addr_set_parse(addr_set_t *s, const char *text, unsigned limit, char *err, size_t errlen);

/* -------------------------------------------------------------- images */

/* The program's I/O image (scan_core.h): the core copies the located
 * variables in and out of it; only the scan thread touches it. */
typedef plc_image_t prog_image_t;

/* The Modbus view, guarded by runtime_t.lock.  `pending_*` hold host writes
 * not yet applied to the program; `dirty_*` say which. */
typedef struct bus_image {
    uint8_t coils[MAP_BITS];
    uint8_t discrete[MAP_BITS];
    uint16_t input_regs[MAP_INPUT_REGS];
    uint16_t holding[MAP_HOLDING];
    uint8_t pending_coils[MAP_BITS];
    uint16_t pending_holding[MAP_HOLDING];
    addr_set_t dirty_coils;
    addr_set_t dirty_holding;
    bool any_dirty;
} bus_image_t;

/* ------------------------------------------------------------- io layer */

/* The physical side of the image.  read_inputs() runs at the start of each
 * scan, write_outputs() at its end (with all-zero coils and words while the
 * program is stopped).  Both run on the scan thread and must not block for long. */
typedef struct runtime runtime_t;

typedef struct io_layer {
    const char *name;
    const char *description;
    int (*open)(runtime_t *rt, void **state, char *err, size_t errlen);
    void (*read_inputs)(void *state, plc_bool_t ix[MAP_BITS], uint16_t iw[MAP_WORDS]);
    void (*write_outputs)(void *state, const plc_bool_t qx[MAP_BITS], const uint16_t qw[MAP_WORDS]);
    void (*close)(void *state);
} io_layer_t;

extern const io_layer_t io_sim_layer;
extern const io_layer_t io_none_layer;
extern const io_layer_t io_modbus_layer;

/* Every I/O layer, found by name (--io NAME), as libmodbus finds its backends;
 * NULL-terminated.  A new layer is one entry here and one source file. */
extern const io_layer_t *const io_layers[];
const io_layer_t *io_layer_find(const char *name);

/* -------------------------------------------------------------- options */

#define RT_MAX_ALLOW 32

/* What a Modbus client may write, decided at accept time from its address (--allow ADDR[/BITS][=ROLE]). */
typedef enum client_role {
    ROLE_READ,       /* no write function code served: exception 01 */
    ROLE_HOST,       /* the host command ranges only (--host-coils, --host-registers) */
    ROLE_ENGINEER    /* every writable coil and register (--writable-coils, --writable-registers) */
} client_role_t;

const char *role_name(client_role_t role);

typedef struct allow_entry {
    uint32_t addr;   /* host byte order */
    uint32_t mask;
    client_role_t role;
} allow_entry_t;

typedef enum status_mode { STATUS_AUTO, STATUS_TTY, STATUS_LOG, STATUS_OFF } status_mode_t;

typedef struct rt_options {
    char bind[64];
    int port;                      /* 0: any free port (logged) */
    const io_layer_t *io;
    const char *retain_path;       /* NULL: RETAIN not persisted */
    int retain_interval_ms;        /* minimum time between two saves */
    addr_set_t retain_registers;   /* holding registers saved with RETAIN */
    bool have_retain_registers;
    allow_entry_t allow[RT_MAX_ALLOW];
    int n_allow;                   /* 0: any client */
    int max_clients;
    int frame_timeout_ms;          /* a request begun must be complete within this */
    bool read_only;                /* every write function code answered with exception 01 */
    addr_set_t writable_coils;     /* what an engineer may write */
    addr_set_t writable_registers;
    addr_set_t host_coils;         /* what a host may write: within the writable sets */
    addr_set_t host_registers;
    bool realtime;
    int rt_priority;
    int cpu;                       /* the scan thread's CPU (--cpu; -1: not pinned) */
    int cpu_latency_us;            /* PM QoS limit on the CPUs' idle exit latency (--cpu-latency; -1: none) */
    status_mode_t status;
    double status_interval_s;      /* log-line status period when not on a TTY */
    double duration_s;             /* stop after this long (0: run until signalled) */
    int watchdog_ms;               /* longest run() call allowed (0: no watchdog) */
    bool describe_retain;          /* print the retained entries and exit */
    const char *io_devices[IO_MAX_DEVICES];   /* --io-device SPEC, for --io modbus (io_modbus.c) */
    int n_io_devices;
    const char *monitor_path;      /* Unix socket of the monitoring channel (NULL: none) */
    const char *monitor_token_file;    /* file holding the token that unlocks writes (NULL: read-only) */
    const char *audit_path;        /* every write and force appended here (NULL: log only) */
    const char *events_path;       /* description the application's events read (--events; NULL: none) */
    int sim_flag_bit;              /* --sim-flag %IXa.b: the discrete input the sim layer raises (-1: none) */
    /* Modbus/TCP Security (MBAPS): a TLS listener beside the plain one, on when tls_cert is given */
    const char *tls_cert;          /* the server's certificate (PEM, chain allowed) */
    const char *tls_key;           /* its private key (PEM) */
    const char *tls_ca;            /* the CA(s) a client's certificate must be signed by (PEM) */
    char tls_bind[64];             /* default: --bind */
    int tls_port;                  /* default 802; 0: any free port (logged) */
} rt_options_t;

/* ------------------------------------------------------------ statistics */

/* Log-linear histogram of nanosecond values (<1% relative error). */
#define HIST_SUB_BITS 7u
#define HIST_LINEAR (2u << HIST_SUB_BITS)           /* 256 exact buckets */
#define HIST_BUCKETS (HIST_LINEAR + 33u * (1u << HIST_SUB_BITS))

typedef struct histogram {
    uint32_t count[HIST_BUCKETS];
    uint64_t n;
    uint64_t sum_ns;
    uint64_t min_ns;
    uint64_t max_ns;
    uint64_t last_ns;
} histogram_t;

void hist_add(histogram_t *h, uint64_t ns);
uint64_t hist_percentile(const histogram_t *h, double p);

typedef struct scan_stats {
    histogram_t scan;              /* execution time of a scan: input latch to the end of its work */
    histogram_t core;              /* of which the scan core: input latch to output publication */
    histogram_t run;               /* of which the program itself: the run() call */
    histogram_t wake;              /* wake-up latency after the deadline */
    uint64_t scans;
    uint32_t overruns;
    uint32_t skipped;
    uint64_t p50_scan_ns, p99_scan_ns, p50_wake_ns, p99_wake_ns;  /* refreshed periodically */
} scan_stats_t;

/* The live status line's figures (log.c), stored without a lock by the thread that owns each (scan,
 * watchdog, Modbus server) and read by the log thread, which never takes the image lock.  Relaxed: the
 * line is a display, each figure is whole, not the set. */
typedef struct live_status {
    atomic_uint state, fault_kind, fault_line;
    atomic_ullong scans;
    atomic_uint scan_last_us, scan_p99_us, scan_max_us, wake_p99_us, wake_max_us, overruns;
    atomic_uint clients, requests;
} live_status_t;

/* A wake-up the scan thread gives without a lock (realtime.c): a semaphore, not a condition variable. */
typedef struct rt_wake {
    sem_t sem;
} rt_wake_t;

#define RT_WAKE_NEVER UINT64_MAX   /* rt_wake_wait: no time limit */

/* ---------------------------------------------------------------- parts */

typedef struct log_sink log_sink_t;
typedef struct modbus_server modbus_server_t;
typedef struct retain_store retain_store_t;
typedef struct watchdog watchdog_t;
typedef struct notifier notifier_t;
typedef struct monitor monitor_t;           /* monitor.h */
typedef struct force_state force_state_t;   /* monitor.h */
typedef struct events events_t;             /* monitor.h */
typedef struct audit audit_t;

struct runtime {
    rt_options_t opt;
    int cpu_latency_fd;            /* /dev/cpu_dma_latency held open while running (-1: none) */
    const plc_program_t *prog;
    uint64_t period_ns;

    prog_image_t pimg;             /* scan thread only */
    plc_scan_t core;               /* the scan core bound to prog and pimg */

    pthread_mutex_t lock;          /* guards bimg; priority-inheriting (README, "Threads, priorities and locks") */
    bus_image_t bimg;

    void *io_state;
    pthread_mutex_t io_lock;       /* scan thread vs. watchdog at the I/O layer; priority-inheriting */
    log_sink_t *log;
    modbus_server_t *server;
    retain_store_t *retain;
    watchdog_t *watchdog;
    notifier_t *notify;            /* NULL when no service manager listens */
    monitor_t *monitor;            /* NULL without --monitor */
    force_state_t *force;          /* writes, forces, snapshots (with the monitor) */
    events_t *events;              /* NULL without --events */
    audit_t *audit;                /* NULL without --audit */
    plc_bool_t *forces_flag;       /* the program's variable at FORCES_ACTIVE_BIT, NULL if it has none */
    pthread_t scan_thread;
    uint64_t started_ns;           /* when the scan loop started (monotonic) */
    uint64_t refresh_every;        /* scans between two refreshes of the percentiles */
    _Atomic uint64_t run_started_ns;   /* when the current run() call began, 0 outside run() */
    atomic_bool watchdog_tripped;
    atomic_bool scan_lowered;      /* the watchdog lowered the stuck scan thread to SCHED_IDLE */

    atomic_int state;              /* plc_state_t; written by the scan thread only, read by others */
    live_status_t live;            /* the status line's figures */
    int32_t fault_kind;            /* why the program stopped (scan thread only) */
    int32_t fault_line, fault_col;
    scan_stats_t stats;            /* scan thread only; published to diag */
    uint16_t flags;                /* DIAG_FLAG_*, scan thread only */
};

/* image.c */
int image_bind_program(runtime_t *rt, char *err, size_t errlen);
void image_take_host_writes(runtime_t *rt);          /* caller holds rt->lock */
void image_publish(runtime_t *rt);                   /* caller holds rt->lock */
void image_publish_all(runtime_t *rt);               /* the whole image (start-up); caller holds rt->lock */
/* Safe state: every coil (%QX) FALSE.  %QW keep their last values in the image
 * (status words the host still needs, e.g. the tool in the spindle); the I/O
 * layer gets all-zero outputs, coils and words, while the program is stopped. */
void image_make_outputs_safe(prog_image_t *p);
void diag_put16(bus_image_t *b, unsigned off, uint16_t v);
void diag_put32(bus_image_t *b, unsigned off, uint32_t v);
void diag_put64(bus_image_t *b, unsigned off, uint64_t v);
uint32_t diag_get32(const bus_image_t *b, unsigned off);
uint64_t diag_get64(const bus_image_t *b, unsigned off);
/* Host writes, caller holds rt->lock and has checked the addresses. */
void image_host_write_coil(bus_image_t *b, unsigned addr, bool on);
void image_host_write_register(bus_image_t *b, unsigned addr, uint16_t v);
/* The program image's view of a holding register (for retain). */
uint16_t image_prog_holding(const prog_image_t *p, unsigned addr);
void image_prog_set_holding(prog_image_t *p, unsigned addr, uint16_t v);

/* realtime.c */
void rt_mutex_init(pthread_mutex_t *m);             /* priority-inheriting */
void rt_wake_init(rt_wake_t *w);
void rt_wake_destroy(rt_wake_t *w);
void rt_wake(rt_wake_t *w);                         /* never blocks: any thread, the scan's included */
void rt_wake_wait(rt_wake_t *w, uint64_t until_ns); /* until woken or monotonic until_ns; may return early */
void rt_thread_name(const char *name);              /* the calling thread's name, at most 15 characters */
/* With real-time scheduling on, the calling thread becomes SCHED_FIFO at the scan's priority + offset (1..99).
 * Returns the priority, 0 when real-time scheduling is off, or -errno when the kernel refused. */
int rt_thread_fifo(const runtime_t *rt, int offset);
void scan_setup_realtime(runtime_t *rt);            /* --cpu, --cpu-latency, then SCHED_FIFO: on the scan thread */
void scan_release_realtime(runtime_t *rt);          /* lets go of the --cpu-latency request */
bool scan_lower_stuck(runtime_t *rt);               /* the watchdog's: a SCHED_FIFO scan stuck in run() to SCHED_IDLE */
void scan_raise_again(runtime_t *rt);               /* the scan's, outside run(): SCHED_FIFO again if lowered */

/* scan.c */
int scan_run(runtime_t *rt);
uint64_t now_ns(void);

/* modbus_server.c */
#define MODBUS_AUDIT_PER_S 50u     /* Modbus write requests itemised in the audit file per second; the rest summed up */
/* 0 when the Modbus address can be bound now; -1 (logged) when not, e.g. the port is in use: checked before
 * anything is written, so a runtime that cannot serve leaves no retain file behind. */
int modbus_server_probe(runtime_t *rt);
/* 0 when there is no TLS listener or its certificate, key and CA load and match; -1 (logged, with the file)
 * when not.  Checked at start-up before anything is written, as the port. */
int modbus_server_check_tls(runtime_t *rt);
int modbus_server_start(runtime_t *rt, modbus_server_t **out);
void modbus_server_stop(modbus_server_t *srv);

/* retain.c */
int retain_open(runtime_t *rt, retain_store_t **out);   /* restores, starts the writer */
void retain_after_scan(runtime_t *rt, uint64_t now);    /* scan thread, never blocks */
void retain_capture(runtime_t *rt);                     /* take the current values, no save */
void retain_close(runtime_t *rt);                       /* final save, joins the writer */
uint32_t retain_saves(const retain_store_t *rs);
bool retain_last_failed(const retain_store_t *rs);
uint32_t crc32_update(uint32_t crc, const void *data, size_t len);
int retain_describe(runtime_t *rt, FILE *out);          /* the retained entries and located variables */
const char *plc_type_name(unsigned type);               /* "INT" for PLC_T_INT */

/* audit.c: the audit file (--audit); every function accepts NULL (no file: nothing written) */
int audit_open(runtime_t *rt, audit_t **out);           /* *out NULL without --audit */
void audit_line(audit_t *a, const char *fmt, ...) __attribute__((format(printf, 2, 3)));   /* never waits */
void audit_close(audit_t *a);                           /* writes what is queued */

/* watchdog.c */
int watchdog_start(runtime_t *rt, watchdog_t **out);
void watchdog_stop(watchdog_t *wd);

/* notify.c (every function accepts NULL: nobody to tell) */
int notify_open(runtime_t *rt, notifier_t **out);
void notify_send(notifier_t *n, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
void notify_after_scan(notifier_t *n, const runtime_t *rt, uint64_t now);   /* scan thread */
void notify_close(notifier_t *n);

/* log.c */
typedef enum log_level { LOG_INFO, LOG_WARN, LOG_ERROR } log_level_t;
int log_open(runtime_t *rt, log_sink_t **out);
void log_close(log_sink_t *ls);
void log_msg(log_sink_t *ls, log_level_t level, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

#endif /* PLC_RUNTIME_H */
