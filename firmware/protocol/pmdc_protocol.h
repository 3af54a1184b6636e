/*
 * pmdc serial protocol v1 - portable C core (C99, no allocation, no I/O).
 *
 * Wire format: docs/serial-protocol.md. A frame is
 *     COBS(payload | crc16_le(payload)) | 0x00
 * with payload = type (u8) | seq (u8) | body (little-endian fixed struct) and
 * CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF). The same code runs on an
 * Arduino (firmware/arduino/pmdc_board) and in the host tests
 * (firmware/test), where it is checked byte for byte against the Python
 * implementation (pmdc_ident/protocol).
 *
 * The board state machine (pmdc_board_*) holds all protocol logic: handshake,
 * stream-rate negotiation, command handling with clamping, the board-side
 * watchdog and telemetry framing. The sketch only wires it to the UART, the
 * timer, the H-bridge and the sensors.
 */
#ifndef PMDC_PROTOCOL_H
#define PMDC_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define PMDC_PROTOCOL_VERSION 1u
#define PMDC_MAX_PAYLOAD 64u                      /* type + seq + body, no CRC */
#define PMDC_MAX_ENCODED (PMDC_MAX_PAYLOAD + 4u)  /* + CRC + COBS code + delimiter */
#define PMDC_MAX_WIRE (PMDC_MAX_ENCODED + 2u)
#define PMDC_NOT_MEASURED (-32768)
#define PMDC_DEFAULT_WATCHDOG_MS 500u

/* Message types: host -> board below 0x80, board -> host from 0x80. */
enum {
    PMDC_HELLO = 0x01,
    PMDC_START_STREAM = 0x02,
    PMDC_STOP_STREAM = 0x03,
    PMDC_SET_VOLTAGE = 0x04,
    PMDC_SET_DUTY = 0x05,
    PMDC_OPEN_ARMATURE = 0x06,
    PMDC_PING = 0x07,
    PMDC_ACK = 0x80,
    PMDC_HELLO_ACK = 0x81,
    PMDC_TELEMETRY = 0x82,
    PMDC_PONG = 0x87,
    PMDC_ERROR = 0x8E,
    PMDC_BOOT = 0x8F
};

/* ERROR reply codes. */
enum {
    PMDC_ERR_UNKNOWN_TYPE = 1,
    PMDC_ERR_BAD_LENGTH = 2,
    PMDC_ERR_VERSION = 3,
    PMDC_ERR_RATE_TOO_HIGH = 4, /* detail: shortest accepted period, us */
    PMDC_ERR_NOT_READY = 5,
    PMDC_ERR_BAD_VALUE = 6
};

/* Telemetry fault bits (pmdc_ident.backends.base.Fault). */
enum {
    PMDC_FAULT_OVER_CURRENT = 1,
    PMDC_FAULT_OVER_SPEED = 2,
    PMDC_FAULT_WATCHDOG = 4,
    PMDC_FAULT_SUPPLY = 8,
    PMDC_FAULT_CLAMPED = 16,
    PMDC_FAULT_BAD_COMMAND = 32,
    PMDC_FAULT_LINK = 64
};

/* HELLO_ACK capability bits. */
enum {
    PMDC_CAP_TERMINAL_VOLTAGE = 1,
    PMDC_CAP_SUPPLY_VOLTAGE = 2,
    PMDC_CAP_OPEN_ARMATURE = 4,
    PMDC_CAP_CURRENT = 8
};

/* Decode results (negative = error). */
enum { PMDC_OK = 0, PMDC_E_TYPE = -1, PMDC_E_LENGTH = -2, PMDC_E_COBS = -3, PMDC_E_CRC = -4 };

typedef struct {
    uint8_t protocol_version;
    uint8_t capabilities;
    uint16_t firmware_version;
    uint32_t min_period_us;
    uint32_t counts_per_rev;
    float current_lsb_a;
    float voltage_lsb_v;
    float supply_nominal_v;
    float voltage_max_v;
} pmdc_hello_ack_t;

typedef struct {
    uint32_t counter;
    uint32_t time_us;
    int32_t encoder_count;
    int16_t current;
    int16_t applied_v;
    int16_t terminal_v;
    int16_t supply_v;
    uint8_t faults;
} pmdc_telemetry_t;

typedef struct {
    uint8_t type;
    uint8_t seq;
    union {
        struct { uint8_t host_version; } hello;
        struct { uint32_t period_us; uint16_t watchdog_ms; } start_stream;
        struct { int32_t millivolts; } set_voltage;
        struct { int16_t duty_q15; } set_duty;
        struct { uint32_t token; } ping;
        struct { uint8_t acked_type; } ack;
        pmdc_hello_ack_t hello_ack;
        pmdc_telemetry_t telemetry;
        struct { uint32_t token; uint32_t time_us; } pong;
        struct { uint8_t refused_type; uint8_t code; uint32_t detail; } error;
        struct { uint8_t protocol_version; uint16_t firmware_version; } boot;
    } u;
} pmdc_msg_t;

