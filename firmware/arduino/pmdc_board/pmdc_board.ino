/*
 * pmdc_board - reference firmware for the pmdc serial protocol v1.
 *
 * Hobby rig: Arduino Uno/Nano (ATmega328P, 16 MHz), BTS7960 H-bridge
 * (IBT-2 module), ACS712 current sensor, quadrature encoder, three resistor
 * dividers. All protocol logic (framing, handshake, rate negotiation,
 * clamping, watchdog, telemetry) lives in the portable core in src/
 * (a link to firmware/protocol/, tested on the host); this file only wires it to
 * the hardware. Wire format: docs/serial-protocol.md.
 *
 * Wiring (change the pins below to suit; the encoder must stay on D2/D3, the
 * PWM on D9/D10 and the EN line on PORTB, which this file drives directly):
 *   BTS7960 RPWM -> D9 (OC1A), LPWM -> D10 (OC1B), R_EN + L_EN -> D8
 *       (EN low = both half-bridges off = armature open, the motor coasts;
 *        0 V with EN high shorts the winding = dynamic braking)
 *   ACS712 OUT -> A0 (5 V supply; 185 mV/A for the 5 A part, 100 for 20 A, 66 for 30 A)
 *   supply divider -> A1, armature terminal dividers -> A2 (M+) and A3 (M-);
 *       each divider 100k / 10k with 100 nF across the 10k leg (a 1 ms low-pass:
 *       the terminals switch at the PWM frequency)
 *   encoder A -> D2 (INT0), B -> D3 (INT1), both with pull-ups
 *   D13 (LED) is high while a sample is taken and sent, D12 while a host byte is
 *   handled: a scope on them shows the CPU budget (the emulator measures it so).
 *
 * Build: Arduino IDE or arduino-cli (board arduino:avr:uno), or
 * `python3 firmware/emulator/build.py --baud 1000000` (what the tests run). If
 * your tool does not follow the src link, copy firmware/protocol/pmdc_protocol.{h,c}
 * into src/. Set PMDC_BAUD and PMDC_COUNTS_PER_REV below (or with -D).
 *
 * What this board can do, measured on the emulated Uno (firmware/emulator; the
 * command and the full table: docs/serial-protocol.md section 8):
 *   - one sample costs ~370 us of CPU (seven ADC conversions at a 1 MHz ADC clock,
 *     91 us, a random 0..48 us wait, framing, CRC and the UART); 750 us streamed
 *     without a drop until the encoder ran near its limit, so the board refuses
 *     periods below HW_MIN_PERIOD_US = 1000 us (1 kHz) whatever the baud. The line allows 2605 us
 *     at 115200, 1200 us at 250000, 600 us at 500000 and 300 us at 1000000 baud; the
 *     board announces the larger of the two (HELLO_ACK min_period_us), and the host
 *     refuses a faster rate in one line;
 *   - the sample instant: the encoder count is latched by Timer0's compare interrupt
 *     10..30 us after the grid instant the telemetry names, whatever the loop is doing
 *     (version 2 read it in the loop: up to 280 us late behind a host frame, a speed
 *     sample 28 % high at 1 kHz); the conversions start 30..100 us after it;
 *   - a new setpoint reaches the bridge at the next sample, right after its current
 *     conversions (150..240 us after the instant): applied_v is what the bridge holds
 *     over the period, as the host models it (version 2 switched mid-period); trips
 *     open it at once. A lone 0x00 precedes BOOT (a reset may cut a frame);
 *   - encoder: no missed count and no dropped sample up to MAX_EDGE_RATE = 100 000
 *     quadrature edges per second while streaming at 1000 us (the first missed count
 *     was at 106 000 edges/s). At the default 2048 counts/rev that is
 *     2 pi * 100000 / 2048 = 306 rad/s (2930 rpm); max speed = 2 pi * 100000 /
 *     counts_per_rev. Faster, the board trips OVER_SPEED (armature open) rather than
 *     report a wrong angle.
 */
#include <Arduino.h>
#include <avr/interrupt.h>
#include <avr/io.h>

extern "C" {
#include "src/pmdc_protocol.h"
}

