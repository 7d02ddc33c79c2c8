/* What the bridge's logic needs of a board: a port (pico/, host/) fills one of these.
 *
 * Counts are the protocol's: 0..65535 over each channel's span (0..10 V on the cylinder rig,
 * as the rig file's channels say); a port scales its converters' codes to and from them.
 * Every function is called from one loop, never from an interrupt, and none may block for
 * long: the bridge answers within one 1 ms period. */
#ifndef BRIDGE_BOARD_H
#define BRIDGE_BOARD_H

#include <stddef.h>
#include <stdint.h>

struct bridge_board {
    void *ctx;  /* the port's own state, passed back to every call */
    /* Stage output `channel` (0-based, the rig file's order); nothing moves until dac_update. */
    void (*dac_write)(void *ctx, unsigned channel, uint16_t counts);
    /* Move every staged output to the pins at once (a DAC's LDAC): a frame's outputs are one instant. */
    void (*dac_update)(void *ctx);
    /* Sample every input (a conversion sweep); adc_read then returns this sweep's values. */
    void (*adc_sample)(void *ctx);
    uint16_t (*adc_read)(void *ctx, unsigned channel);
    /* Up to max bytes the line has received, never waiting: 0 when none. */
    size_t (*serial_read)(void *ctx, uint8_t *buf, size_t max);
    /* Send n bytes; a port that cannot (no host reading) drops them: the host counts the loss. */
    void (*serial_write)(void *ctx, const uint8_t *buf, size_t n);
    /* A free-running microsecond clock (wraps after 71 min; only differences are used). A
     * millisecond tick would let a 20 ms dead-man fire anywhere between 19 and 21 ms. */
    uint32_t (*micros)(void *ctx);
};

#endif