/* -- framing ------------------------------------------------------------------ */
uint16_t pmdc_crc16(const uint8_t *data, size_t n);
size_t pmdc_cobs_encode(const uint8_t *in, size_t n, uint8_t *out);
/* Returns the decoded length, or PMDC_E_COBS / PMDC_E_LENGTH (more than cap). */
int pmdc_cobs_decode(const uint8_t *in, size_t n, uint8_t *out, size_t cap);
/* Wire bytes of a payload (CRC, COBS, delimiter); out needs PMDC_MAX_WIRE bytes. */
size_t pmdc_frame_payload(const uint8_t *payload, size_t n, uint8_t *out);

/* -- messages ------------------------------------------------------------------- */
/* Body length of a message type, or -1 for an unknown type. */
int pmdc_body_length(uint8_t type);
/* Payload bytes (type, seq, body) of a message; returns the length (0 if unknown). */
size_t pmdc_encode_payload(const pmdc_msg_t *msg, uint8_t *out);
int pmdc_decode_payload(const uint8_t *payload, size_t n, pmdc_msg_t *msg);
/* Encode straight to wire bytes; returns the length (0 if the type is unknown). */
size_t pmdc_encode_frame(const pmdc_msg_t *msg, uint8_t *out);

/* -- streaming parser: feed bytes, get CRC-checked payloads ------------------------ */
typedef struct {
    uint8_t buf[PMDC_MAX_ENCODED];
    uint8_t len;
    uint8_t overflow;
    uint32_t frames_ok;
    uint32_t crc_errors;
    uint32_t framing_errors;
    uint32_t oversize_frames;
} pmdc_parser_t;

void pmdc_parser_init(pmdc_parser_t *p);
/* Feed one byte. Returns the payload length (>= 2) when a valid frame ended,
 * 0 otherwise; the payload is written to out (PMDC_MAX_PAYLOAD bytes). */
int pmdc_parser_feed(pmdc_parser_t *p, uint8_t byte, uint8_t *out);
uint32_t pmdc_parser_errors(const pmdc_parser_t *p);

/* -- the board ------------------------------------------------------------------- */
typedef struct {
    pmdc_hello_ack_t info;
    pmdc_parser_t parser;
    uint8_t ready;
    uint8_t streaming;
    uint8_t driven;          /* 0: armature open */
    uint8_t faults;
    uint32_t period_us;
    uint16_t watchdog_ms;
    uint32_t counter;
    int32_t setpoint_mv;
    int16_t applied_q;       /* setpoint_mv in voltage LSBs (computed once per command) */
    uint32_t last_host_us;
    uint32_t seen_errors;
} pmdc_board_t;

/* info: the board's description (protocol_version normally PMDC_PROTOCOL_VERSION). */
void pmdc_board_init(pmdc_board_t *b, const pmdc_hello_ack_t *info);
/* Power-up/reset: stream off, armature open; writes the BOOT frame. */
size_t pmdc_board_boot(pmdc_board_t *b, uint8_t *out);
/* Process received bytes; writes replies to out (cap bytes), returns their length.
 * Give cap >= PMDC_MAX_WIRE per complete frame that can arrive in data. */
size_t pmdc_board_receive(pmdc_board_t *b, const uint8_t *data, size_t n, uint32_t now_us,
                          uint8_t *out, size_t cap);
/* Open the armature if the host was silent longer than the watchdog. */
void pmdc_board_check_watchdog(pmdc_board_t *b, uint32_t now_us);
/* A protection tripped: open the armature, latch the fault bit. */
void pmdc_board_trip(pmdc_board_t *b, uint8_t fault_bit);
/* 1 and *mv set while the armature is driven, 0 while it is open. */
int pmdc_board_setpoint_mv(const pmdc_board_t *b, int32_t *mv);
/* A sample instant passed without a frame (the CPU was late): the counter still
 * advances, so the host sees the gap as dropped samples. */
void pmdc_board_skip_sample(pmdc_board_t *b);
/* One telemetry frame (current/terminal/supply in A and V; NaN = not measured). */
size_t pmdc_board_telemetry(pmdc_board_t *b, uint32_t now_us, int32_t encoder_count,
                            double current_a, double terminal_v, double supply_v,
                            uint8_t *out);
/* The same with the three measurements already in LSB counts (PMDC_NOT_MEASURED for
 * none): a microcontroller without an FPU converts its ADC readings in fixed point. */
size_t pmdc_board_telemetry_q(pmdc_board_t *b, uint32_t now_us, int32_t encoder_count,
                              int16_t current, int16_t terminal, int16_t supply, uint8_t *out);

#ifdef __cplusplus
}
#endif

#endif /* PMDC_PROTOCOL_H */
