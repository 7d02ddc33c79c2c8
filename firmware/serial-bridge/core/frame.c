/* Frames of the serial DAQ bridge: CRC, encoder, and the resynchronising parser (frame.h). */
#include "frame.h"

#include <string.h>

uint16_t frame_crc16(const uint8_t *data, size_t n)
{
    uint16_t crc = 0xFFFFu;
    for (size_t i = 0; i < n; i++) {
        crc ^= (uint16_t)((uint16_t)data[i] << 8);
        for (int bit = 0; bit < 8; bit++)
            crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
    }
    return crc;
}

size_t frame_encode(uint8_t kind, uint16_t seq, const uint16_t *counts, unsigned n, uint8_t *out)
{
    if (n > FRAME_MAX_CHANNELS)
        return 0;
    out[0] = FRAME_SYNC0;
    out[1] = FRAME_SYNC1;
    out[2] = kind;
    out[3] = (uint8_t)(seq & 0xFFu);
    out[4] = (uint8_t)(seq >> 8);
    out[5] = (uint8_t)(2u * n);
    for (unsigned i = 0; i < n; i++) {
        out[FRAME_HEADER + 2u * i] = (uint8_t)(counts[i] & 0xFFu);
        out[FRAME_HEADER + 2u * i + 1u] = (uint8_t)(counts[i] >> 8);
    }
    size_t end = FRAME_HEADER + 2u * n;
    uint16_t crc = frame_crc16(out + 2, end - 2u);  /* kind..payload */
    out[end] = (uint8_t)(crc & 0xFFu);
    out[end + 1u] = (uint8_t)(crc >> 8);
    return end + 2u;
}

void frame_parser_init(struct frame_parser *p)
{
    memset(p, 0, sizeof *p);
}

/* Forget the first k buffered bytes. */
static void drop(struct frame_parser *p, unsigned k)
{
    memmove(p->buf, p->buf + k, (size_t)(p->len - k));
    p->len = (uint8_t)(p->len - k);
}

/* Look at the buffer from its start: 1 and out filled for a good frame (removed from the
 * buffer), 0 when it needs more bytes. A rejected frame loses only its sync pattern, so the
 * search for the next one goes through the rest of its bytes. */
static int scan(struct frame_parser *p, struct frame *out)
{
    for (;;) {
        if (p->len >= 1 && p->buf[0] != FRAME_SYNC0) {
            p->stats.discarded_bytes++;
            drop(p, 1);
            continue;
        }
        if (p->len >= 2 && p->buf[1] != FRAME_SYNC1) {  /* 0xA5 not followed by 0x5A: not a sync */
            p->stats.discarded_bytes++;
            drop(p, 1);
            continue;
        }
        if (p->len < FRAME_HEADER)
            return 0;
        uint8_t kind = p->buf[2], length = p->buf[5];
        if ((kind != FRAME_OUTPUTS && kind != FRAME_INPUTS) || length > FRAME_MAX_PAYLOAD || (length & 1u)) {
            p->stats.bad_headers++;
            p->stats.discarded_bytes += 2u;
            drop(p, 2);
            continue;
        }
        unsigned end = FRAME_HEADER + length;
        if (p->len < end + 2u)
            return 0;
        uint16_t crc = (uint16_t)(p->buf[end] | (p->buf[end + 1u] << 8));
        if (crc != frame_crc16(p->buf + 2, end - 2u)) {
            p->stats.crc_errors++;
            p->stats.discarded_bytes += 2u;
            drop(p, 2);
            continue;
        }
        out->kind = kind;
        out->seq = (uint16_t)(p->buf[3] | (p->buf[4] << 8));
        out->n = (uint8_t)(length / 2u);
        for (unsigned i = 0; i < out->n; i++)
            out->counts[i] = (uint16_t)(p->buf[FRAME_HEADER + 2u * i] | (p->buf[FRAME_HEADER + 2u * i + 1u] << 8));
        drop(p, end + 2u);
        p->stats.frames++;
        return 1;
    }
}

unsigned frame_parser_feed(struct frame_parser *p, const uint8_t *data, size_t n, frame_handler *on_frame, void *ctx)
{
    struct frame frame;
    unsigned found = 0;
    for (size_t i = 0; i < n; i++) {
        /* scan() until it wants more leaves fewer than FRAME_MAX_BYTES buffered: room for one */
        p->buf[p->len++] = data[i];
        while (scan(p, &frame)) {  /* a rejected frame's bytes may hold more than one good frame */
            found++;
            on_frame(ctx, &frame);
        }
    }
    return found;
}
