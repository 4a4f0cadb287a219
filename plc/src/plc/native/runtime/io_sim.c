/*
 * io_sim.c - the simulated plant attached to the I/O image.
 *
 * A program that carries models of its own plant (the tool changer's ST
 * plant models, which also run on a real OpenPLC for demos) is told to use
 * them by one discrete input it names: `--sim-flag %IXa.b` (the application
 * says which, from its register map; `plc run` passes it).  That input is held
 * TRUE; every other input is a loop-back of the outputs of the previous scan
 * (%QXn.m -> %IXn.m, %QWn -> %IWn), which keeps simple programs testable
 * without a plant.
 */
#include <stdlib.h>
#include <string.h>

#include "runtime.h"

typedef struct sim_plant {
    plc_bool_t qx[MAP_BITS];
    uint16_t qw[MAP_WORDS];
    int flag_bit;                  /* --sim-flag, -1: none */
} sim_plant_t;

static int sim_open(runtime_t *rt, void **state, char *err, size_t errlen)
{
    (void)err;
    (void)errlen;
    sim_plant_t *s = calloc(1, sizeof(sim_plant_t));
    if (!s)
        return -1;
    s->flag_bit = rt->opt.sim_flag_bit;
    if (s->flag_bit >= 0)
        log_msg(rt->log, LOG_INFO, "io sim: %%IX%d.%d held TRUE (--sim-flag): the program's plant models run",
                s->flag_bit / 8, s->flag_bit % 8);
    *state = s;
    return 0;
}

static void sim_read_inputs(void *state, plc_bool_t ix[MAP_BITS], uint16_t iw[MAP_WORDS])
{
    const sim_plant_t *s = state;

    memcpy(ix, s->qx, sizeof s->qx);
    memcpy(iw, s->qw, sizeof s->qw);
    if (s->flag_bit >= 0)
        ix[s->flag_bit] = 1;
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
    .description = "outputs loop back to inputs; with --sim-flag the program's own simulated plant",
    .open = sim_open,
    .read_inputs = sim_read_inputs,
    .write_outputs = sim_write_outputs,
    .close = sim_close,
};
