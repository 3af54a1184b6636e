/*
 * Host test harness of the portable protocol core (built by test/test_firmware_c.py
 * with gcc -std=c99 -Wall -Wextra -Werror; or by hand:
 *   gcc -std=c99 -Wall -Wextra -Werror -I../protocol pmdc_host_test.c \
 *       ../protocol/pmdc_protocol.c -lm -o pmdc_host_test
 *
 * Modes (one output line per input line, so the Python test can compare):
 *   encode FILE   message vectors "TYPE SEQ FIELDS... HEX": prints the C encoding
 *   decode FILE   decodes each HEX with the C parser, prints "TYPE SEQ FIELDS..."
 *   board FILE    runs a board script (see gen_vectors.py), prints the reply bytes;
 *                 lines with "=> HEX" are checked, exit status 1 on any mismatch
 *   fuzz SEED N   N pseudo-random bytes into the board (run under ASan/UBSan)
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pmdc_protocol.h"

#define MAX_TOKENS 24

static int split(char *line, char **tok)
{
    int n = 0;
    char *p = strtok(line, " \t\r\n");
    while (p && n < MAX_TOKENS) {
        tok[n++] = p;
        p = strtok(NULL, " \t\r\n");
    }
    return n;
}

static void print_hex(const uint8_t *b, size_t n)
{
    size_t i;
    if (n == 0) printf("-");
    for (i = 0; i < n; ++i) printf("%02x", b[i]);
}

static size_t from_hex(const char *s, uint8_t *out, size_t cap)
{
    size_t n = 0;
    unsigned v;
    if (strcmp(s, "-") == 0) return 0;
    while (s[0] && s[1] && n < cap) {
        if (sscanf(s, "%2x", &v) != 1) break;
        out[n++] = (uint8_t)v;
        s += 2;
    }
    return n;
}

static long L(const char *s) { return strtol(s, NULL, 0); }
static unsigned long U(const char *s) { return strtoul(s, NULL, 0); }

/* Fields in the order of the Python dataclasses (pmdc_ident/protocol/messages.py). */
static int fill(pmdc_msg_t *m, char **f, int nf)
{
    switch (m->type) {
    case PMDC_HELLO: if (nf != 1) return -1; m->u.hello.host_version = (uint8_t)U(f[0]); break;
    case PMDC_START_STREAM:
        if (nf != 2) return -1;
        m->u.start_stream.period_us = (uint32_t)U(f[0]);
        m->u.start_stream.watchdog_ms = (uint16_t)U(f[1]);
        break;
    case PMDC_STOP_STREAM: case PMDC_OPEN_ARMATURE: if (nf != 0) return -1; break;
    case PMDC_SET_VOLTAGE: if (nf != 1) return -1; m->u.set_voltage.millivolts = (int32_t)L(f[0]); break;
    case PMDC_SET_DUTY: if (nf != 1) return -1; m->u.set_duty.duty_q15 = (int16_t)L(f[0]); break;
    case PMDC_PING: if (nf != 1) return -1; m->u.ping.token = (uint32_t)U(f[0]); break;
    case PMDC_ACK: if (nf != 1) return -1; m->u.ack.acked_type = (uint8_t)U(f[0]); break;
    case PMDC_HELLO_ACK: {
        pmdc_hello_ack_t *h = &m->u.hello_ack;
        if (nf != 9) return -1;
        h->protocol_version = (uint8_t)U(f[0]);
        h->capabilities = (uint8_t)U(f[1]);
        h->firmware_version = (uint16_t)U(f[2]);
        h->min_period_us = (uint32_t)U(f[3]);
        h->counts_per_rev = (uint32_t)U(f[4]);
        h->current_lsb_a = strtof(f[5], NULL);
        h->voltage_lsb_v = strtof(f[6], NULL);
        h->supply_nominal_v = strtof(f[7], NULL);
        h->voltage_max_v = strtof(f[8], NULL);
        break;
    }
    case PMDC_TELEMETRY: {
        pmdc_telemetry_t *t = &m->u.telemetry;
        if (nf != 8) return -1;
        t->counter = (uint32_t)U(f[0]);
        t->time_us = (uint32_t)U(f[1]);
        t->encoder_count = (int32_t)L(f[2]);
        t->current = (int16_t)L(f[3]);
        t->applied_v = (int16_t)L(f[4]);
        t->terminal_v = (int16_t)L(f[5]);
        t->supply_v = (int16_t)L(f[6]);
        t->faults = (uint8_t)U(f[7]);
        break;
    }
    case PMDC_PONG:
        if (nf != 2) return -1;
        m->u.pong.token = (uint32_t)U(f[0]);
        m->u.pong.time_us = (uint32_t)U(f[1]);
        break;
    case PMDC_ERROR:
        if (nf != 3) return -1;
        m->u.error.refused_type = (uint8_t)U(f[0]);
        m->u.error.code = (uint8_t)U(f[1]);
        m->u.error.detail = (uint32_t)U(f[2]);
        break;
    case PMDC_BOOT:
        if (nf != 2) return -1;
        m->u.boot.protocol_version = (uint8_t)U(f[0]);
        m->u.boot.firmware_version = (uint16_t)U(f[1]);
        break;
    default: return -1;
    }
    return 0;
}

