/*
 * pmdc_board - reference firmware for the pmdc serial protocol v1.
 *
 * Hobby rig: Arduino Uno/Nano (ATmega328P, 16 MHz), BTS7960 H-bridge
 * (IBT-2 module), ACS712 current sensor, quadrature encoder, two resistor
 * dividers. All protocol logic (framing, handshake, rate negotiation,
 * clamping, watchdog, telemetry) lives in the portable core in src/
 * (a link to firmware/protocol/, tested on the host); this file only wires it to
 * the hardware. Wire format: docs/serial-protocol.md.
 *
 * Wiring (change the pins below to suit):
 *   BTS7960 RPWM -> D9 (OC1A), LPWM -> D10 (OC1B), R_EN + L_EN -> D8
 *       (EN low = both half-bridges off = armature open, the motor coasts;
 *        0 V with EN high shorts the winding = dynamic braking)
 *   ACS712 OUT -> A0 (5 V supply; 185 mV/A for the 5 A part, 100 for 20 A, 66 for 30 A)
 *   supply divider -> A1, armature terminal dividers -> A2 (M+) and A3 (M-)
 *   encoder A -> D2 (INT0), B -> D3 (INT1), both with pull-ups
 * Build: Arduino IDE or arduino-cli (board arduino:avr:uno). If your tool does
 * not follow the src link, copy firmware/protocol/pmdc_protocol.{h,c} into src/.
 */
#include <Arduino.h>

extern "C" {
#include "src/pmdc_protocol.h"
}

/* ---- configuration ------------------------------------------------------------- */
static const uint32_t BAUD = 115200;
static const uint16_t FIRMWARE_VERSION = 1;
static const uint32_t HW_MIN_PERIOD_US = 1000;  /* 4 ADC reads + framing fit in 1 ms */
static const uint32_t COUNTS_PER_REV = 4 * 1024; /* 1024-line encoder, x4 decoding */
static const float SUPPLY_NOMINAL_V = 24.0f;
static const float VOLTAGE_MAX_V = 24.0f;
static const float CURRENT_MAX_A = 20.0f;        /* over-current trip */
static const float ACS712_V_PER_A = 0.100f;      /* 20 A part */
static const float ADC_VREF = 5.0f;
static const float DIVIDER_RATIO = 11.0f;        /* 100k / 10k: 0..55 V -> 0..5 V */
static const float SUPPLY_MIN_V = 6.0f;          /* below: SUPPLY fault, armature open */

static const uint8_t PIN_RPWM = 9, PIN_LPWM = 10, PIN_EN = 8;
static const uint8_t PIN_ENC_A = 2, PIN_ENC_B = 3;
static const uint8_t PIN_CURRENT = A0, PIN_SUPPLY = A1, PIN_TERM_P = A2, PIN_TERM_N = A3;
static const uint16_t PWM_TOP = 400;             /* 16 MHz / (2 * 400) = 20 kHz */

/* ---- state --------------------------------------------------------------------- */
static pmdc_board_t board;
static volatile int32_t encoder_count = 0;
static uint32_t next_sample_us = 0;
static int16_t current_zero_adc = 512;
static uint8_t tx[PMDC_MAX_WIRE * 4];

/* ---- encoder: x4 quadrature decoding on both edges of A and B ------------------- */
static volatile uint8_t enc_state = 0;
static void encoder_isr()
{
    static const int8_t table[16] = {0, -1, 1, 0, 1, 0, 0, -1, -1, 0, 0, 1, 0, 1, -1, 0};
    uint8_t s = (uint8_t)((digitalRead(PIN_ENC_A) << 1) | digitalRead(PIN_ENC_B));
    enc_state = (uint8_t)(((enc_state << 2) | s) & 0x0F);
    encoder_count += table[enc_state];
}

/* ---- bridge -------------------------------------------------------------------- */
static void bridge_open()
{
    digitalWrite(PIN_EN, LOW);
    OCR1A = 0;
    OCR1B = 0;
}

static void bridge_apply(int32_t mv, float supply_v)
{
    /* duty = V / supply, sign-magnitude on the two half-bridges */
    float duty = (float)mv / 1000.0f / supply_v;
    if (duty > 1.0f) duty = 1.0f;
    if (duty < -1.0f) duty = -1.0f;
    uint16_t top = (uint16_t)((duty >= 0 ? duty : -duty) * PWM_TOP + 0.5f);
    OCR1A = duty >= 0 ? top : 0;
    OCR1B = duty >= 0 ? 0 : top;
    digitalWrite(PIN_EN, HIGH);
}

