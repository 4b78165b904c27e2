/*
 * The firmware on a simulated bench: simavr runs the compiled ELF on an ATmega328P at 16 MHz,
 * its UART on a pseudo-terminal (simavr's uart_pty part), and this program plays the rest of
 * the wiring. It counts the pulses on STEP (signed by DIR), closes the home switch when the
 * counted position is at home, and times each shutter pulse in simulated cycles.
 *
 * Usage: bench FIRMWARE.elf [START_STEPS]
 *   prints "pty /dev/pts/N" once the UART is connected; then, for each line read on standard
 *   input, "steps NET TOTAL" (net signed steps since the start, and all pulses) followed by
 *   "shutter W1 W2 ..." (each finished pulse's width in microseconds of simulated time).
 *   START_STEPS: where the table stands at power-up, in steps past home.
 */

#include <inttypes.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "avr_ioport.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "uart_pty.h"

#ifndef STEPS_PER_TURN
#define STEPS_PER_TURN 3200L
#endif
#define MAX_PULSES 4096

static avr_t *avr;
static uart_pty_t uart;
static avr_irq_t *home_pin;

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static int64_t net_steps, total_steps, start_steps;
static int dir_positive;
static int home_closed = -1;
static avr_cycle_count_t shutter_rose;
static uint32_t widths_us[MAX_PULSES];
static int n_widths;

/* The switch is closed over one step at home (position 0, modulo a turn). */
static void update_home(void) {
    int64_t at = (start_steps + net_steps) % STEPS_PER_TURN;
    if (at < 0) at += STEPS_PER_TURN;
    int closed = at == 0;
    if (closed != home_closed) {
        home_closed = closed;
        /* Driven from outside, as a switch to ground beside the pull-up is: simavr would
         * otherwise put the pull-up's level back on the pin at the firmware's next write to
         * PORTD (every step). */
        avr_ioport_external_t level = {.name = 'D', .mask = 1 << 5, .value = closed ? 0 : 1 << 5};
        avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('D'), &level);
        avr_raise_irq(home_pin, closed ? 0 : 1);
    }
}

static void on_dir(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    (void)param;
    dir_positive = value != 0;
}

static void on_step(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)param;
    /* A rising edge is a step. */
    if (value && !irq->value) {
        pthread_mutex_lock(&lock);
        net_steps += dir_positive ? 1 : -1;
        total_steps++;
        pthread_mutex_unlock(&lock);
        update_home();
    }
}

static void on_shutter(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)param;
    if (value && !irq->value) {
        shutter_rose = avr->cycle;
    } else if (!value && irq->value) {
        uint64_t cycles = avr->cycle - shutter_rose;
        pthread_mutex_lock(&lock);
        if (n_widths < MAX_PULSES) widths_us[n_widths++] = (uint32_t)(cycles * 1000000 / avr->frequency);
        pthread_mutex_unlock(&lock);
    }
}

/* Answers the test's questions on standard input while the simulation runs. */
static void *report(void *arg) {
    (void)arg;
    char line[64];
    while (fgets(line, sizeof line, stdin)) {
        pthread_mutex_lock(&lock);
        printf("steps %" PRId64 " %" PRId64 "\nshutter", net_steps, total_steps);
        for (int i = 0; i < n_widths; i++) printf(" %" PRIu32, widths_us[i]);
        printf("\n");
        pthread_mutex_unlock(&lock);
        fflush(stdout);
    }
    exit(0);
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: %s FIRMWARE.elf [START_STEPS]\n", argv[0]);
        return 2;
    }
    elf_firmware_t f;
    memset(&f, 0, sizeof f);
    if (elf_read_firmware(argv[1], &f) != 0) {
        fprintf(stderr, "bench: cannot read %s\n", argv[1]);
        return 1;
    }
    start_steps = argc > 2 ? strtoll(argv[2], NULL, 10) : 0;
    avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) {
        fprintf(stderr, "bench: simavr has no atmega328p\n");
        return 1;
    }
    avr_init(avr);
    avr->frequency = 16000000;
    avr_load_firmware(avr, &f);
    avr->frequency = 16000000;

    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2), on_step, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 3), on_dir, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 6), on_shutter, NULL);
    home_pin = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 5);
    update_home();

    uart_pty_init(avr, &uart);
    uart_pty_connect(&uart, '0');
    printf("pty %s\n", uart.pty.slavename);
    fflush(stdout);

    pthread_t t;
    pthread_create(&t, NULL, report, NULL);
    for (;;) {
        int state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed) {
            fprintf(stderr, "bench: the firmware stopped (state %d)\n", state);
            return 1;
        }
    }
}
