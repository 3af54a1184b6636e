/* pmdc serial protocol v1 - portable C core. See pmdc_protocol.h. */
#include "pmdc_protocol.h"

#include <math.h>
#include <string.h>
#if defined(__AVR__)
#include <util/crc16.h> /* avr-libc's hand-written CRC-16 (poly 0x1021, MSB first) */
#endif

/* -- little-endian helpers -------------------------------------------------------- */
static void put_u16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    p[2] = (uint8_t)(v >> 16);
    p[3] = (uint8_t)(v >> 24);
}
static void put_f32(uint8_t *p, float f)
{
    uint32_t v;
    memcpy(&v, &f, 4); /* IEEE 754 binary32 on AVR, ARM and x86 */
    put_u32(p, v);
}
static uint16_t get_u16(const uint8_t *p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }
static uint32_t get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) |
           ((uint32_t)p[3] << 24);
}
static float get_f32(const uint8_t *p)
{
    uint32_t v = get_u32(p);
    float f;
    memcpy(&f, &v, 4);
    return f;
}

/* -- CRC and COBS ---------------------------------------------------------------------- */
uint16_t pmdc_crc16(const uint8_t *data, size_t n)
{
    uint16_t crc = 0xFFFFu;
    size_t i;
#if defined(__AVR__)
    /* The XMODEM update is CRC-16/CCITT-FALSE's step; ~5x faster than the loop below. */
    for (i = 0; i < n; ++i) crc = _crc_xmodem_update(crc, data[i]);
#else
    int bit;
    for (i = 0; i < n; ++i) {
        crc ^= (uint16_t)((uint16_t)data[i] << 8);
        for (bit = 0; bit < 8; ++bit) {
            crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
        }
    }
#endif
    return crc;
}

size_t pmdc_cobs_encode(const uint8_t *in, size_t n, uint8_t *out)
{
    size_t code_idx = 0, o = 1, i;
    uint8_t code = 1;
    for (i = 0; i < n; ++i) {
        if (in[i] == 0) {
            out[code_idx] = code;
            code_idx = o++;
            code = 1;
        } else {
            out[o++] = in[i];
            if (++code == 0xFF) {
                out[code_idx] = code;
                code_idx = o++;
                code = 1;
            }
        }
    }
    out[code_idx] = code;
    return o;
}

int pmdc_cobs_decode(const uint8_t *in, size_t n, uint8_t *out, size_t cap)
{
    size_t i = 0, o = 0, j, end;
    while (i < n) {
        uint8_t code = in[i];
        if (code == 0) return PMDC_E_COBS;
        end = i + code;
        if (end > n) return PMDC_E_COBS;
        for (j = i + 1; j < end; ++j) {
            if (in[j] == 0) return PMDC_E_COBS;
            if (o >= cap) return PMDC_E_LENGTH;
            out[o++] = in[j];
        }
        i = end;
        if (code < 0xFF && i < n) {
            if (o >= cap) return PMDC_E_LENGTH;
            out[o++] = 0;
        }
    }
    return (int)o;
}

size_t pmdc_frame_payload(const uint8_t *payload, size_t n, uint8_t *out)
{
    uint8_t raw[PMDC_MAX_PAYLOAD + 2];
    uint16_t crc;
    size_t len;
    if (n == 0 || n > PMDC_MAX_PAYLOAD) return 0;
    memcpy(raw, payload, n);
    crc = pmdc_crc16(payload, n);
    put_u16(raw + n, crc);
    len = pmdc_cobs_encode(raw, n + 2, out);
    out[len++] = 0;
    return len;
}

/* -- messages ---------------------------------------------------------------------------- */
int pmdc_body_length(uint8_t type)
{
    switch (type) {
    case PMDC_HELLO: return 1;
    case PMDC_START_STREAM: return 6;
    case PMDC_STOP_STREAM: return 0;
    case PMDC_SET_VOLTAGE: return 4;
    case PMDC_SET_DUTY: return 2;
    case PMDC_OPEN_ARMATURE: return 0;
    case PMDC_PING: return 4;
    case PMDC_ACK: return 1;
    case PMDC_HELLO_ACK: return 28;
    case PMDC_TELEMETRY: return 21;
    case PMDC_PONG: return 8;
    case PMDC_ERROR: return 6;
    case PMDC_BOOT: return 3;
    default: return -1;
    }
}