/* ---- configuration ------------------------------------------------------------- */
#ifndef PMDC_BAUD
#define PMDC_BAUD 115200UL
#endif
#ifndef PMDC_COUNTS_PER_REV
#define PMDC_COUNTS_PER_REV 2048UL /* 512-line encoder, x4 decoding */
#endif
static const uint32_t BAUD = PMDC_BAUD;
static const uint32_t COUNTS_PER_REV = PMDC_COUNTS_PER_REV;
/* 3: counts latched at the sample instant, setpoints applied at a sample, 0x00 before BOOT */
static const uint16_t FIRMWARE_VERSION = 3;
/* The CPU's own limit (see the header): seven conversions + framing + the UART. */
static const uint32_t HW_MIN_PERIOD_US = 1000;
/* Quadrature edges per second the encoder interrupt follows while streaming at
 * the fastest period (see the header). */
static const uint32_t MAX_EDGE_RATE = 100000UL;
static const float SUPPLY_NOMINAL_V = 24.0f;
static const float VOLTAGE_MAX_V = 24.0f;
static const float CURRENT_MAX_A = 20.0f;        /* over-current trip */
static const float ACS712_V_PER_A = 0.100f;      /* 20 A part */
static const float ADC_VREF = 5.0f;
static const float DIVIDER_RATIO = 11.0f;        /* 100k / 10k: 0..55 V -> 0..5 V */
static const float SUPPLY_MIN_V = 6.0f;          /* below: SUPPLY fault, armature open */
static const uint8_t CURRENT_OVERSAMPLE = 4;     /* conversions averaged: one PWM period */
static const float CURRENT_LSB_A = 0.01f;        /* telemetry units (HELLO_ACK) */
static const float VOLTAGE_LSB_V = 0.01f;
/* ADC counts -> telemetry LSBs in fixed point (no float division on the sample path):
 * current: (sum of CURRENT_OVERSAMPLE readings - zero) * CURRENT_Q15 / 2^15,
 * voltage: reading * VOLTAGE_Q13 / 2^13. */
static const int32_t CURRENT_Q15 =
    (int32_t)(ADC_VREF / 1023.0f / CURRENT_OVERSAMPLE / ACS712_V_PER_A / CURRENT_LSB_A * 32768.0f +
              0.5f);
static const int32_t VOLTAGE_Q13 =
    (int32_t)(ADC_VREF / 1023.0f * DIVIDER_RATIO / VOLTAGE_LSB_V * 8192.0f + 0.5f);
static const int16_t CURRENT_MAX_Q = (int16_t)(CURRENT_MAX_A / CURRENT_LSB_A);
static const int16_t SUPPLY_MIN_Q = (int16_t)(SUPPLY_MIN_V / VOLTAGE_LSB_V);
static const int16_t SUPPLY_NOMINAL_Q = (int16_t)(SUPPLY_NOMINAL_V / VOLTAGE_LSB_V);

/* Pins, as port bits (the wiring above): D8 = PB0, D9 = PB1 (OC1A), D10 = PB2 (OC1B),
 * D12 = PB4, D13 = PB5; D2 = PD2 (INT0), D3 = PD3 (INT1); A0..A3 = ADC0..3. */
#define EN_BIT _BV(PB0)
#define RPWM_BIT _BV(PB1)
#define LPWM_BIT _BV(PB2)
#define CAPTURE_BIT _BV(PB3)
#define RX_BUSY_BIT _BV(PB4)
#define SAMPLE_BUSY_BIT _BV(PB5)
static const uint8_t ADC_CURRENT = 0, ADC_SUPPLY = 1, ADC_TERM_P = 2, ADC_TERM_N = 3;
/* Timer1 fast PWM, TOP = ICR1: 16 MHz / 800 = 20 kHz, 800 duty steps. */
static const uint16_t PWM_PERIOD = 800;
/* Faults that open the bridge at once, not at the next sample. */
static const uint8_t TRIP_FAULTS = PMDC_FAULT_OVER_CURRENT | PMDC_FAULT_OVER_SPEED |
                                   PMDC_FAULT_WATCHDOG | PMDC_FAULT_SUPPLY |
                                   PMDC_FAULT_BAD_COMMAND;

