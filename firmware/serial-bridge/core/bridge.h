/* The serial DAQ bridge's logic, board-independent (docs/serial-bridge.md, "Rules for the bridge"):
 *
 * - every good outputs frame is answered with one inputs frame carrying its seq; its outputs
 *   are applied (all at once) before the inputs are sampled;
 * - an outputs frame with no payload is a query: answered, no output changed;
 * - a frame of the wrong kind or channel count, one that fails its CRC or has an impossible
 *   header gets no answer (counted); the parser resynchronises inside its bytes;
 * - the dead-man: once no frame with outputs has come for BRIDGE_DEADMAN_US, the safe
 *   outputs are written (a query does not feed it: it changes no output). The bridge also
 *   starts on its safe outputs.
 *
 * No allocation, no blocking: a port calls bridge_poll() in its main loop, as often as it can. */
#ifndef BRIDGE_BRIDGE_H
#define BRIDGE_BRIDGE_H

#include <stdint.h>

#include "board.h"
#include "frame.h"
#include "layouts.h"

#define BRIDGE_DEADMAN_US 20000u     /* 20 ms without outputs: the safe outputs */
#define BRIDGE_READ_CHUNK 64u        /* bytes taken from the line per read */
#define BRIDGE_READS_PER_POLL 8u     /* a flood of bytes cannot hold off the dead-man */

struct bridge_counters {
    uint32_t replies;       /* inputs frames sent */
    uint32_t queries;       /* outputs frames with no payload, answered */
    uint32_t refused;       /* good frames of the wrong kind or channel count: no answer */
    uint32_t deadman;       /* times the dead-man wrote the safe outputs */
};

struct bridge {
    const struct bridge_board *board;
    const struct bridge_layout *layout;
    struct frame_parser parser;
    struct bridge_counters counters;
    uint32_t now_us;            /* this poll's time */
    uint32_t last_outputs_us;   /* when the last outputs were applied */
    int safe;                   /* the DACs hold the safe outputs */
};

/* Bind a board and a layout, and write the safe outputs. */
void bridge_init(struct bridge *b, const struct bridge_board *board, const struct bridge_layout *layout);

/* Take what the line has, answer its frames, then run the dead-man. */
void bridge_poll(struct bridge *b);

#endif
