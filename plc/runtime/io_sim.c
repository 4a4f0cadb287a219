/*
 * io_sim.c - the simulated plant attached to the I/O image.
 *
 * Until the carousel model exists, the plant is a loop-back: at the start of
 * each scan every input takes the value its output had at the end of the
 * previous scan (%QXn.m -> %IXn.m, %QWn -> %IWn).  A real plant model
 * replaces sim_read_inputs/sim_write_outputs without touching the scan loop.
 */
#include <stdlib.h>
#include <string.h>

#include "runtime.h"

typedef struct sim_plant {
    plc_bool_t qx[MAP_BITS];
    uint16_t qw[MAP_WORDS];
} sim_plant_t;

static int sim_open(void **state, char *err, size_t errlen)
{
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
    .description = "simulated plant (outputs looped back to inputs)",
    .open = sim_open,
    .read_inputs = sim_read_inputs,
    .write_outputs = sim_write_outputs,
    .close = sim_close,
};