/* ---- state --------------------------------------------------------------------- */
static pmdc_board_t board;
static uint8_t sampling = 0; /* streaming: the capture interrupt is armed */
static uint32_t next_instant_us = 0; /* the next grid instant (the loop's copy) */
static int32_t last_count = 0;
static uint32_t edge_period_us = 0, max_edges = 0; /* encoder edges allowed per period */
static uint16_t current_zero_adc4 = 4 * 512; /* sum of CURRENT_OVERSAMPLE zero readings */
static uint8_t tx[PMDC_MAX_WIRE * 4];
static int16_t bridge_top = -1; /* last duty programmed, in PWM steps; -1 = open */
static int8_t bridge_dir = 0;
static int32_t bridge_mv = INT32_MIN; /* the request behind bridge_top */
static int16_t bridge_supply_q = -1;
static int16_t supply_q = 2400; /* measured supply, voltage LSBs */

/* ---- encoder: x4 quadrature decoding on both edges of A and B -------------------
 * One direct read of PIND (A = bit 2, B = bit 3; digitalRead costs ~50 cycles a pin)
 * and a 16-bit counter (the sample extends it to 32 bits: fewer registers to save
 * than a 32-bit add). The state index is (previous << 2) | current, each (B << 1) | A.
 * Read by the emulator (firmware/emulator) to check for missed counts: keep the name. */
extern "C" {
volatile int16_t pmdc_encoder_count __attribute__((used)) = 0;
}
static volatile uint8_t enc_prev = 0; /* previous state, shifted left by 2 */
static const int8_t enc_table[16] = {0, 1, -1, 0, -1, 0, 0, 1, 1, 0, 0, -1, 0, -1, 1, 0};
static int32_t encoder_total = 0;  /* the 32-bit count, extended at each sample */
static int16_t encoder_seen = 0;
ISR(INT0_vect)
{
    uint8_t idx = (uint8_t)(enc_prev | ((uint8_t)(PIND >> 2) & 3));
    enc_prev = (uint8_t)((uint8_t)(idx << 2) & 0x0C);
    int8_t d = enc_table[idx];
    if (d > 0) {
        pmdc_encoder_count++;
    } else if (d < 0) {
        pmdc_encoder_count--;
    }
}
ISR(INT1_vect, ISR_ALIASOF(INT0_vect));

/* ---- the sample instant: the encoder count latched by a timer interrupt ------------
 * A sample is the state at its grid instant (docs/serial-protocol.md). The loop cannot
 * promise to be there: a host frame's last byte costs up to ~330 us (decode, CRC,
 * reply), and a count read that late is a speed 1/3 too high at 1 kHz. Timer0 (the
 * core's micros() clock: 4 us ticks, turning every 1024 us) runs in normal mode, so its
 * compare-B register takes effect at once; its interrupt fires at the tick of the next
 * instant and latches the count (D11 pulses: a scope, or the emulator, times it). The
 * loop converts and sends it, and completes no host frame within GUARD_US of an instant,
 * so the conversions start on time too. */
static const uint16_t GUARD_US = 400; /* > the longest frame handling (~360 us) */
static volatile uint32_t cap_due = 0, cap_period = 0, cap_t = 0;
static volatile int16_t cap_count = 0;
static volatile uint8_t cap_n = 0; /* instants so far (wraps); the loop compares */
static volatile uint8_t cap_skip = 0; /* compare matches (timer turns) before the instant */
static uint8_t cap_seen = 0;

/* Arm the compare for the instant after `due` (both in micros(); ticks = us / 4). The
 * match comes every 256 ticks: the turns before the instant's are skipped. */
static inline void capture_next(uint32_t due)
{
    uint32_t next = due + cap_period;
    cap_skip = (uint8_t)(((next >> 2) - (due >> 2) - 1) >> 8);
    cap_due = next;
    OCR0B = (uint8_t)(next >> 2);
}

/* Interruptible but for the latch: an encoder edge arriving meanwhile is served at
 * once (two edges waiting for a long interrupt would be a missed count, at 10 us apart
 * near the encoder limit). Nothing else touches cap_* while it runs. */
