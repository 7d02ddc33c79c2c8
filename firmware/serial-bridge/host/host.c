/* The bridge's logic as a process on this machine: the "host build".
 *
 *   bridge-host --link PATH --plant-fd FD [--layout NAME] [--corrupt-every N]
 *
 * The serial line is a pseudo-terminal (the daemon opens PATH, a link to its terminal end,
 * as it would /dev/ttyACM0); the board's converters are the simulated rig's plant, reached
 * on FD, a SOCK_SEQPACKET socket that sim_backend/firmware_plant.py made and serves:
 *
 *   'H' n_in n_out safe_out[n_out] name  ->  'K', or 'E' and why   (once, at start)
 *   'W' t_us gap_us counts[n_out]        ->  (no reply)  the DACs updated, at t_us of this
 *                                            process's clock, gap_us after its previous look
 *   'S'                                  ->  counts[n_in]   the ADCs sampled now
 *
 * (integers little-endian: t_us and gap_us uint32, counts uint16). Everything else is the
 * core of core/, unchanged. --corrupt-every N flips a bit in every Nth reply (as
 * sim_backend.serial_peer's option does), for the host's CRC counting. On SIGTERM or SIGINT,
 * or when the plant goes away, it prints its counters as one JSON line and exits. */
#define _XOPEN_SOURCE 700

#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "../core/bridge.h"

#define LOOK_US 200  /* the longest wait for a byte: the dead-man is looked at at least this often */

struct host {
    int master, slave, plant;
    const struct bridge_layout *layout;
    uint16_t staged[FRAME_MAX_CHANNELS];
    uint16_t sampled[FRAME_MAX_CHANNELS];
    uint32_t now_us, gap_us;      /* the last clock reading, and its distance from the one before */
    unsigned long corrupt_every, written, tx_dropped;
};

static volatile sig_atomic_t stopping;

static void on_signal(int sig)
{
    (void)sig;
    stopping = 1;
}

static void die(const char *what)
{
    fprintf(stderr, "bridge-host: %s: %s\n", what, errno ? strerror(errno) : "failed");
    exit(2);
}

static void put16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
}

static void put32(uint8_t *p, uint32_t v)
{
    put16(p, (uint16_t)(v & 0xFFFFu));
    put16(p + 2, (uint16_t)(v >> 16));
}

/* One message to the plant; the plant gone ends this process (a board without its rig). */
static void plant_send(struct host *h, const uint8_t *msg, size_t n)
{
    if (send(h->plant, msg, n, MSG_NOSIGNAL) != (ssize_t)n) {
        stopping = 1;
    }
}

static size_t plant_receive(struct host *h, uint8_t *msg, size_t max)
{
    ssize_t n = recv(h->plant, msg, max, 0);
    if (n <= 0) {
        stopping = 1;
        return 0;
    }
    return (size_t)n;
}

/* The plant speaks only when asked: a readable socket between requests is its end. */
static int plant_gone(struct host *h)
{
    uint8_t msg[256];
    return recv(h->plant, msg, sizeof msg, 0) <= 0;
}

/* -- the board interface ------------------------------------------------------------------ */

static void dac_write(void *ctx, unsigned channel, uint16_t counts)
{
    struct host *h = ctx;
    h->staged[channel] = counts;
}

static void dac_update(void *ctx)
{
    struct host *h = ctx;
    uint8_t msg[9 + 2 * FRAME_MAX_CHANNELS];
    msg[0] = 'W';
    put32(msg + 1, h->now_us);
    put32(msg + 5, h->gap_us);
    for (unsigned ch = 0; ch < h->layout->n_out; ch++)
        put16(msg + 9 + 2 * ch, h->staged[ch]);
    plant_send(h, msg, 9 + 2u * h->layout->n_out);
}

static void adc_sample(void *ctx)
{
    struct host *h = ctx;
    uint8_t msg[2 * FRAME_MAX_CHANNELS + 1] = {'S'};
    plant_send(h, msg, 1);
    size_t n = plant_receive(h, msg, sizeof msg);
    if (n != 2u * h->layout->n_in)
        return;  /* the plant is gone (this process ends after this poll): the last sample stands */
    for (unsigned ch = 0; ch < h->layout->n_in; ch++)
        h->sampled[ch] = (uint16_t)(msg[2 * ch] | (msg[2 * ch + 1] << 8));
}

static uint16_t adc_read(void *ctx, unsigned channel)
{
    struct host *h = ctx;
    return h->sampled[channel];
}

static size_t serial_read(void *ctx, uint8_t *buf, size_t max)
{
    struct host *h = ctx;
    ssize_t n = read(h->master, buf, max);
    return n > 0 ? (size_t)n : 0;  /* EAGAIN: nothing yet */
}

static void serial_write(void *ctx, const uint8_t *buf, size_t n)
{
    struct host *h = ctx;
    uint8_t frame[FRAME_MAX_BYTES];
    memcpy(frame, buf, n);
    if (h->corrupt_every && ++h->written % h->corrupt_every == 0)
        frame[n - 3] ^= 0x10;  /* a flipped bit in the payload: the host must drop it on its CRC */
    if (write(h->master, frame, n) != (ssize_t)n)
        h->tx_dropped++;  /* the terminal's buffer is full: nobody reads the other end */
}

