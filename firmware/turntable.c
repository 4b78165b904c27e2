/*
 * brdfd rig protocol (version 1) on an ATmega328P (Arduino Uno or Nano, 16 MHz): a turntable
 * driven through a step/dir stepper driver (A4988, DRV8825, TMC2208 in step/dir mode), a home
 * switch, and a shutter output through an optocoupler to the camera's remote socket.
 *
 * The protocol is described in drivers/serial/src/lib.rs: one command per line, one answer
 * per command (`OK`, `OK <value>` or `ERR <reason>`), lines starting with `#` are a log the
 * host skips. This firmware answers `ID?` with `OK brdfd-avr 1 FIRE ROT`.
 *
 * Pins (Arduino names):
 *   D2 (PD2)  STEP    to the driver's STEP input; one step per rising edge
 *   D3 (PD3)  DIR     high turns the positive way
 *   D4 (PD4)  ENABLE  low enables the driver (A4988/DRV8825 /EN)
 *   D5 (PD5)  HOME    home switch to ground, pulled up here: low when the table is home
 *   D6 (PD6)  SHUTTER high drives the optocoupler's LED (through its resistor): pressed
 *   D13 (PB5) LED     on while the table moves or the shutter is held
 *
 * Build settings (make STEPS_PER_TURN=... STEP_HZ=...): the motor's steps per turn of the table
 * (full steps × microsteps × gear ratio), and the stepping rate.
 */

#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <util/delay.h>

#ifndef STEPS_PER_TURN
#define STEPS_PER_TURN 3200L /* 200 full steps × 16 microsteps, direct drive */
#endif
#ifndef STEP_HZ
#define STEP_HZ 1600 /* an eighth of a turn per second at the defaults */
#endif
#ifndef BAUD
#define BAUD 115200UL
#endif

#define STEP_BIT PD2
#define DIR_BIT PD3
#define ENABLE_BIT PD4
#define HOME_BIT PD5
#define SHUTTER_BIT PD6
#define LED_BIT PB5

/* Half of one step's period: the STEP line is high for one half and low for the other. */
#define HALF_STEP_US (500000UL / STEP_HZ)
#define MAX_FIRE_MS 60000UL
#define LINE_MAX 40

/* Position of the table in steps from home, in [0, STEPS_PER_TURN). */
static int32_t position;

/* ---- serial ---------------------------------------------------------------------------- */

/* Received bytes, filled by the interrupt so that nothing is lost while the table turns. */
static volatile uint8_t rx_buf[64];
static volatile uint8_t rx_head, rx_tail;

ISR(USART_RX_vect) {
    uint8_t c = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1) & 63);
    if (next != rx_tail) { /* a full buffer drops the byte: the line is then refused */
        rx_buf[rx_head] = c;
        rx_head = next;
    }
}

static void uart_init(void) {
    /* Double speed: 115200 baud at 16 MHz is UBRR 16, 2.1% off, which a USB adapter takes. */
    uint16_t ubrr = (uint16_t)((F_CPU + 4 * BAUD) / (8 * BAUD) - 1);
    UBRR0H = (uint8_t)(ubrr >> 8);
    UBRR0L = (uint8_t)ubrr;
    UCSR0A = _BV(U2X0);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00); /* 8N1 */
}

static void put_char(char c) {
    while (!(UCSR0A & _BV(UDRE0))) {
    }
    UDR0 = (uint8_t)c;
}

static void put_str(const char *s) {
    while (*s) put_char(*s++);
}

static void put_line(const char *s) {
    put_str(s);
    put_str("\r\n");
}

/* Takes one byte from the receive buffer, or -1; sleeps until one comes if `wait`. */
static int get_char(uint8_t wait) {
    for (;;) {
        cli();
        if (rx_head != rx_tail) {
            uint8_t c = rx_buf[rx_tail];
            rx_tail = (uint8_t)((rx_tail + 1) & 63);
            sei();
            return c;
        }
        if (!wait) {
            sei();
            return -1;
        }
        /* Idle sleep: the UART's receive interrupt wakes the CPU. sei then sleep, as the
         * datasheet pairs them, so that an interrupt between the check and the sleep is not
         * slept through. */
        sleep_enable();
        sei();
        sleep_cpu();
        sleep_disable();
    }
}

/* ---- numbers --------------------------------------------------------------------------- */

/* Writes a position in steps as degrees with two decimals ("315.00"). */
static void put_degrees(int32_t steps) {
    int32_t hundredths = (int32_t)(((int64_t)steps * 36000 + STEPS_PER_TURN / 2) / STEPS_PER_TURN);
    char buf[16];
    ltoa(hundredths / 100, buf, 10);
    put_str(buf);
    put_char('.');
    int32_t frac = hundredths % 100;
    put_char((char)('0' + frac / 10));
    put_char((char)('0' + frac % 10));
}

/* Parses a signed decimal ("-45", "12.5", "+0.25") into hundredths; 0 if it is not one. */
static uint8_t parse_hundredths(const char *s, int32_t *out) {
    int8_t sign = 1;
    if (*s == '-' || *s == '+') {
        if (*s == '-') sign = -1;
        s++;
    }
    int32_t whole = 0;
    uint8_t digits = 0;
    while (*s >= '0' && *s <= '9') {
        if (whole > 1000000L) return 0;
        whole = whole * 10 + (*s++ - '0');
        digits++;
    }
    int32_t frac = 0;
    uint8_t places = 0;
    if (*s == '.') {
        s++;
        while (*s >= '0' && *s <= '9') {
            if (places < 2) {
                frac = frac * 10 + (*s - '0');
                places++;
            }
            digits++;
            s++;
        }
    }
    if (*s != '\0' || digits == 0) return 0;
    while (places < 2) {
        frac *= 10;
        places++;
    }
    *out = sign * (whole * 100 + frac);
    return 1;
}