static void print_fields(const pmdc_msg_t *m)
{
    printf("%u %u", m->type, m->seq);
    switch (m->type) {
    case PMDC_HELLO: printf(" %u", m->u.hello.host_version); break;
    case PMDC_START_STREAM:
        printf(" %lu %u", (unsigned long)m->u.start_stream.period_us, m->u.start_stream.watchdog_ms);
        break;
    case PMDC_SET_VOLTAGE: printf(" %ld", (long)m->u.set_voltage.millivolts); break;
    case PMDC_SET_DUTY: printf(" %d", m->u.set_duty.duty_q15); break;
    case PMDC_PING: printf(" %lu", (unsigned long)m->u.ping.token); break;
    case PMDC_ACK: printf(" %u", m->u.ack.acked_type); break;
    case PMDC_HELLO_ACK: {
        const pmdc_hello_ack_t *h = &m->u.hello_ack;
        printf(" %u %u %u %lu %lu %.9g %.9g %.9g %.9g", h->protocol_version, h->capabilities,
               h->firmware_version, (unsigned long)h->min_period_us,
               (unsigned long)h->counts_per_rev, (double)h->current_lsb_a,
               (double)h->voltage_lsb_v, (double)h->supply_nominal_v, (double)h->voltage_max_v);
        break;
    }
    case PMDC_TELEMETRY: {
        const pmdc_telemetry_t *t = &m->u.telemetry;
        printf(" %lu %lu %ld %d %d %d %d %u", (unsigned long)t->counter,
               (unsigned long)t->time_us, (long)t->encoder_count, t->current, t->applied_v,
               t->terminal_v, t->supply_v, t->faults);
        break;
    }
    case PMDC_PONG:
        printf(" %lu %lu", (unsigned long)m->u.pong.token, (unsigned long)m->u.pong.time_us);
        break;
    case PMDC_ERROR:
        printf(" %u %u %lu", m->u.error.refused_type, m->u.error.code,
               (unsigned long)m->u.error.detail);
        break;
    case PMDC_BOOT: printf(" %u %u", m->u.boot.protocol_version, m->u.boot.firmware_version); break;
    default: break;
    }
}

static int run_vectors(FILE *fp, int encode)
{
    char line[1024];
    char *tok[MAX_TOKENS];
    uint8_t wire[PMDC_MAX_WIRE], expect[256], payload[PMDC_MAX_PAYLOAD];
    int bad = 0;
    while (fgets(line, sizeof line, fp)) {
        int n;
        if (line[0] == '#' || line[0] == '\n') continue;
        n = split(line, tok);
        if (n < 3) continue;
        if (encode) {
            pmdc_msg_t m;
            size_t len, elen;
            memset(&m, 0, sizeof m);
            m.type = (uint8_t)U(tok[0]);
            m.seq = (uint8_t)U(tok[1]);
            if (fill(&m, tok + 2, n - 3) != 0) {
                printf("BADLINE\n");
                bad++;
                continue;
            }
            len = pmdc_encode_frame(&m, wire);
            elen = from_hex(tok[n - 1], expect, sizeof expect);
            if (len != elen || memcmp(wire, expect, len) != 0) bad++;
            print_hex(wire, len);
            printf("\n");
        } else {
            pmdc_parser_t p;
            pmdc_msg_t m;
            size_t i, elen = from_hex(tok[n - 1], expect, sizeof expect);
            int plen = 0, got = 0;
            pmdc_parser_init(&p);
            for (i = 0; i < elen; ++i) {
                plen = pmdc_parser_feed(&p, expect[i], payload);
                if (plen > 0) got = plen;
            }
            if (got <= 0 || pmdc_decode_payload(payload, (size_t)got, &m) != PMDC_OK) {
                printf("UNDECODABLE\n");
                bad++;
                continue;
            }
            print_fields(&m);
            printf("\n");
        }
    }
    return bad ? 1 : 0;
}