static uint32_t micros(void *ctx)
{
    struct host *h = ctx;
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    uint32_t now = (uint32_t)((uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u);
    h->gap_us = now - h->now_us;
    h->now_us = now;
    return now;
}

/* -- the pseudo-terminal and the plant ------------------------------------------------------ */

static const char *open_line(struct host *h, const char *link)
{
    h->master = posix_openpt(O_RDWR | O_NOCTTY);
    if (h->master < 0 || grantpt(h->master) || unlockpt(h->master))
        die("posix_openpt");
    const char *name = ptsname(h->master);
    if (!name)
        die("ptsname");
    static char slave_name[256];
    snprintf(slave_name, sizeof slave_name, "%s", name);
    /* held open by us too: the daemon's going away is then silence, not a hang-up, as on USB */
    h->slave = open(slave_name, O_RDWR | O_NOCTTY);
    if (h->slave < 0)
        die(slave_name);
    struct termios t;
    if (tcgetattr(h->slave, &t))
        die("tcgetattr");
    t.c_iflag &= ~(tcflag_t)(IGNBRK | BRKINT | PARMRK | ISTRIP | INLCR | IGNCR | ICRNL | IXON);
    t.c_oflag &= ~(tcflag_t)OPOST;
    t.c_lflag &= ~(tcflag_t)(ECHO | ECHONL | ICANON | ISIG | IEXTEN);
    t.c_cflag &= ~(tcflag_t)(CSIZE | PARENB);
    t.c_cflag |= CS8;
    if (tcsetattr(h->slave, TCSANOW, &t))
        die("tcsetattr");
    fcntl(h->master, F_SETFL, fcntl(h->master, F_GETFL) | O_NONBLOCK);
    char tmp[4096];
    snprintf(tmp, sizeof tmp, "%s.%ld", link, (long)getpid());
    unlink(tmp);
    if (symlink(slave_name, tmp) || rename(tmp, link))  /* atomic: a reconnecting host never sees it missing */
        die(link);
    return slave_name;
}

/* Tell the plant what this bridge carries; it refuses a layout that is not its rig's. */
static void hello(struct host *h)
{
    uint8_t msg[256] = {'H', h->layout->n_in, h->layout->n_out};
    size_t n = 3;
    for (unsigned ch = 0; ch < h->layout->n_out; ch++, n += 2)
        put16(msg + n, h->layout->safe_out[ch]);
    size_t name = strlen(h->layout->name);
    memcpy(msg + n, h->layout->name, name < sizeof msg - n ? name : sizeof msg - n);
    plant_send(h, msg, n + name);
    uint8_t answer[512];
    size_t got = plant_receive(h, answer, sizeof answer - 1);
    if (got == 0 || answer[0] != 'K') {
        answer[got] = 0;
        fprintf(stderr, "bridge-host: the plant refuses layout %s: %s\n", h->layout->name,
                got ? (const char *)answer + 1 : "no answer");
        exit(2);
    }
}

static void usage(void)
{
    fprintf(stderr, "usage: bridge-host --link PATH --plant-fd FD [--layout NAME] [--corrupt-every N]\n"
                    "layouts:");
    for (unsigned i = 0; i < bridge_layout_count; i++)
        fprintf(stderr, " %s", bridge_layouts[i].name);
    fprintf(stderr, "\n");
    exit(2);
}

int main(int argc, char **argv)
{
    struct host h;
    memset(&h, 0, sizeof h);
    const char *link = 0, *layout = "cylinder-2";
    h.plant = -1;
    for (int i = 1; i < argc; i++) {
        if (i + 1 >= argc)
            usage();
        if (!strcmp(argv[i], "--link"))
            link = argv[++i];
        else if (!strcmp(argv[i], "--plant-fd"))
            h.plant = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--layout"))
            layout = argv[++i];
        else if (!strcmp(argv[i], "--corrupt-every"))
            h.corrupt_every = strtoul(argv[++i], 0, 10);
        else
            usage();
    }
    h.layout = bridge_layout_find(layout);
    if (!link || h.plant < 0 || !h.layout)
        usage();

    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, 0);
    sigaction(SIGINT, &sa, 0);

    hello(&h);
    const char *slave = open_line(&h, link);
    const struct bridge_board board = {&h, dac_write, dac_update, adc_sample, adc_read, serial_read, serial_write,
                                       micros};
    struct bridge b;
    micros(&h);
    bridge_init(&b, &board, h.layout);
    printf("serial bridge firmware (host build): %s -> %s (layout %s)\n", link, slave, h.layout->name);
    fflush(stdout);

    while (!stopping) {
        fd_set readable;
        FD_ZERO(&readable);
        FD_SET(h.master, &readable);
        FD_SET(h.plant, &readable);
        struct timeval look = {0, LOOK_US};
        int nfds = (h.master > h.plant ? h.master : h.plant) + 1;
        int ready = select(nfds, &readable, 0, 0, &look);
        if (ready < 0 && errno != EINTR)
            die("select");
        if (ready > 0 && FD_ISSET(h.plant, &readable) && plant_gone(&h))
            break;
        bridge_poll(&b);
    }

    char target[4096];
    ssize_t n = readlink(link, target, sizeof target - 1);
    if (n > 0 && (target[n] = 0, !strcmp(target, slave)))
        unlink(link);
    const struct frame_stats *s = &b.parser.stats;
    printf("{\"frames\": %lu, \"crc_errors\": %lu, \"bad_headers\": %lu, \"discarded_bytes\": %lu, "
           "\"replies\": %lu, \"queries\": %lu, \"refused\": %lu, \"deadman\": %lu, \"corrupted\": %lu, "
           "\"tx_dropped\": %lu}\n",
           (unsigned long)s->frames, (unsigned long)s->crc_errors, (unsigned long)s->bad_headers,
           (unsigned long)s->discarded_bytes, (unsigned long)b.counters.replies, (unsigned long)b.counters.queries,
           (unsigned long)b.counters.refused, (unsigned long)b.counters.deadman,
           h.corrupt_every ? h.written / h.corrupt_every : 0ul, h.tx_dropped);
    return 0;
}