size_t pmdc_encode_payload(const pmdc_msg_t *m, uint8_t *out)
{
    uint8_t *b = out + 2;
    int len = pmdc_body_length(m->type);
    if (len < 0) return 0;
    out[0] = m->type;
    out[1] = m->seq;
    switch (m->type) {
    case PMDC_HELLO: b[0] = m->u.hello.host_version; break;
    case PMDC_START_STREAM:
        put_u32(b, m->u.start_stream.period_us);
        put_u16(b + 4, m->u.start_stream.watchdog_ms);
        break;
    case PMDC_SET_VOLTAGE: put_u32(b, (uint32_t)m->u.set_voltage.millivolts); break;
    case PMDC_SET_DUTY: put_u16(b, (uint16_t)m->u.set_duty.duty_q15); break;
    case PMDC_PING: put_u32(b, m->u.ping.token); break;
    case PMDC_ACK: b[0] = m->u.ack.acked_type; break;
    case PMDC_HELLO_ACK: {
        const pmdc_hello_ack_t *h = &m->u.hello_ack;
        b[0] = h->protocol_version;
        b[1] = h->capabilities;
        put_u16(b + 2, h->firmware_version);
        put_u32(b + 4, h->min_period_us);
        put_u32(b + 8, h->counts_per_rev);
        put_f32(b + 12, h->current_lsb_a);
        put_f32(b + 16, h->voltage_lsb_v);
        put_f32(b + 20, h->supply_nominal_v);
        put_f32(b + 24, h->voltage_max_v);
        break;
    }
    case PMDC_TELEMETRY: {
        const pmdc_telemetry_t *t = &m->u.telemetry;
        put_u32(b, t->counter);
        put_u32(b + 4, t->time_us);
        put_u32(b + 8, (uint32_t)t->encoder_count);
        put_u16(b + 12, (uint16_t)t->current);
        put_u16(b + 14, (uint16_t)t->applied_v);
        put_u16(b + 16, (uint16_t)t->terminal_v);
        put_u16(b + 18, (uint16_t)t->supply_v);
        b[20] = t->faults;
        break;
    }
    case PMDC_PONG:
        put_u32(b, m->u.pong.token);
        put_u32(b + 4, m->u.pong.time_us);
        break;
    case PMDC_ERROR:
        b[0] = m->u.error.refused_type;
        b[1] = m->u.error.code;
        put_u32(b + 2, m->u.error.detail);
        break;
    case PMDC_BOOT:
        b[0] = m->u.boot.protocol_version;
        put_u16(b + 1, m->u.boot.firmware_version);
        break;
    default: break; /* STOP_STREAM, OPEN_ARMATURE: no body */
    }
    return (size_t)len + 2u;
}

