/* The serial DAQ bridge on a Raspberry Pi Pico: the board glue for core/ (board.h).
 *
 *   USB CDC (the SDK's stdio_usb driver, used raw)  the line to the daemon: /dev/ttyACM0
 *   TI ADS8688, 8-channel 16-bit SAR ADC, SPI       the inputs, range 0..10.24 V
 *   Analog Devices AD5676R, 8-channel 16-bit DAC    the outputs 0..2.5 V, LDAC for one instant,
 *     each followed by a x4 stage (OPA4197 on the regulators' 24 V): 0..10 V into the ITV0051
 *
 * Wiring and parts: docs/serial-bridge.md, "The firmware". Both chips share SPI0 in mode 1.
 * The hardware watchdog restarts a hung bridge in 50 ms, and a restart writes the safe outputs
 * first thing (the DAC keeps its registers through the MCU's reset). Not compiled against
 * hardware here: what was built where is in the same document. */
#include <stdio.h>
#include <string.h>

#include "hardware/gpio.h"
#include "hardware/spi.h"
#include "hardware/watchdog.h"
#include "pico/stdio/driver.h"
#include "pico/stdio_usb.h"
#include "pico/stdlib.h"

#include "bridge.h"

#define PIN_SCK 2
#define PIN_MOSI 3
#define PIN_MISO 4
#define PIN_CS_ADC 5
#define PIN_CS_DAC 6
#define PIN_LDAC 7          /* low pulse: every DAC input register to its output at once */
#define PIN_ADC_RST 8       /* ADS8688 RST/PD: high to run */
#define SPI_HZ 10000000u    /* both chips take more (ADS8688 17 MHz, AD5676R 50 MHz) */
#define WATCHDOG_MS 50

/* The layout's inputs on the ADS8688's pins: ai0-ai2 potentiometers on AIN0-2, ai6 their
 * supply on AIN3, ai7 the AS-FS amplifier on AIN4. */
static const uint8_t adc_pin[] = {0, 1, 2, 3, 4};

struct pico {
    const struct bridge_layout *layout;
    uint16_t inputs[FRAME_MAX_CHANNELS];
};

static void transfer(uint cs, const uint8_t *out, uint8_t *in, size_t n)
{
    gpio_put(cs, 0);
    spi_write_read_blocking(spi0, out, in, n);
    gpio_put(cs, 1);
}

/* -- AD5676R: 24-bit words, command 0x1 writes input register n (moved to the pin by LDAC) -- */

static void dac_write(void *ctx, unsigned channel, uint16_t counts)
{
    (void)ctx;
    /* counts over 0..10 V at the connector: the x4 stage after a 0..2.5 V DAC, so code = counts */
    uint8_t out[3] = {(uint8_t)(0x10u | (channel & 0x7u)), (uint8_t)(counts >> 8), (uint8_t)counts}, in[3];
    transfer(PIN_CS_DAC, out, in, sizeof out);
}

static void dac_update(void *ctx)
{
    (void)ctx;
    gpio_put(PIN_LDAC, 0);
    busy_wait_us_32(1);  /* LDAC pulse: 20 ns minimum */
    gpio_put(PIN_LDAC, 1);
}

/* -- ADS8688: 32-clock frames; each frame returns the conversion started by the one before -- */

static void adc_register(uint8_t reg, uint8_t value)
{
    uint8_t out[4] = {(uint8_t)((reg << 1) | 1u), value, 0, 0}, in[4];
    transfer(PIN_CS_ADC, out, in, sizeof out);
}

static void adc_init(const struct bridge_layout *layout)
{
    uint8_t mask = 0;
    for (unsigned ch = 0; ch < layout->n_in; ch++) {
        mask |= (uint8_t)(1u << adc_pin[ch]);
        adc_register((uint8_t)(0x05u + adc_pin[ch]), 0x05);  /* range 0101: 0..2.5 x 4.096 V = 0..10.24 V */
    }
    adc_register(0x01, mask);   /* AUTO_SEQ_EN: the sweep takes these channels, in pin order */
    adc_register(0x02, (uint8_t)~mask);  /* the others powered down */
}

static void adc_sample(void *ctx)
{
    struct pico *p = ctx;
    uint8_t out[4] = {0xA0, 0x00, 0, 0}, in[4];  /* AUTO_RST: the sweep starts at its first channel */
    transfer(PIN_CS_ADC, out, in, sizeof out);
    out[0] = 0x00;  /* NO_OP: the next channel of the sweep */
    for (unsigned ch = 0; ch < p->layout->n_in; ch++) {
        transfer(PIN_CS_ADC, out, in, sizeof out);
        uint32_t code = (uint32_t)(in[2] << 8 | in[3]);   /* 0..65535 over 0..10.24 V */
        uint32_t counts = (code * 1024u + 500u) / 1000u;  /* ... over the protocol's 0..10 V */
        p->inputs[ch] = (uint16_t)(counts > 65535u ? 65535u : counts);
    }
}

static uint16_t adc_read(void *ctx, unsigned channel)
{
    return ((struct pico *)ctx)->inputs[channel];
}

/* -- USB CDC through the SDK's driver, without stdio's text handling -- */

static size_t serial_read(void *ctx, uint8_t *buf, size_t max)
{
    (void)ctx;
    int n = stdio_usb.in_chars((char *)buf, (int)max);
    return n > 0 ? (size_t)n : 0;
}

static void serial_write(void *ctx, const uint8_t *buf, size_t n)
{
    (void)ctx;
    stdio_usb.out_chars((const char *)buf, (int)n);  /* gives up after PICO_STDIO_USB_STDOUT_TIMEOUT_US */
}

static uint32_t micros(void *ctx)
{
    (void)ctx;
    return time_us_32();
}

static void pins_init(void)
{
    spi_init(spi0, SPI_HZ);
    spi_set_format(spi0, 8, SPI_CPOL_0, SPI_CPHA_1, SPI_MSB_FIRST);
    gpio_set_function(PIN_SCK, GPIO_FUNC_SPI);
    gpio_set_function(PIN_MOSI, GPIO_FUNC_SPI);
    gpio_set_function(PIN_MISO, GPIO_FUNC_SPI);
    const uint outputs[] = {PIN_CS_ADC, PIN_CS_DAC, PIN_LDAC, PIN_ADC_RST};
    for (unsigned i = 0; i < sizeof outputs / sizeof outputs[0]; i++) {
        gpio_init(outputs[i]);
        gpio_set_dir(outputs[i], GPIO_OUT);
        gpio_put(outputs[i], 1);
    }
    sleep_ms(20);  /* the ADS8688 wakes from RST/PD and its reference settles */
}

int main(void)
{
    static struct pico pico;
    static struct bridge bridge;
    pico.layout = bridge_layout_find(BRIDGE_LAYOUT);
    if (!pico.layout || pico.layout->n_in > sizeof adc_pin)
        panic("layout " BRIDGE_LAYOUT " is not in core/layouts.c or has more inputs than the ADC is wired for");
    const struct bridge_board board = {&pico, dac_write, dac_update, adc_sample, adc_read, serial_read,
                                       serial_write, micros};
    pins_init();
    bridge_init(&bridge, &board, pico.layout);  /* the safe outputs, before anything else */
    adc_init(pico.layout);
    stdio_usb_init();
    watchdog_enable(WATCHDOG_MS, true);
    for (;;) {
        bridge_poll(&bridge);
        watchdog_update();
    }
}
