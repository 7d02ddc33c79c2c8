/* Unit tests of the bridge's core on a fake board with a fake clock: frames and CRC, the
 * parser's resynchronisation, and the rules of docs/serial-bridge.md (seq echo, queries,
 * outputs before inputs, refusals, the 20 ms dead-man). Run by tests/test_firmware_bridge.py;
 * prints one line per failed check and a closing "N passed, N failed". */
#include <stdio.h>
#include <string.h>

#include "../core/bridge.h"

static int passed, failed;

#define CHECK(cond)                                                                   \
    do {                                                                              \
        if (cond) {                                                                   \
            passed++;                                                                 \
        } else {                                                                      \
            failed++;                                                                 \
            printf("FAILED %s:%d: %s\n", __FILE__, __LINE__, #cond);                  \
        }                                                                             \
    } while (0)

/* -- frames ------------------------------------------------------------------------------------ */

struct collected {
    unsigned n;
    struct frame frames[64];
};

static void collect(void *ctx, const struct frame *frame)
{
    struct collected *c = ctx;
    if (c->n < 64)
        c->frames[c->n++] = *frame;
}

static uint32_t rng = 7;

static uint32_t next_random(void)  /* a fixed LCG: the same stream every run */
{
    rng = rng * 1664525u + 1013904223u;
    return rng >> 16;
}

static void test_crc_check_value_and_a_frame_round_trip(void)
{
    CHECK(frame_crc16((const uint8_t *)"123456789", 9) == 0x29B1u);  /* the catalogue's check value */
    uint16_t counts[] = {0, 1, 65535, 4096};
    uint8_t buf[FRAME_MAX_BYTES];
    size_t n = frame_encode(FRAME_INPUTS, 513, counts, 4, buf);
    CHECK(n == FRAME_OVERHEAD + 8);
    /* byte order: seq and counts little-endian, the crc over kind..payload little-endian */
    CHECK(buf[0] == 0xA5 && buf[1] == 0x5A && buf[2] == 0x81 && buf[3] == 0x01 && buf[4] == 0x02 && buf[5] == 8);
    CHECK(buf[10] == 0xFF && buf[11] == 0xFF);
    uint16_t crc = frame_crc16(buf + 2, n - 4);
    CHECK(buf[n - 2] == (crc & 0xFF) && buf[n - 1] == (crc >> 8));
    struct frame_parser p;
    struct collected got = {0};
    frame_parser_init(&p);
    CHECK(frame_parser_feed(&p, buf, n, collect, &got) == 1);
    CHECK(got.n == 1 && got.frames[0].kind == FRAME_INPUTS && got.frames[0].seq == 513 && got.frames[0].n == 4);
    CHECK(memcmp(got.frames[0].counts, counts, sizeof counts) == 0);
    CHECK(frame_encode(FRAME_OUTPUTS, 1, counts, FRAME_MAX_CHANNELS + 1, buf) == 0);  /* cannot be carried */
}

static void test_frames_split_at_every_byte_and_run_together_are_all_found(void)
{
    struct frame_parser p;
    struct collected got = {0};
    frame_parser_init(&p);
    for (uint16_t seq = 0; seq < 50; seq++) {
        uint16_t counts[2] = {seq, (uint16_t)(2 * seq)};
        uint8_t buf[FRAME_MAX_BYTES];
        size_t n = frame_encode(FRAME_OUTPUTS, seq, counts, 2, buf);
        for (size_t i = 0; i < n; i++)
            frame_parser_feed(&p, buf + i, 1, collect, &got);
    }
    CHECK(got.n == 50 && p.stats.discarded_bytes == 0);
    int in_order = 1;
    for (unsigned i = 0; i < got.n; i++)
        in_order &= got.frames[i].seq == i && got.frames[i].counts[1] == 2 * i;
    CHECK(in_order);
}

static void test_a_sync_pattern_inside_a_payload_does_not_cost_the_next_frame(void)
{
    uint16_t tricky_counts[] = {0x5AA5, 0x5AA5}, seven = 7;  /* the payload holds the sync bytes */
    uint8_t tricky[FRAME_MAX_BYTES], stream[3 * FRAME_MAX_BYTES];
    size_t nt = frame_encode(FRAME_INPUTS, 1, tricky_counts, 2, tricky), n = 0;
    memcpy(stream, tricky, nt - 3);  /* a frame cut short by a reset bridge */
    n += nt - 3;
    n += frame_encode(FRAME_INPUTS, 2, &seven, 1, stream + n);
    memcpy(stream + n, tricky, nt);
    n += nt;
    struct frame_parser p;
    struct collected got = {0};
    frame_parser_init(&p);
    frame_parser_feed(&p, stream, n, collect, &got);
    CHECK(got.n == 2 && got.frames[0].seq == 2 && got.frames[1].seq == 1);
    CHECK(p.stats.crc_errors == 1);
}

static void test_a_good_frame_inside_a_long_rejected_one_is_found(void)
{
    /* A header claiming 64 bytes swallows the next frames whole; once its CRC fails, the
     * search resumes inside what it swallowed. */
    uint8_t stream[4 * FRAME_MAX_BYTES] = {0xA5, 0x5A, FRAME_OUTPUTS, 0x00, 0x00, 64};
    size_t n = 6;
    uint16_t counts[4] = {100, 200, 300, 400};
    for (uint16_t seq = 10; seq < 15; seq++)
        n += frame_encode(FRAME_OUTPUTS, seq, counts, 4, stream + n);  /* 16 bytes each: 86 in all, past its 72 */
    struct frame_parser p;
    struct collected got = {0};
    frame_parser_init(&p);
    frame_parser_feed(&p, stream, n, collect, &got);
    CHECK(p.stats.crc_errors == 1);
    CHECK(got.n == 5 && got.frames[0].seq == 10 && got.frames[4].seq == 14);
}

static void test_impossible_headers_are_skipped_not_waited_for(void)
{
    uint8_t stream[64] = {0xA5, 0x5A, FRAME_INPUTS, 0, 0, 200,   /* beyond FRAME_MAX_PAYLOAD */
                          0xA5, 0x5A, FRAME_OUTPUTS, 0, 0, 3,    /* odd */
                          0xA5, 0x5A, 0x02, 0, 0, 2};            /* unknown kind */
    uint16_t one = 1;
    size_t n = 18 + frame_encode(FRAME_INPUTS, 9, &one, 1, stream + 18);
    struct frame_parser p;
    struct collected got = {0};
    frame_parser_init(&p);
    frame_parser_feed(&p, stream, n, collect, &got);
    CHECK(got.n == 1 && got.frames[0].seq == 9);
    CHECK(p.stats.bad_headers == 3);
}

static void test_noise_and_corrupted_frames_are_counted_and_the_good_ones_kept(void)
{
    static uint8_t stream[200 * (FRAME_MAX_BYTES + 4)];
    size_t n = 0;
    unsigned corrupted = 0, expected[200], n_expected = 0;
    for (uint16_t seq = 0; seq < 200; seq++) {
        for (uint32_t k = next_random() % 5; k > 0; k--)
            stream[n++] = (uint8_t)next_random();  /* line noise */
        uint16_t counts[6] = {seq, seq, seq, seq, seq, seq};
        size_t len = frame_encode(FRAME_INPUTS, seq, counts, 6, stream + n);
        if (seq % 10 == 3) {
            stream[n + 8] ^= 0x40;  /* one flipped bit in the payload */
            corrupted++;
        } else {
            expected[n_expected++] = seq;
        }
        n += len;
    }
    struct frame_parser p;
    frame_parser_init(&p);
    static struct collected got[4];  /* 64 frames each: fed in quarters */
    size_t at = 0;
    for (unsigned q = 0; q < 4; q++) {
        size_t end = (q + 1) * n / 4;
        while (at < end) {  /* reads of random sizes, as a port delivers them */
            size_t k = 1 + next_random() % 40;
            k = k > end - at ? end - at : k;
            frame_parser_feed(&p, stream + at, k, collect, &got[q]);
            at += k;
        }
    }
    unsigned total = 0, same = 1;
    for (unsigned q = 0; q < 4; q++)
        for (unsigned i = 0; i < got[q].n; i++, total++)
            same &= total < n_expected && got[q].frames[i].seq == expected[total];
    CHECK(total == n_expected && same);
    CHECK(p.stats.crc_errors + p.stats.bad_headers >= corrupted);
    CHECK(p.stats.discarded_bytes > 0);
}

/* -- the bridge on a fake board ---------------------------------------------------------------------- */

struct fake {
    uint32_t t_us;
    uint16_t staged[FRAME_MAX_CHANNELS], outputs[FRAME_MAX_CHANNELS], inputs[FRAME_MAX_CHANNELS];
    unsigned updates, samples;
    char log[64];  /* 'w' write, 'u' update, 's' sample, 'r' read, 'x' reply, in call order */
    unsigned log_n;
    uint8_t rx[4 * FRAME_MAX_BYTES], tx[4 * FRAME_MAX_BYTES];
    size_t rx_n, rx_at, tx_n;
};

static void note(struct fake *f, char what)
{
    if (f->log_n < sizeof f->log - 1)
        f->log[f->log_n++] = what;
}

static void f_dac_write(void *ctx, unsigned ch, uint16_t counts)
{
    struct fake *f = ctx;
    f->staged[ch] = counts;
    note(f, 'w');
}

static void f_dac_update(void *ctx)
{
    struct fake *f = ctx;
    memcpy(f->outputs, f->staged, sizeof f->outputs);
    f->updates++;
    note(f, 'u');
}

static void f_adc_sample(void *ctx)
{
    struct fake *f = ctx;
    f->samples++;
    note(f, 's');
}

static uint16_t f_adc_read(void *ctx, unsigned ch)
{
    struct fake *f = ctx;
    note(f, 'r');
    return f->inputs[ch];
}

static size_t f_serial_read(void *ctx, uint8_t *buf, size_t max)
{
    struct fake *f = ctx;
    size_t n = f->rx_n - f->rx_at < max ? f->rx_n - f->rx_at : max;
    memcpy(buf, f->rx + f->rx_at, n);
    f->rx_at += n;
    return n;
}

static void f_serial_write(void *ctx, const uint8_t *buf, size_t n)
{
    struct fake *f = ctx;
    memcpy(f->tx + f->tx_n, buf, n);
    f->tx_n += n;
    note(f, 'x');
}

static uint32_t f_micros(void *ctx)
{
    return ((struct fake *)ctx)->t_us;
}

static const struct bridge_layout layout = {"test", 3, 2, {111, 222}};

/* A bridge on a fresh fake board at t_us, its log cleared after the start. */
static void start(struct bridge *b, struct fake *f, struct bridge_board *board, uint32_t t_us)
{
    memset(f, 0, sizeof *f);
    f->t_us = t_us;
    f->inputs[0] = 10, f->inputs[1] = 20, f->inputs[2] = 30;
    struct bridge_board fb = {f, f_dac_write, f_dac_update, f_adc_sample, f_adc_read, f_serial_read, f_serial_write,
                              f_micros};
    *board = fb;
    bridge_init(b, board, &layout);
    f->log_n = 0;
    memset(f->log, 0, sizeof f->log);
}

/* Send a frame to the bridge and poll once; the replies it sent, parsed. */
static struct collected exchange(struct bridge *b, struct fake *f, uint8_t kind, uint16_t seq, const uint16_t *counts,
                                 unsigned n)
{
    f->rx_n = frame_encode(kind, seq, counts, n, f->rx);
    f->rx_at = 0;
    f->tx_n = 0;
    bridge_poll(b);
    struct frame_parser p;
    struct collected got = {0};
    frame_parser_init(&p);
    frame_parser_feed(&p, f->tx, f->tx_n, collect, &got);
    return got;
}

static void test_the_bridge_starts_on_its_safe_outputs(void)
{
    struct bridge b;
    struct fake f;
    struct bridge_board board;
    start(&b, &f, &board, 0);
    CHECK(f.updates == 1 && f.outputs[0] == 111 && f.outputs[1] == 222 && b.safe);
}

static void test_outputs_are_applied_then_inputs_sampled_and_the_seq_echoed(void)
{
    struct bridge b;
    struct fake f;
    struct bridge_board board;
    start(&b, &f, &board, 5000);
    uint16_t out[2] = {40000, 12345};
    struct collected got = exchange(&b, &f, FRAME_OUTPUTS, 0xFFFF, out, 2);
    CHECK(f.outputs[0] == 40000 && f.outputs[1] == 12345);
    CHECK(strcmp(f.log, "wwusrrrx") == 0);  /* both outputs, one update, then the sweep, then the reply */
    CHECK(got.n == 1 && got.frames[0].kind == FRAME_INPUTS && got.frames[0].seq == 0xFFFF && got.frames[0].n == 3);
    CHECK(got.frames[0].counts[0] == 10 && got.frames[0].counts[2] == 30);
    CHECK(b.counters.replies == 1 && !b.safe);
}

static void test_a_query_is_answered_and_changes_no_output(void)
{
    struct bridge b;
    struct fake f;
    struct bridge_board board;
    start(&b, &f, &board, 0);
    struct collected got = exchange(&b, &f, FRAME_OUTPUTS, 42, 0, 0);
    CHECK(got.n == 1 && got.frames[0].seq == 42 && got.frames[0].n == 3);
    CHECK(strcmp(f.log, "srrrx") == 0 && b.counters.queries == 1);
    CHECK(f.outputs[0] == 111 && f.outputs[1] == 222);
}

static void test_frames_not_for_this_bridge_get_no_answer(void)
{
    struct bridge b;
    struct fake f;
    struct bridge_board board;
    start(&b, &f, &board, 0);
    uint16_t three[3] = {1, 2, 3};
    CHECK(exchange(&b, &f, FRAME_OUTPUTS, 1, three, 3).n == 0);  /* another rig's channel count */
    CHECK(exchange(&b, &f, FRAME_INPUTS, 2, three, 3).n == 0);   /* an inputs frame: our own echo */
    CHECK(b.counters.refused == 2 && f.log_n == 0 && f.outputs[0] == 111);
    f.rx_n = frame_encode(FRAME_OUTPUTS, 3, three, 2, f.rx);
    f.rx[7] ^= 0x01;  /* a corrupted outputs frame: dropped on its CRC, nothing applied */
    f.rx_at = 0;
    bridge_poll(&b);
    CHECK(f.tx_n == 0 && f.outputs[0] == 111 && b.parser.stats.crc_errors == 1);
}

static void test_the_dead_man_writes_the_safe_outputs_after_20_ms_without_outputs(void)
{
    struct bridge b;
    struct fake f;
    struct bridge_board board;
    start(&b, &f, &board, 1000);
    uint16_t out[2] = {40000, 40000};
    exchange(&b, &f, FRAME_OUTPUTS, 1, out, 2);
    f.t_us = 1000 + 10000;
    exchange(&b, &f, FRAME_OUTPUTS, 2, 0, 0);  /* a query does not feed the dead-man */
    f.t_us = 1000 + BRIDGE_DEADMAN_US;
    bridge_poll(&b);
    CHECK(f.outputs[0] == 40000 && !b.safe);  /* exactly 20 ms: not yet */
    f.t_us += 1;
    bridge_poll(&b);
    CHECK(f.outputs[0] == 111 && f.outputs[1] == 222 && b.safe && b.counters.deadman == 1);
    unsigned updates = f.updates;
    f.t_us += 100000;
    bridge_poll(&b);
    CHECK(f.updates == updates && b.counters.deadman == 1);  /* written once, not again and again */
    exchange(&b, &f, FRAME_OUTPUTS, 3, out, 2);
    CHECK(f.outputs[0] == 40000 && !b.safe);  /* the host is back: its outputs apply */
}

static void test_outputs_keep_the_dead_man_off_and_the_clock_may_wrap(void)
{
    struct bridge b;
    struct fake f;
    struct bridge_board board;
    start(&b, &f, &board, 0xFFFFFFFFu - 30000u);
    uint16_t out[2] = {500, 600};
    for (uint16_t seq = 0; seq < 100; seq++) {  /* 100 ms of 1 kHz frames across the wrap */
        exchange(&b, &f, FRAME_OUTPUTS, seq, out, 2);
        f.t_us += 1000;
    }
    CHECK(b.counters.deadman == 0 && f.outputs[0] == 500 && b.counters.replies == 100);
    f.t_us += BRIDGE_DEADMAN_US;
    bridge_poll(&b);
    CHECK(b.counters.deadman == 1 && f.outputs[0] == 111);
}

int main(void)
{
    test_crc_check_value_and_a_frame_round_trip();
    test_frames_split_at_every_byte_and_run_together_are_all_found();
    test_a_sync_pattern_inside_a_payload_does_not_cost_the_next_frame();
    test_a_good_frame_inside_a_long_rejected_one_is_found();
    test_impossible_headers_are_skipped_not_waited_for();
    test_noise_and_corrupted_frames_are_counted_and_the_good_ones_kept();
    test_the_bridge_starts_on_its_safe_outputs();
    test_outputs_are_applied_then_inputs_sampled_and_the_seq_echoed();
    test_a_query_is_answered_and_changes_no_output();
    test_frames_not_for_this_bridge_get_no_answer();
    test_the_dead_man_writes_the_safe_outputs_after_20_ms_without_outputs();
    test_outputs_keep_the_dead_man_off_and_the_clock_may_wrap();
    printf("%d passed, %d failed\n", passed, failed);
    return failed != 0;
}