int pmdc_decode_payload(const uint8_t *p, size_t n, pmdc_msg_t *m)
{
    const uint8_t *b = p + 2;
    int len;
    if (n < 2) return PMDC_E_LENGTH;
    len = pmdc_body_length(p[0]);
    if (len < 0) return PMDC_E_TYPE;
    if ((size_t)len != n - 2) return PMDC_E_LENGTH;
    memset(m, 0, sizeof *m);
    m->type = p[0];
    m->seq = p[1];
    switch (m->type) {
    case PMDC_HELLO: m->u.hello.host_version = b[0]; break;
    case PMDC_START_STREAM:
        m->u.start_stream.period_us = get_u32(b);
        m->u.start_stream.watchdog_ms = get_u16(b + 4);
        break;
    case PMDC_SET_VOLTAGE: m->u.set_voltage.millivolts = (int32_t)get_u32(b); break;
    case PMDC_SET_DUTY: m->u.set_duty.duty_q15 = (int16_t)get_u16(b); break;
    case PMDC_PING: m->u.ping.token = get_u32(b); break;
    case PMDC_ACK: m->u.ack.acked_type = b[0]; break;
    case PMDC_HELLO_ACK: {
        pmdc_hello_ack_t *h = &m->u.hello_ack;
        h->protocol_version = b[0];
        h->capabilities = b[1];
        h->firmware_version = get_u16(b + 2);
        h->min_period_us = get_u32(b + 4);
        h->counts_per_rev = get_u32(b + 8);
        h->current_lsb_a = get_f32(b + 12);
        h->voltage_lsb_v = get_f32(b + 16);
        h->supply_nominal_v = get_f32(b + 20);
        h->voltage_max_v = get_f32(b + 24);
        break;
    }
    case PMDC_TELEMETRY: {
        pmdc_telemetry_t *t = &m->u.telemetry;
        t->counter = get_u32(b);
        t->time_us = get_u32(b + 4);
        t->encoder_count = (int32_t)get_u32(b + 8);
        t->current = (int16_t)get_u16(b + 12);
        t->applied_v = (int16_t)get_u16(b + 14);
        t->terminal_v = (int16_t)get_u16(b + 16);
        t->supply_v = (int16_t)get_u16(b + 18);
        t->faults = b[20];
        break;
    }
    case PMDC_PONG:
        m->u.pong.token = get_u32(b);
        m->u.pong.time_us = get_u32(b + 4);
        break;
    case PMDC_ERROR:
        m->u.error.refused_type = b[0];
        m->u.error.code = b[1];
        m->u.error.detail = get_u32(b + 2);
        break;
    case PMDC_BOOT:
        m->u.boot.protocol_version = b[0];
        m->u.boot.firmware_version = get_u16(b + 1);
        break;
    default: break;
    }
    return PMDC_OK;
}

size_t pmdc_encode_frame(const pmdc_msg_t *msg, uint8_t *out)
{
    uint8_t payload[PMDC_MAX_PAYLOAD];
    size_t n = pmdc_encode_payload(msg, payload);
    return n ? pmdc_frame_payload(payload, n, out) : 0;
}

/* -- parser --------------------------------------------------------------------------------- */
void pmdc_parser_init(pmdc_parser_t *p) { memset(p, 0, sizeof *p); }

uint32_t pmdc_parser_errors(const pmdc_parser_t *p)
{
    return p->crc_errors + p->framing_errors + p->oversize_frames;
}

int pmdc_parser_feed(pmdc_parser_t *p, uint8_t byte, uint8_t *out)
{
    uint8_t raw[PMDC_MAX_PAYLOAD + 2];
    int n;
    if (byte != 0) {
        if (p->overflow) return 0;
        if (p->len >= PMDC_MAX_ENCODED) {
            p->overflow = 1;
            p->oversize_frames++;
            p->len = 0;
            return 0;
        }
        p->buf[p->len++] = byte;
        return 0;
    }
    /* delimiter */
    if (p->overflow || p->len == 0) {
        p->overflow = 0;
        p->len = 0;
        return 0;
    }
    n = pmdc_cobs_decode(p->buf, p->len, raw, sizeof raw);
    p->len = 0;
    if (n < 0) {
        p->framing_errors++;
        return 0;
    }
    if (n < 3) {
        p->framing_errors++;
        return 0;
    }
    if (pmdc_crc16(raw, (size_t)n - 2) != get_u16(raw + n - 2)) {
        p->crc_errors++;
        return 0;
    }
    if (n - 2 < 2) {
        p->framing_errors++;
        return 0;
    }
    memcpy(out, raw, (size_t)n - 2);
    p->frames_ok++;
    return n - 2;
}

/* -- board -------------------------------------------------------------------------------------- */
#define STICKY (PMDC_FAULT_OVER_CURRENT | PMDC_FAULT_OVER_SPEED | PMDC_FAULT_WATCHDOG)

void pmdc_board_init(pmdc_board_t *b, const pmdc_hello_ack_t *info)
{
    memset(b, 0, sizeof *b);
    b->info = *info;
    pmdc_parser_init(&b->parser);
}

static size_t reply(const pmdc_msg_t *m, uint8_t *out) { return pmdc_encode_frame(m, out); }