ISR(TIMER0_COMPB_vect, ISR_NOBLOCK)
{
    if (cap_skip) {
        cap_skip--;
        return;
    }
    cli();
    PORTB |= CAPTURE_BIT;
    cap_count = pmdc_encoder_count;
    PORTB &= (uint8_t)~CAPTURE_BIT;
    sei();
    uint32_t due = cap_due;
    cap_t = due;
    cap_n++;
    capture_next(due);
}

/* START_STREAM: sample 0 is now, the grid follows from it. */
static void capture_start(uint32_t period_us)
{
    uint8_t sreg = SREG;
    cli();
    uint32_t t = micros(); /* a whole tick: t / 4 is Timer0's count */
    PORTB |= CAPTURE_BIT;
    cap_count = pmdc_encoder_count;
    cap_t = t;
    cap_seen = cap_n;
    cap_n++;
    cap_period = period_us;
    capture_next(t);
    TIFR0 = _BV(OCF0B); /* a match already pending belongs to no instant */
    TIMSK0 |= _BV(OCIE0B);
    PORTB &= (uint8_t)~CAPTURE_BIT;
    SREG = sreg;
    next_instant_us = t;
}

static void capture_stop()
{
    uint8_t sreg = SREG;
    cli();
    TIMSK0 &= (uint8_t)~_BV(OCIE0B);
    SREG = sreg;
}

/* ---- UART: a lean interrupt-driven driver in place of the core's Serial ----------
 * HardwareSerial costs ~10 us of CPU per byte sent (write + its UDRE interrupt): a
 * quarter of the CPU for 1 kHz telemetry. These two interrupts cost ~2 us a byte. */
#define RX_RING 64  /* powers of two */
#define TX_RING 128
static volatile uint8_t rx_ring[RX_RING], tx_ring[TX_RING];
static volatile uint8_t rx_head, rx_tail, tx_head, tx_tail;

ISR(USART_RX_vect)
{
    uint8_t c = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1) & (RX_RING - 1));
    if (next != rx_tail) { /* full: the byte is lost (the CRC will tell) */
        rx_ring[rx_head] = c;
        rx_head = next;
    }
}

ISR(USART_UDRE_vect)
{
    uint8_t t = tx_tail;
    UDR0 = tx_ring[t];
    t = (uint8_t)((t + 1) & (TX_RING - 1));
    tx_tail = t;
    if (t == tx_head) UCSR0B &= (uint8_t)~_BV(UDRIE0);
}

static void uart_begin(uint32_t baud)
{
    /* double speed, as the Arduino core sets it: 115200 is 117647 (+2.1 %) at 16 MHz */
    uint16_t ubrr = (uint16_t)((F_CPU / 4 / baud - 1) / 2);
    UCSR0A = _BV(U2X0);
    UBRR0 = ubrr;
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00); /* 8N1 */
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

static void uart_write(const uint8_t *data, size_t n)
{
    for (size_t k = 0; k < n; ++k) {
        uint8_t next = (uint8_t)((tx_head + 1) & (TX_RING - 1));
        while (next == tx_tail) { /* full: wait for the line */
        }
        tx_ring[tx_head] = data[k];
        uint8_t sreg = SREG;
        cli();
        tx_head = next;
        UCSR0B |= _BV(UDRIE0);
        SREG = sreg;
    }
}

static int16_t uart_peek() { return rx_head == rx_tail ? -1 : rx_ring[rx_tail]; }

static void uart_drop() { rx_tail = (uint8_t)((rx_tail + 1) & (RX_RING - 1)); }

/* ---- ADC: 1 MHz ADC clock (prescaler 16): 13 us a conversion instead of the
 * Arduino core's 104 us (prescaler 128). About 9 effective bits instead of 10. */
static uint16_t adc_read(uint8_t channel)
{
    ADMUX = _BV(REFS0) | (channel & 0x07); /* AVcc reference */
    ADCSRA |= _BV(ADSC);
    while (ADCSRA & _BV(ADSC)) {
    }
    return ADC;
}

static int16_t volts_q(int16_t counts) { return (int16_t)(((int32_t)counts * VOLTAGE_Q13 + 4096) >> 13); }

