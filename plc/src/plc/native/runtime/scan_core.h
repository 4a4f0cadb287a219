/*
 * scan_core.h - the one scan core: what every host does around run().
 *
 * The soft-PLC runtime (scan.c), the `plc test` runner (stdlib/test_main.c)
 * and the conformance test driver (tests/scan_driver.c) all execute a program
 * through plc_scan_step(), so a test proves what the runtime will do.  Only
 * the clock and the outside world differ between them: the runtime passes the
 * real tick count and connects the I/O layer and the Modbus image, the test
 * hosts pass a simulated clock and direct I/O.
 *
 * One scan, in this order:
 *
 *   1. input latch     io.read_inputs() fills the I/O image from the world,
 *                      then every bound (located) input is copied from the
 *                      image into the program, and the bound %Q/%M variables
 *                      too when the world wrote them (host writes; the first
 *                      scan).  Nothing the world does after this point is
 *                      seen before the next scan.
 *   2. forced values   hooks.after_inputs(): forced inputs overwrite what was
 *                      latched.
 *   3. tasks due       *clock_ns is set, then run(tick) (or the host's own
 *                      runner) executes the tasks due on this base tick.
 *   4. output publication
 *                      hooks.before_outputs(): forced outputs overwrite what
 *                      the program wrote; then every bound %Q/%M variable is
 *                      copied from the program into the image (all coils
 *                      cleared instead while the program is stopped), and
 *                      io.write_outputs() hands the image to the world.
 *                      hooks.scan_done() closes the scan: program variables
 *                      and image agree, a consistent point for a snapshot.
 *
 * Only the program's located variables cross between the image and the
 * program; the copy is a precomputed table of (variable, slot, bytes).
 * The core has no threads, locks or clocks of its own: C99, libc only.
 */
#ifndef PLC_SCAN_CORE_H
#define PLC_SCAN_CORE_H

#include <stddef.h>
#include <stdint.h>

#include "plc_abi.h"

/* OpenPLC's address map (docs/openplc-addressing.md). */
#define PLC_MAP_BITS  800u      /* %IX0.0..%IX99.7, %QX0.0..%QX99.7 */
#define PLC_MAP_WORDS 1024u     /* %IW, %QW, %MW, %MD, %ML: 1024 each */

/* 32- and 64-bit memory slots: the program may store DINT, REAL, LINT, LREAL... */
typedef union { uint32_t u; int32_t i; float f; } plc_slot32_t;
typedef union { uint64_t u; int64_t i; double f; } plc_slot64_t;

/* The I/O image: what the world sees of the program, and the program of the world. */
typedef struct plc_image {
    plc_bool_t ix[PLC_MAP_BITS];
    plc_bool_t qx[PLC_MAP_BITS];
    uint16_t iw[PLC_MAP_WORDS];
    uint16_t qw[PLC_MAP_WORDS];
    uint16_t mw[PLC_MAP_WORDS];
    plc_slot32_t md[PLC_MAP_WORDS];
    plc_slot64_t ml[PLC_MAP_WORDS];
} plc_image_t;

/* One located variable bound to its image slot (24 bytes: the scan walks these, not the located table). */
typedef struct plc_binding {
    void *var;                     /* the program's storage (*located.ptr after init()) */
    void *slot;                    /* its place in the image */
    uint32_t size;                 /* bytes */
    uint32_t located;              /* its entry in prog->located */
} plc_binding_t;

/* The host's world: where inputs come from and outputs go.  Either may be NULL. */
typedef struct plc_scan_io {
    void *ctx;
    /* Returns nonzero when it also changed %Q or %M slots (host writes): the
     * latch then copies those into the program too, not only the inputs. */
    int (*read_inputs)(void *ctx, plc_image_t *image);
    /* running is 0 once the program has stopped (fault): outputs must be safe */
    void (*write_outputs)(void *ctx, plc_image_t *image, int running);
} plc_scan_io_t;

/*
 * Forcing and monitoring (the HMI): called at fixed points of every scan, on
 * the scan thread; each may be NULL (nothing forced, nobody watching).
 */
typedef struct plc_scan_hooks {
    void *ctx;
    void (*after_inputs)(void *ctx);                  /* apply forced inputs */
    void (*before_outputs)(void *ctx);                /* apply forced outputs */
    void (*scan_done)(void *ctx, uint64_t scan_no);   /* consistent snapshot point */
} plc_scan_hooks_t;

/* Runs the tasks due on `tick`; returns 0 or a fault kind (as plc_program_t.run). */
typedef int (*plc_scan_run_fn)(void *ctx, uint64_t tick);

typedef struct plc_scan {
    const plc_program_t *prog;
    plc_image_t *image;
    plc_binding_t *bindings;       /* inputs (%I) first, then %Q and %M */
    uint32_t n_bindings;
    uint32_t n_inputs;
    plc_scan_io_t io;
    plc_scan_hooks_t hooks;
    plc_scan_run_fn run;           /* NULL: prog->run */
    void *run_ctx;
    int latch_all;                 /* the next latch copies %Q/%M too (set by bind and restart) */
    uint64_t tick;                 /* base tick of the next scan */
    uint64_t scans;                /* scans completed */
    int fault;                     /* 0 while running; the fault kind once stopped */
} plc_scan_t;

/* Where a located variable lives in the image, or NULL (then *why says why:
 * the address is not on OpenPLC's Modbus map). */
void *plc_image_slot(plc_image_t *image, const plc_located_t *l, const char **why);

/* Bytes behind a located address of size 'X', 'B', 'W', 'D' or 'L' (0: unknown). */
unsigned plc_located_bytes(char size);

/* Called by plc_scan_bind() for each located variable that stays off the image. */
typedef void (*plc_unmapped_fn)(void *ctx, const plc_located_t *l, const char *why);

/*
 * Prepare `s` to run `prog` against `image`: call after every prog->init().
 * Each mapped located variable is bound to its slot and its initial value
 * copied into the image; variables of several PROGRAMs at one address are
 * pointed at one storage (the ABI's *ptr), as MATIEC shares them.  Returns 0, or -1 with a message in err (malformed entry,
 * a type whose size differs from the address's).  plc_scan_free() releases.
 */
int plc_scan_bind(plc_scan_t *s, const plc_program_t *prog, plc_image_t *image,
                  plc_unmapped_fn unmapped, void *unmapped_ctx, char *err, size_t errlen);
void plc_scan_free(plc_scan_t *s);

/* Start again from tick 0 after prog->init() (the bindings stay). */
void plc_scan_restart(plc_scan_t *s);

/* One whole scan at program time now_ns (the stages above).  Returns 0, or
 * the fault kind once the program has stopped (it then stays stopped). */
int plc_scan_step(plc_scan_t *s, int64_t now_ns);

/* The stages one by one, for hosts and tests that look between them;
 * plc_scan_step() is exactly these four calls. */
void plc_scan_latch_inputs(plc_scan_t *s);
void plc_scan_force_inputs(plc_scan_t *s);
/* Copies the located inputs as the program sees them (forced values included) back to their image
 * slots, so that every reader of the image sees what the program sees. */
void plc_scan_reflect_inputs(plc_scan_t *s);
int plc_scan_run_tasks(plc_scan_t *s, int64_t now_ns);
void plc_scan_publish_outputs(plc_scan_t *s);

#endif /* PLC_SCAN_CORE_H */