static float adc_volts(uint8_t pin) { return analogRead(pin) * (ADC_VREF / 1023.0f); }

/* ---- setup / loop -------------------------------------------------------------- */
void setup()
{
    pinMode(PIN_EN, OUTPUT);
    bridge_open(); /* first thing: the winding is disconnected */
    pinMode(PIN_RPWM, OUTPUT);
    pinMode(PIN_LPWM, OUTPUT);
    /* Timer1: phase-correct PWM, TOP = ICR1, no prescaler -> 20 kHz on OC1A/OC1B */
    TCCR1A = _BV(COM1A1) | _BV(COM1B1) | _BV(WGM11);
    TCCR1B = _BV(WGM13) | _BV(CS10);
    ICR1 = PWM_TOP;
    OCR1A = 0;
    OCR1B = 0;

    pinMode(PIN_ENC_A, INPUT_PULLUP);
    pinMode(PIN_ENC_B, INPUT_PULLUP);
    attachInterrupt(digitalPinToInterrupt(PIN_ENC_A), encoder_isr, CHANGE);
    attachInterrupt(digitalPinToInterrupt(PIN_ENC_B), encoder_isr, CHANGE);

    /* current sensor zero with the armature open */
    long sum = 0;
    for (int i = 0; i < 64; ++i) sum += analogRead(PIN_CURRENT);
    current_zero_adc = (int16_t)(sum / 64);

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
    info.current_lsb_a = 0.01f;
    info.voltage_lsb_v = 0.01f;
    info.supply_nominal_v = SUPPLY_NOMINAL_V;
    info.voltage_max_v = VOLTAGE_MAX_V;
    pmdc_board_init(&board, &info);

    Serial.begin(BAUD);
    size_t n = pmdc_board_boot(&board, tx);
    Serial.write(tx, n);
}

void loop()
{
    /* 1. host bytes -> protocol core -> replies */
    uint32_t now = micros();
    while (Serial.available() > 0) {
        uint8_t byte = (uint8_t)Serial.read();
        size_t n = pmdc_board_receive(&board, &byte, 1, now, tx, sizeof tx);
        if (n) Serial.write(tx, n);
        if (board.streaming && next_sample_us == 0) next_sample_us = now;
    }
    if (!board.streaming) {
        next_sample_us = 0;
    }

    /* 2. board-side watchdog, then apply the setpoint */
    pmdc_board_check_watchdog(&board, now);
    float supply_v = adc_volts(PIN_SUPPLY) * DIVIDER_RATIO;
    int32_t mv;
    if (supply_v < SUPPLY_MIN_V && pmdc_board_setpoint_mv(&board, &mv)) {
        pmdc_board_trip(&board, PMDC_FAULT_SUPPLY);
    }
    if (pmdc_board_setpoint_mv(&board, &mv)) {
        bridge_apply(mv, supply_v > SUPPLY_MIN_V ? supply_v : SUPPLY_NOMINAL_V);
    } else {
        bridge_open();
    }

    /* 3. samples on an exact grid: next += period, never now + period (no drift) */
    if (board.streaming && next_sample_us != 0 && (int32_t)(now - next_sample_us) >= 0) {
        uint32_t t = next_sample_us;
        next_sample_us += board.period_us;
        noInterrupts();
        int32_t count = encoder_count;
        interrupts();
        float current_a =
            (float)(analogRead(PIN_CURRENT) - current_zero_adc) * (ADC_VREF / 1023.0f) /
            ACS712_V_PER_A;
        float terminal_v = (adc_volts(PIN_TERM_P) - adc_volts(PIN_TERM_N)) * DIVIDER_RATIO;
        if (current_a > CURRENT_MAX_A || current_a < -CURRENT_MAX_A) {
            pmdc_board_trip(&board, PMDC_FAULT_OVER_CURRENT);
            bridge_open();
        }
        size_t n = pmdc_board_telemetry(&board, t, count, current_a, terminal_v, supply_v, tx);
        Serial.write(tx, n);
    }
}
