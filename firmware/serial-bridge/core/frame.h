/* The serial DAQ bridge's frames (docs/serial-bridge.md; the host's side is hal/serial_frames.py).
 *
 *   offset  size  field
 *   0       2     sync      0xA5 0x5A
 *   2       1     kind      0x01 outputs (host -> bridge), 0x81 inputs (bridge -> host)
 *   3       2     seq       uint16 little-endian; a reply carries the seq of its request
 *   5       1     length    payload bytes: even, at most FRAME_MAX_PAYLOAD
 *   6       n     payload   uint16 little-endian raw counts, one per channel
 *   6+n     2     crc       CRC-16/CCITT-FALSE over kind..payload, little-endian
 *
 * The parser takes one byte at a time and keeps at most one frame's bytes: no allocation,
 * a bounded amount of work per byte. After a rejected frame it resynchronises on the next
 * sync pattern, which may start inside the bytes it rejected (the host's FrameReader does
 * the same, and counts the same things). */
#ifndef BRIDGE_FRAME_H
#define BRIDGE_FRAME_H

#include <stddef.h>
#include <stdint.h>

#define FRAME_SYNC0 0xA5u
#define FRAME_SYNC1 0x5Au
#define FRAME_OUTPUTS 0x01u
#define FRAME_INPUTS 0x81u
#define FRAME_MAX_PAYLOAD 64u                  /* 32 channels of 16 bits */
#define FRAME_MAX_CHANNELS (FRAME_MAX_PAYLOAD / 2u)
#define FRAME_HEADER 6u
#define FRAME_OVERHEAD (FRAME_HEADER + 2u)     /* header and crc */
#define FRAME_MAX_BYTES (FRAME_OVERHEAD + FRAME_MAX_PAYLOAD)

/* CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final xor ("123456789" -> 0x29B1). */
uint16_t frame_crc16(const uint8_t *data, size_t n);

/* One frame into out (FRAME_OVERHEAD + 2 n bytes, at most FRAME_MAX_BYTES); its length, or 0
 * when n exceeds FRAME_MAX_CHANNELS. */
size_t frame_encode(uint8_t kind, uint16_t seq, const uint16_t *counts, unsigned n, uint8_t *out);

struct frame {
    uint8_t kind;
    uint16_t seq;
    uint8_t n;                               /* channels in counts */
    uint16_t counts[FRAME_MAX_CHANNELS];
};

/* What the parser threw away, as the host's ReaderStats counts it. */
struct frame_stats {
    uint32_t frames;            /* good frames returned */
    uint32_t crc_errors;
    uint32_t bad_headers;       /* unknown kind, odd or oversized length */
    uint32_t discarded_bytes;   /* skipped while looking for a sync pattern */
};

struct frame_parser {
    uint8_t buf[FRAME_MAX_BYTES];
    uint8_t len;
    struct frame_stats stats;
};

void frame_parser_init(struct frame_parser *p);

/* Called for each good frame, in the order the bytes brought them. */
typedef void frame_handler(void *ctx, const struct frame *frame);

/* Feed n bytes as the line gave them (split, run together, with noise between); every good
 * frame in them is handed to on_frame before the call returns. The number of frames. */
unsigned frame_parser_feed(struct frame_parser *p, const uint8_t *data, size_t n, frame_handler *on_frame, void *ctx);

#endif