/* The mean of CURRENT_OVERSAMPLE back-to-back conversions (13 us apart): they span one
 * 50 us PWM period, so most of the switching ripple of the armature current averages
 * out. What is left depends on where in the PWM period they start, and a sample period
 * that is a multiple of 50 us would start them at the same place every time: a bias
 * (+0.07 A at 12 V on the emulated rig). A random wait of 0..48 us first turns it into
 * zero-mean noise. */
static uint8_t phase_rand = 0x5A;
static uint16_t current_sum()
{
    phase_rand ^= (uint8_t)(phase_rand << 3); /* xorshift: period 255 */
    phase_rand ^= (uint8_t)(phase_rand >> 5);
    phase_rand ^= (uint8_t)(phase_rand << 4);
    for (uint8_t k = phase_rand & 63; k; --k) { /* ~12 cycles a turn */
        __asm__ __volatile__("nop\n\tnop\n\tnop\n\tnop\n\tnop\n\tnop\n\tnop\n\tnop\n\t");
    }
    uint16_t sum = 0;
    for (uint8_t k = 0; k < CURRENT_OVERSAMPLE; ++k) sum += adc_read(ADC_CURRENT);
    return sum;
}

/* ---- bridge: sign-magnitude PWM, one half-bridge switching, the other held low --- */
static void bridge_open()
{
    PORTB &= (uint8_t)~EN_BIT;
    TCCR1A = _BV(WGM11); /* both outputs disconnected from the timer */
    PORTB &= (uint8_t)~(RPWM_BIT | LPWM_BIT);
    bridge_top = -1;
    bridge_dir = 0;
    bridge_mv = INT32_MIN;
}

/* mv at the measured supply (in voltage LSBs); called every loop, works only on a change. */
static void bridge_apply(int32_t mv, int16_t supply_q)
{
    if (mv == bridge_mv && supply_q == bridge_supply_q && bridge_top >= 0) return;
    bridge_mv = mv;
    bridge_supply_q = supply_q;
    int32_t supply_mv = (int32_t)supply_q * (int32_t)(VOLTAGE_LSB_V * 1000.0f + 0.5f);
    int8_t dir = mv >= 0 ? 1 : -1;
    int32_t mag = mv >= 0 ? mv : -mv;
    int16_t top = mag >= supply_mv ? (int16_t)PWM_PERIOD
                                   : (int16_t)((mag * (int32_t)PWM_PERIOD + supply_mv / 2) / supply_mv);
    if (top == bridge_top && dir == bridge_dir) return;
    uint8_t pwm_bit = dir > 0 ? RPWM_BIT : LPWM_BIT;
    uint8_t com = dir > 0 ? _BV(COM1A1) : _BV(COM1B1);
    if (top <= 0) {
        TCCR1A = _BV(WGM11); /* 0 %: both low sides on (brake), no 1-tick spike */
        PORTB &= (uint8_t)~(RPWM_BIT | LPWM_BIT);
    } else if (top >= (int16_t)PWM_PERIOD) {
        TCCR1A = _BV(WGM11); /* 100 %: held high */
        PORTB = (uint8_t)((PORTB & ~(RPWM_BIT | LPWM_BIT)) | pwm_bit);
    } else {
        /* fast PWM: high for OCR + 1 of the PWM_PERIOD timer steps */
        if (dir > 0) OCR1A = (uint16_t)(top - 1);
        else OCR1B = (uint16_t)(top - 1);
        PORTB &= (uint8_t)~(RPWM_BIT | LPWM_BIT);
        TCCR1A = (uint8_t)(_BV(WGM11) | com);
    }
    PORTB |= EN_BIT;
    bridge_top = top;
    bridge_dir = dir;
}