/* ---- the table ------------------------------------------------------------------------- */

static uint8_t at_home(void) { return !(PIND & _BV(HOME_BIT)); }

static void step_once(void) {
    PORTD |= _BV(STEP_BIT);
    _delay_us(HALF_STEP_US);
    PORTD &= (uint8_t)~_BV(STEP_BIT);
    _delay_us(HALF_STEP_US);
}

static void set_direction(uint8_t positive) {
    if (positive)
        PORTD |= _BV(DIR_BIT);
    else
        PORTD &= (uint8_t)~_BV(DIR_BIT);
    _delay_us(5); /* the drivers want the direction settled before the next step edge */
}

/* Turns by `steps` (signed) and keeps the position. */
static void turn_steps(int32_t steps) {
    set_direction(steps >= 0);
    int32_t n = steps >= 0 ? steps : -steps;
    PORTB |= _BV(LED_BIT);
    for (int32_t i = 0; i < n; i++) step_once();
    PORTB &= (uint8_t)~_BV(LED_BIT);
    position = (position + steps) % STEPS_PER_TURN;
    if (position < 0) position += STEPS_PER_TURN;
}

/* Turns the negative way until the switch closes, at most a turn and a tenth. */
static uint8_t home(void) {
    set_direction(0);
    PORTB |= _BV(LED_BIT);
    int32_t limit = STEPS_PER_TURN + STEPS_PER_TURN / 10;
    int32_t i = 0;
    while (!at_home() && i < limit) {
        step_once();
        i++;
    }
    PORTB &= (uint8_t)~_BV(LED_BIT);
    if (!at_home()) {
        /* Not found: the table has still turned, and the position says where to. */
        position = (position - i % STEPS_PER_TURN) % STEPS_PER_TURN;
        if (position < 0) position += STEPS_PER_TURN;
        return 0;
    }
    position = 0;
    return 1;
}

/* Holds the shutter for `ms` milliseconds, counted by Timer1 (a 1 kHz compare match) rather
 * than by a delay loop, whose overhead would add up over a long press. */
static void fire(uint16_t ms) {
    TCCR1A = 0;
    TCCR1B = _BV(WGM12) | _BV(CS11) | _BV(CS10); /* CTC, F_CPU / 64 */
    OCR1A = (uint16_t)(F_CPU / 64 / 1000 - 1);
    TCNT1 = 0;
    TIFR1 = _BV(OCF1A);
    PORTD |= _BV(SHUTTER_BIT);
    PORTB |= _BV(LED_BIT);
    for (uint16_t i = 0; i < ms; i++) {
        while (!(TIFR1 & _BV(OCF1A))) {
        }
        TIFR1 = _BV(OCF1A);
    }
    PORTD &= (uint8_t)~_BV(SHUTTER_BIT);
    PORTB &= (uint8_t)~_BV(LED_BIT);
    TCCR1B = 0;
}

/* ---- commands -------------------------------------------------------------------------- */

static void answer_position(void) {
    put_str("OK ");
    put_degrees(position);
    put_str("\r\n");
}

static void run(char *line) {
    char *arg = strchr(line, ' ');
    if (arg) {
        *arg++ = '\0';
        while (*arg == ' ') arg++;
    }
    if (strcmp(line, "ID?") == 0 && !arg) {
        put_line("OK brdfd-avr 1 FIRE ROT");
    } else if (strcmp(line, "POS?") == 0 && !arg) {
        answer_position();
    } else if (strcmp(line, "HOME") == 0 && !arg) {
        if (home())
            put_line("OK 0.00");
        else
            put_line("ERR home switch not found within a turn");
    } else if (strcmp(line, "ROT") == 0 && arg) {
        int32_t hundredths;
        if (!parse_hundredths(arg, &hundredths) || hundredths > 360000L || hundredths < -360000L) {
            put_line("ERR bad angle");
            return;
        }
        /* Rounded to the nearest step, the way it turns. */
        int64_t scaled = (int64_t)hundredths * STEPS_PER_TURN;
        int32_t steps = (int32_t)((scaled + (scaled >= 0 ? 18000 : -18000)) / 36000);
        turn_steps(steps);
        answer_position();
    } else if (strcmp(line, "FIRE") == 0 && arg) {
        char *end;
        unsigned long ms = strtoul(arg, &end, 10);
        if (*end != '\0' || ms < 1 || ms > MAX_FIRE_MS) {
            put_line("ERR bad duration");
            return;
        }
        fire((uint16_t)ms);
        put_line("OK");
    } else {
        put_line("ERR unknown command");
    }
}

int main(void) {
    DDRD |= _BV(STEP_BIT) | _BV(DIR_BIT) | _BV(ENABLE_BIT) | _BV(SHUTTER_BIT);
    PORTD &= (uint8_t)~(_BV(STEP_BIT) | _BV(SHUTTER_BIT) | _BV(ENABLE_BIT));
    PORTD |= _BV(HOME_BIT); /* pull-up: the switch pulls it low */
    DDRB |= _BV(LED_BIT);
    uart_init();
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
    put_line("# brdfd-avr 1 ready");

    char line[LINE_MAX + 1];
    uint8_t len = 0, overflow = 0;
    for (;;) {
        int c = get_char(1);
        if (c == '\r') continue;
        if (c == '\n') {
            line[len] = '\0';
            if (overflow)
                put_line("ERR line too long");
            else if (len > 0)
                run(line);
            len = 0;
            overflow = 0;
        } else if (len < LINE_MAX) {
            line[len++] = (char)c;
        } else {
            overflow = 1;
        }
    }
}
