/*
 * io_layers.c - the table of I/O layers, found by name (--io NAME).
 */
#include <string.h>

#include "runtime.h"

const io_layer_t *const io_layers[] = {
    &io_sim_layer,
    &io_none_layer,
    &io_modbus_layer,
    NULL,
};

const io_layer_t *io_layer_find(const char *name)
{
    for (const io_layer_t *const *l = io_layers; *l; l++)
        if (strcmp((*l)->name, name) == 0)
            return *l;
    return NULL;
}
