/* The serial DAQ bridge's logic (bridge.h). */
#include "bridge.h"

#include <string.h>

static void write_outputs(struct bridge *b, const uint16_t *counts)
{
    const struct bridge_board *board = b->board;
    for (unsigned ch = 0; ch < b->layout->n_out; ch++)
        board->dac_write(board->ctx, ch, counts[ch]);
    board->dac_update(board->ctx);
}

void bridge_init(struct bridge *b, const struct bridge_board *board, const struct bridge_layout *layout)
{
    memset(b, 0, sizeof *b);
    b->board = board;
    b->layout = layout;
    frame_parser_init(&b->parser);
    b->now_us = board->micros(board->ctx);
    b->last_outputs_us = b->now_us;
    write_outputs(b, layout->safe_out);
    b->safe = 1;
}

static void answer(void *ctx, const struct frame *frame)
{
    struct bridge *b = ctx;
    const struct bridge_board *board = b->board;
    if (frame->kind != FRAME_OUTPUTS || (frame->n != 0 && frame->n != b->layout->n_out)) {
        b->counters.refused++;  /* an echo of our own reply, another rig's host: not ours to answer */
        return;
    }
    if (frame->n) {
        write_outputs(b, frame->counts);
        b->last_outputs_us = b->now_us;
        b->safe = 0;
    } else {
        b->counters.queries++;
    }
    uint16_t inputs[FRAME_MAX_CHANNELS];
    board->adc_sample(board->ctx);  /* after the outputs moved: the host dates the sample by its request */
    for (unsigned ch = 0; ch < b->layout->n_in; ch++)
        inputs[ch] = board->adc_read(board->ctx, ch);
    uint8_t reply[FRAME_MAX_BYTES];
    size_t n = frame_encode(FRAME_INPUTS, frame->seq, inputs, b->layout->n_in, reply);
    board->serial_write(board->ctx, reply, n);
    b->counters.replies++;
}

void bridge_poll(struct bridge *b)
{
    const struct bridge_board *board = b->board;
    b->now_us = board->micros(board->ctx);
    uint8_t chunk[BRIDGE_READ_CHUNK];
    for (unsigned i = 0; i < BRIDGE_READS_PER_POLL; i++) {
        size_t n = board->serial_read(board->ctx, chunk, sizeof chunk);
        if (n == 0)
            break;
        frame_parser_feed(&b->parser, chunk, n, answer, b);
    }
    /* unsigned difference: right across the clock's wrap */
    if (!b->safe && (uint32_t)(b->now_us - b->last_outputs_us) > BRIDGE_DEADMAN_US) {
        write_outputs(b, b->layout->safe_out);
        b->safe = 1;
        b->counters.deadman++;
    }
}
