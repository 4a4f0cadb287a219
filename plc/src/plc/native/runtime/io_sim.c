/*
 * io_sim.c - the simulated plant attached to the I/O image.
 *
 * The carousel, arm and collet are simulated by the ST plant models
 * (FB_CarouselPlant and friends) inside the program, so that the same
 * simulation also runs on a real OpenPLC for demos.  This layer tells the
 * program to use them by raising the discrete input SIM_FLAG_BIT (%IX49.7,
 * "SimulatedPlant" in modbus_map/map.toml).  Every other input is a loop-back
 * of the outputs of the previous scan (%QXn.m -> %IXn.m, %QWn -> %IWn), which
 * keeps simple programs testable without a plant.
 */
#include <stdlib.h>
#include <string.h>

#include "runtime.h"

/* %IX49.7: TRUE tells the program that its plant models stand in for the machine. */
#define SIM_FLAG_BIT 399

typedef struct sim_plant {
    plc_bool_t qx[MAP_BITS];
    uint16_t qw[MAP_WORDS];
} sim_plant_t;

static int sim_open(runtime_t *rt, void **state, char *err, size_t errlen)
{
    (void)rt;
    (void)err;
    (void)errlen;
    *state = calloc(1, sizeof(sim_plant_t));
    return *state ? 0 : -1;
}

static void sim_read_inputs(void *state, plc_bool_t ix[MAP_BITS], uint16_t iw[MAP_WORDS])
{
    const sim_plant_t *s = state;

    memcpy(ix, s->qx, sizeof s->qx);
    memcpy(iw, s->qw, sizeof s->qw);
    ix[SIM_FLAG_BIT] = 1;
}

static void sim_write_outputs(void *state, const plc_bool_t qx[MAP_BITS], const uint16_t qw[MAP_WORDS])
{
    sim_plant_t *s = state;

    memcpy(s->qx, qx, sizeof s->qx);
    memcpy(s->qw, qw, sizeof s->qw);
}

static void sim_close(void *state)
{
    free(state);
}

const io_layer_t io_sim_layer = {
    .name = "sim",
    .description = "simulated plant (the program's plant models, %IX49.7 set; other inputs loop back)",
    .open = sim_open,
    .read_inputs = sim_read_inputs,
    .write_outputs = sim_write_outputs,
    .close = sim_close,
};