/* ---- setup / loop -------------------------------------------------------------- */
void setup()
{
    DDRB |= EN_BIT | RPWM_BIT | LPWM_BIT | CAPTURE_BIT | RX_BUSY_BIT | SAMPLE_BUSY_BIT;
    bridge_open(); /* first thing: the winding is disconnected */
    /* Timer1: fast PWM, TOP = ICR1 (mode 14), no prescaler -> 20 kHz on OC1A/OC1B */
    ICR1 = PWM_PERIOD - 1;
    OCR1A = 0;
    OCR1B = 0;
    TCCR1A = _BV(WGM11);
    TCCR1B = _BV(WGM13) | _BV(WGM12) | _BV(CS10);
    /* Timer0: normal mode (the core set fast PWM, for analogWrite on D5/D6, which this
     * sketch does not use): same 0..255 count and overflow for micros(), and OCR0B
     * writes take effect at once (the sample instants). */
    TCCR0A = 0;

    /* encoder: inputs with pull-ups, INT0/INT1 on any change */
    DDRD &= (uint8_t)~(_BV(PD2) | _BV(PD3));
    PORTD |= _BV(PD2) | _BV(PD3);
    enc_prev = (uint8_t)(((PIND >> 2) & 3) << 2);
    EICRA = _BV(ISC00) | _BV(ISC10);
    EIFR = _BV(INTF0) | _BV(INTF1);
    EIMSK = _BV(INT0) | _BV(INT1);

    /* ADC: enabled, prescaler 16 */
    ADCSRA = _BV(ADEN) | _BV(ADPS2);
    (void)adc_read(ADC_CURRENT); /* the first conversion after enabling takes 25 clocks */

    supply_q = volts_q((int16_t)adc_read(ADC_SUPPLY));
    /* current sensor zero with the armature open */
    uint32_t sum = 0;
    for (uint8_t i = 0; i < 16; ++i) sum += current_sum();
    current_zero_adc4 = (uint16_t)((sum + 8) / 16);

    pmdc_hello_ack_t info;
    memset(&info, 0, sizeof info);
    info.protocol_version = PMDC_PROTOCOL_VERSION;
    info.capabilities = PMDC_CAP_TERMINAL_VOLTAGE | PMDC_CAP_SUPPLY_VOLTAGE |
                        PMDC_CAP_OPEN_ARMATURE | PMDC_CAP_CURRENT;
    info.firmware_version = FIRMWARE_VERSION;
    /* 27-byte telemetry frames may use 90 % of the line (docs/serial-protocol.md) */
    uint32_t baud_min_us = (uint32_t)((27UL * 10UL * 1000000UL + BAUD * 9 / 10 - 1) /
                                      (BAUD * 9 / 10));
    info.min_period_us = baud_min_us > HW_MIN_PERIOD_US ? baud_min_us : HW_MIN_PERIOD_US;
    info.counts_per_rev = COUNTS_PER_REV;
    info.current_lsb_a = CURRENT_LSB_A;
    info.voltage_lsb_v = VOLTAGE_LSB_V;
    info.supply_nominal_v = SUPPLY_NOMINAL_V;
    info.voltage_max_v = VOLTAGE_MAX_V;
    pmdc_board_init(&board, &info);

    uart_begin(BAUD);
    /* A lone delimiter first: a reset may have cut a frame on the line, and the host's
     * parser would join its bytes to the BOOT frame and drop both (bad CRC); it then
     * learns of the reset only when its link times out. */
    const uint8_t delimiter = 0;
    uart_write(&delimiter, 1);
    size_t n = pmdc_board_boot(&board, tx);
    uart_write(tx, n);
}