size_t pmdc_board_boot(pmdc_board_t *b, uint8_t *out)
{
    pmdc_msg_t m;
    b->ready = 0;
    b->streaming = 0;
    b->period_us = 0;
    b->watchdog_ms = PMDC_DEFAULT_WATCHDOG_MS;
    b->counter = 0;
    b->driven = 0;
    b->setpoint_mv = 0;
    b->faults = 0;
    b->last_host_us = 0;
    b->seen_errors = pmdc_parser_errors(&b->parser);
    memset(&m, 0, sizeof m);
    m.type = PMDC_BOOT;
    m.u.boot.protocol_version = b->info.protocol_version;
    m.u.boot.firmware_version = b->info.firmware_version;
    return reply(&m, out);
}

void pmdc_board_trip(pmdc_board_t *b, uint8_t fault_bit)
{
    b->driven = 0;
    b->faults |= fault_bit;
}

int pmdc_board_setpoint_mv(const pmdc_board_t *b, int32_t *mv)
{
    if (b->driven && mv) *mv = b->setpoint_mv;
    return b->driven;
}

static int16_t quantize(double value, double lsb)
{
    double q;
    if (isnan(value)) return (int16_t)PMDC_NOT_MEASURED;
    q = floor(value / lsb + 0.5);
    if (q > 32767.0) return 32767;
    if (q < -32767.0) return -32767;
    return (int16_t)q;
}

static void drive_mv(pmdc_board_t *b, int32_t mv)
{
    double vmax = b->info.voltage_max_v < b->info.supply_nominal_v ? b->info.voltage_max_v
                                                                   : b->info.supply_nominal_v;
    int32_t limit_mv = (int32_t)(vmax * 1000.0 + 0.5);
    b->faults &= (uint8_t)~(STICKY | PMDC_FAULT_CLAMPED | PMDC_FAULT_BAD_COMMAND);
    if (mv > limit_mv || mv < -limit_mv) {
        b->faults |= PMDC_FAULT_CLAMPED;
        mv = mv > 0 ? limit_mv : -limit_mv;
    }
    b->setpoint_mv = mv;
    b->applied_q = quantize((double)mv / 1000.0, (double)b->info.voltage_lsb_v);
    b->driven = 1;
}

static size_t error_reply(uint8_t type, uint8_t seq, uint8_t code, uint32_t detail, uint8_t *out)
{
    pmdc_msg_t m;
    memset(&m, 0, sizeof m);
    m.type = PMDC_ERROR;
    m.seq = seq;
    m.u.error.refused_type = type;
    m.u.error.code = code;
    m.u.error.detail = detail;
    return reply(&m, out);
}

static size_t handle(pmdc_board_t *b, const uint8_t *payload, size_t n, uint32_t now_us,
                     uint8_t *out)
{
    pmdc_msg_t m, r;
    uint8_t type = payload[0], seq = payload[1];
    int rc;
    int blen = pmdc_body_length(type);
    if (blen < 0 || type >= 0x80) return error_reply(type, seq, PMDC_ERR_UNKNOWN_TYPE, 0, out);
    rc = pmdc_decode_payload(payload, n, &m);
    if (rc != PMDC_OK) return error_reply(type, seq, PMDC_ERR_BAD_LENGTH, (uint32_t)(n - 2), out);
    memset(&r, 0, sizeof r);
    r.seq = seq;
    switch (type) {
    case PMDC_HELLO:
        b->streaming = 0;
        b->driven = 0;
        b->faults = 0;
        b->ready = m.u.hello.host_version == b->info.protocol_version;
        r.type = PMDC_HELLO_ACK;
        r.u.hello_ack = b->info;
        return reply(&r, out);
    case PMDC_PING:
        r.type = PMDC_PONG;
        r.u.pong.token = m.u.ping.token;
        r.u.pong.time_us = now_us;
        return reply(&r, out);
    default: break;
    }
    if (!b->ready) return error_reply(type, seq, PMDC_ERR_NOT_READY, 0, out);
    switch (type) {
    case PMDC_START_STREAM:
        if (m.u.start_stream.period_us < b->info.min_period_us)
            return error_reply(type, seq, PMDC_ERR_RATE_TOO_HIGH, b->info.min_period_us, out);
        b->period_us = m.u.start_stream.period_us;
        b->watchdog_ms = m.u.start_stream.watchdog_ms ? m.u.start_stream.watchdog_ms
                                                      : (uint16_t)PMDC_DEFAULT_WATCHDOG_MS;
        b->counter = 0;
        b->streaming = 1;
        break;
    case PMDC_STOP_STREAM: b->streaming = 0; break;
    case PMDC_SET_VOLTAGE: drive_mv(b, m.u.set_voltage.millivolts); break;
    case PMDC_SET_DUTY: {
        int32_t supply_mv = (int32_t)((double)b->info.supply_nominal_v * 1000.0 + 0.5);
        int64_t product = (int64_t)m.u.set_duty.duty_q15 * supply_mv;
        if (m.u.set_duty.duty_q15 < -32767) {
            pmdc_board_trip(b, PMDC_FAULT_BAD_COMMAND);
            return error_reply(type, seq, PMDC_ERR_BAD_VALUE,
                               (uint32_t)(uint16_t)m.u.set_duty.duty_q15, out);
        }
        drive_mv(b, (int32_t)(product / 32767)); /* C99: truncates toward zero */
        break;
    }
    case PMDC_OPEN_ARMATURE:
        b->driven = 0;
        b->faults &= (uint8_t)~(STICKY | PMDC_FAULT_CLAMPED | PMDC_FAULT_BAD_COMMAND);
        break;
    default: break;
    }
    r.type = PMDC_ACK;
    r.u.ack.acked_type = type;
    return reply(&r, out);
}