static int run_board(FILE *fp)
{
    char line[2048];
    char *tok[MAX_TOKENS];
    static uint8_t data[1024], out[4096], expect[4096];
    pmdc_board_t b;
    pmdc_hello_ack_t info;
    int bad = 0, lineno = 0;
    memset(&info, 0, sizeof info);
    pmdc_board_init(&b, &info);
    while (fgets(line, sizeof line, fp)) {
        int n, k, has_expect = 0;
        size_t len = 0;
        ++lineno;
        if (line[0] == '#' || line[0] == '\n') continue;
        n = split(line, tok);
        for (k = 0; k < n; ++k) {
            if (strcmp(tok[k], "=>") == 0) {
                has_expect = 1;
                break;
            }
        }
        if (strcmp(tok[0], "info") == 0 && k == 10) {
            info.protocol_version = (uint8_t)U(tok[1]);
            info.capabilities = (uint8_t)U(tok[2]);
            info.firmware_version = (uint16_t)U(tok[3]);
            info.min_period_us = (uint32_t)U(tok[4]);
            info.counts_per_rev = (uint32_t)U(tok[5]);
            info.current_lsb_a = strtof(tok[6], NULL);
            info.voltage_lsb_v = strtof(tok[7], NULL);
            info.supply_nominal_v = strtof(tok[8], NULL);
            info.voltage_max_v = strtof(tok[9], NULL);
            pmdc_board_init(&b, &info);
        } else if (strcmp(tok[0], "boot") == 0) {
            len = pmdc_board_boot(&b, out);
        } else if (strcmp(tok[0], "rx") == 0 && k == 3) {
            size_t dn = from_hex(tok[2], data, sizeof data);
            len = pmdc_board_receive(&b, data, dn, (uint32_t)U(tok[1]), out, sizeof out);
        } else if (strcmp(tok[0], "wd") == 0 && k == 2) {
            pmdc_board_check_watchdog(&b, (uint32_t)U(tok[1]));
        } else if (strcmp(tok[0], "trip") == 0 && k == 2) {
            pmdc_board_trip(&b, (uint8_t)U(tok[1]));
        } else if (strcmp(tok[0], "tlm") == 0 && k == 6) {
            len = pmdc_board_telemetry(&b, (uint32_t)U(tok[1]), (int32_t)L(tok[2]),
                                       strtod(tok[3], NULL), strtod(tok[4], NULL),
                                       strtod(tok[5], NULL), out);
        } else {
            printf("BADLINE %d\n", lineno);
            bad++;
            continue;
        }
        print_hex(out, len);
        printf("\n");
        if (has_expect && k + 1 < n) {
            size_t elen = from_hex(tok[k + 1], expect, sizeof expect);
            if (elen != len || memcmp(expect, out, len) != 0) {
                fprintf(stderr, "line %d: board output differs from the Python board\n", lineno);
                bad++;
            }
        }
    }
    return bad ? 1 : 0;
}

static int run_fuzz(unsigned long seed, unsigned long count)
{
    pmdc_board_t b;
    pmdc_hello_ack_t info;
    static uint8_t data[256], out[256 * PMDC_MAX_WIRE];
    unsigned long x = seed ? seed : 1, i = 0;
    size_t total = 0;
    memset(&info, 0, sizeof info);
    info.protocol_version = PMDC_PROTOCOL_VERSION;
    info.min_period_us = 300;
    info.current_lsb_a = 0.001f;
    info.voltage_lsb_v = 0.001f;
    info.supply_nominal_v = 24.0f;
    info.voltage_max_v = 24.0f;
    pmdc_board_init(&b, &info);
    while (i < count) {
        size_t n = 0, k;
        for (k = 0; k < sizeof data && i < count; ++k, ++i) {
            x = x * 6364136223846793005UL + 1442695040888963407UL;
            /* bias toward zeros and small codes so frames form */
            data[n++] = (uint8_t)((x >> 33) % 7 == 0 ? 0 : (x >> 41));
        }
        total += pmdc_board_receive(&b, data, n, (uint32_t)i, out, sizeof out);
        pmdc_board_check_watchdog(&b, (uint32_t)i);
    }
    printf("fuzz ok: %lu bytes in, %lu bytes out, %lu frames ok, %lu errors\n", count,
           (unsigned long)total, (unsigned long)b.parser.frames_ok,
           (unsigned long)pmdc_parser_errors(&b.parser));
    return b.parser.len <= PMDC_MAX_ENCODED ? 0 : 1;
}

int main(int argc, char **argv)
{
    FILE *fp;
    int rc;
    if (argc == 4 && strcmp(argv[1], "fuzz") == 0) return run_fuzz(U(argv[2]), U(argv[3]));
    if (argc != 3) {
        fprintf(stderr, "usage: %s encode|decode|board FILE | fuzz SEED N\n", argv[0]);
        return 2;
    }
    fp = fopen(argv[2], "r");
    if (!fp) {
        perror(argv[2]);
        return 2;
    }
    if (strcmp(argv[1], "encode") == 0) rc = run_vectors(fp, 1);
    else if (strcmp(argv[1], "decode") == 0) rc = run_vectors(fp, 0);
    else if (strcmp(argv[1], "board") == 0) rc = run_board(fp);
    else rc = 2;
    fclose(fp);
    return rc;
}