/* One sample: the count latched at instant t, current, voltages; protections; the frame. */
static void take_sample(uint32_t t, int16_t raw)
{
    PORTB |= SAMPLE_BUSY_BIT;
    encoder_total += (int16_t)(raw - encoder_seen); /* wraps: fine below 32767 a period */
    encoder_seen = raw;
    int32_t count = encoder_total;
    int16_t raw_i = (int16_t)current_sum();
    /* The bridge takes a new setpoint here, once this sample's current is in: the
     * applied_v this sample reports is what the bridge holds until the next one (the
     * zero-order hold the host models), not a change somewhere inside the period. */
    int32_t mv;
    int driven = pmdc_board_setpoint_mv(&board, &mv);
    if (driven) {
        bridge_apply(mv, supply_q > SUPPLY_MIN_Q ? supply_q : SUPPLY_NOMINAL_Q);
    } else if (bridge_top >= 0) {
        bridge_open();
    }
    supply_q = volts_q((int16_t)adc_read(ADC_SUPPLY));
    int16_t term_p = (int16_t)adc_read(ADC_TERM_P), term_n = (int16_t)adc_read(ADC_TERM_N);
    int16_t current_q =
        (int16_t)(((int32_t)(raw_i - (int16_t)current_zero_adc4) * CURRENT_Q15 + 16384) >> 15);
    /* An open winding floats: its dividers cannot measure it against ground. */
    int16_t terminal_q = driven ? volts_q((int16_t)(term_p - term_n)) : (int16_t)PMDC_NOT_MEASURED;
    if (current_q > CURRENT_MAX_Q || current_q < -CURRENT_MAX_Q) {
        pmdc_board_trip(&board, PMDC_FAULT_OVER_CURRENT);
    }
    /* Faster than the encoder interrupt follows: the angle would be wrong. */
    if (board.period_us != edge_period_us) { /* once per stream: no 64-bit math per sample */
        edge_period_us = board.period_us;
        max_edges = (MAX_EDGE_RATE / 100UL) * (edge_period_us / 100UL) / 100UL + 1;
    }
    uint32_t edges = (uint32_t)labs(count - last_count);
    if (board.counter != 0 && edges > max_edges) { /* not across streams */
        pmdc_board_trip(&board, PMDC_FAULT_OVER_SPEED);
    }
    last_count = count;
    if (driven && supply_q < SUPPLY_MIN_Q) pmdc_board_trip(&board, PMDC_FAULT_SUPPLY);
    size_t n = pmdc_board_telemetry_q(&board, t, count, current_q, terminal_q, supply_q, tx);
    uart_write(tx, n);
    PORTB &= (uint8_t)~SAMPLE_BUSY_BIT;
}

void loop()
{
    uint32_t now = micros();

    /* 1. samples on an exact grid (next += period, never now + period: no drift), the
     * count latched by the timer at the instant. A board more than one period late
     * skips the missed instants (the host sees the counter gap as dropped samples)
     * instead of falling behind for good. */
    if (sampling && cap_n != cap_seen) {
        noInterrupts();
        int16_t raw = cap_count;
        uint32_t t = cap_t;
        uint8_t n = cap_n;
        interrupts();
        for (uint8_t k = (uint8_t)(n - cap_seen - 1); k; --k) pmdc_board_skip_sample(&board);
        cap_seen = n;
        next_instant_us = t + board.period_us;
        take_sample(t, raw);
        now = micros();
    }

    /* 2. one host byte -> protocol core -> replies. A frame's last byte (the 0x00
     * delimiter: decode, CRC, the command, a reply) waits in the ring while an instant
     * is near, so the conversions of a sample start on time; the others cost a few us. */
    int16_t in = uart_peek();
    if (in == 0 && sampling && (int32_t)(next_instant_us - now) <= (int32_t)GUARD_US) in = -1;
    if (in >= 0) {
        uart_drop();
        PORTB |= RX_BUSY_BIT;
        uint8_t byte = (uint8_t)in;
        uint8_t was_streaming = board.streaming;
        uint32_t counter = board.counter;
        size_t n = pmdc_board_receive(&board, &byte, 1, now, tx, sizeof tx);
        if (n) uart_write(tx, n);
        if (board.streaming && (!was_streaming || (board.counter == 0 && counter != 0))) {
            capture_start(board.period_us); /* START_STREAM: sample 0 now, then the grid */
            sampling = 1;
        } else if (!board.streaming && sampling) {
            capture_stop();
            sampling = 0;
        }
        PORTB &= (uint8_t)~RX_BUSY_BIT;
    }

    /* 3. board-side watchdog, then the bridge follows the setpoint: while streaming at
     * the next sample (take_sample), but a trip opens it at once */
    pmdc_board_check_watchdog(&board, now);
    int32_t mv;
    if (pmdc_board_setpoint_mv(&board, &mv)) {
        if (!sampling) bridge_apply(mv, supply_q > SUPPLY_MIN_Q ? supply_q : SUPPLY_NOMINAL_Q);
    } else if (bridge_top >= 0 && (!sampling || (board.faults & TRIP_FAULTS))) {
        bridge_open();
    }
}