size_t pmdc_board_receive(pmdc_board_t *b, const uint8_t *data, size_t n, uint32_t now_us,
                          uint8_t *out, size_t cap)
{
    uint8_t payload[PMDC_MAX_PAYLOAD];
    size_t i, o = 0;
    int len;
    uint32_t errors;
    for (i = 0; i < n; ++i) {
        len = pmdc_parser_feed(&b->parser, data[i], payload);
        if (len > 0) {
            b->last_host_us = now_us;
            if (o + PMDC_MAX_WIRE <= cap) o += handle(b, payload, (size_t)len, now_us, out + o);
        }
    }
    errors = pmdc_parser_errors(&b->parser);
    if (errors != b->seen_errors) {
        b->faults |= PMDC_FAULT_LINK;
        b->seen_errors = errors;
    }
    return o;
}

void pmdc_board_check_watchdog(pmdc_board_t *b, uint32_t now_us)
{
    int32_t silent_us = (int32_t)(now_us - b->last_host_us); /* wrap-safe */
    if (b->driven && silent_us > (int32_t)b->watchdog_ms * 1000) {
        pmdc_board_trip(b, PMDC_FAULT_WATCHDOG);
    }
}

void pmdc_board_skip_sample(pmdc_board_t *b) { b->counter++; }


size_t pmdc_board_telemetry(pmdc_board_t *b, uint32_t now_us, int32_t encoder_count,
                            double current_a, double terminal_v, double supply_v, uint8_t *out)
{
    double lsb_v = (double)b->info.voltage_lsb_v;
    return pmdc_board_telemetry_q(b, now_us, encoder_count,
                                  quantize(current_a, (double)b->info.current_lsb_a),
                                  quantize(terminal_v, lsb_v), quantize(supply_v, lsb_v), out);
}

size_t pmdc_board_telemetry_q(pmdc_board_t *b, uint32_t now_us, int32_t encoder_count,
                              int16_t current, int16_t terminal, int16_t supply, uint8_t *out)
{
    pmdc_msg_t m;
    pmdc_telemetry_t *t = &m.u.telemetry;
    memset(&m, 0, sizeof m);
    m.type = PMDC_TELEMETRY;
    t->counter = b->counter;
    t->time_us = now_us;
    t->encoder_count = encoder_count;
    t->current = current;
    t->applied_v = b->driven ? b->applied_q : (int16_t)PMDC_NOT_MEASURED;
    t->terminal_v = terminal;
    t->supply_v = supply;
    t->faults = b->faults;
    b->counter++;
    b->faults &= (uint8_t)~PMDC_FAULT_LINK;
    return reply(&m, out);
}
