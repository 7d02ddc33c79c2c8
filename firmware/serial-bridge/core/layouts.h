/* The bridge's channel counts and safe outputs, per rig: a small table, one entry a rig
 * file. A bridge answers only frames that carry its rig's outputs, and its dead-man writes
 * its rig's safe outputs, so both must agree with the daemon's rig file (channel order as
 * hal.transport.rig_channels gives it: each joint's angle sensor, the supply monitor, the
 * force sensor; outputs head, rod per joint). The host build checks an entry against the rig
 * file at start (sim_backend/firmware_plant.py). */
#ifndef BRIDGE_LAYOUTS_H
#define BRIDGE_LAYOUTS_H

#include <stdint.h>

#include "frame.h"

struct bridge_layout {
    const char *name;     /* how a port or the host build names it (--layout) */
    uint8_t n_in;         /* inputs carried in a reply */
    uint8_t n_out;        /* outputs an outputs frame carries */
    /* What the dead-man writes [counts over 0..10 V]: each regulator's safe_mpa. 0 V vents
     * the ITV0051 (0.001 MPa, the rig files' safe_mpa). */
    uint16_t safe_out[FRAME_MAX_CHANNELS];
};

/* The entry named `name`, or 0. */
const struct bridge_layout *bridge_layout_find(const char *name);

extern const struct bridge_layout bridge_layouts[];
extern const unsigned bridge_layout_count;

#endif
