/*
 * io_none.c - no physical I/O.
 *
 * Inputs stay as the program image holds them and outputs go nowhere: the
 * program is reached only through Modbus (for an external simulator that
 * plays the plant through the host-writable registers).
 */
#include "runtime.h"

static int none_open(runtime_t *rt, void **state, char *err, size_t errlen)
{
    (void)rt;
    (void)err;
    (void)errlen;
    *state = NULL;
    return 0;
}

static void none_read_inputs(void *state, plc_bool_t ix[MAP_BITS], uint16_t iw[MAP_WORDS])
{
    (void)state;
    (void)ix;
    (void)iw;
}

static void none_write_outputs(void *state, const plc_bool_t qx[MAP_BITS], const uint16_t qw[MAP_WORDS])
{
    (void)state;
    (void)qx;
    (void)qw;
}

static void none_close(void *state)
{
    (void)state;
}

const io_layer_t io_none_layer = {
    .name = "none",
    .description = "no physical I/O; the program is reached through Modbus only",
    .open = none_open,
    .read_inputs = none_read_inputs,
    .write_outputs = none_write_outputs,
    .close = none_close,
};
