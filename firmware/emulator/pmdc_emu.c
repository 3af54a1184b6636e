/*
 * pmdc_emu - the reference sketch on an emulated ATmega328P against a simulated motor.
 *
 * simavr (libsimavr) executes the sketch's ELF cycle by cycle at 16 MHz. Around the
 * MCU this program wires the rig of the sketch's header:
 *
 *   - the H-bridge (BTS7960): EN on PB0 (D8), RPWM on PB1 (OC1A, D9), LPWM on PB2
 *     (OC1B, D10). A pin follows Timer1's compare output while its COM1x bits are
 *     set, else its PORTB bit; EN low opens the bridge (the current freewheels
 *     through the body diodes to zero, then the winding floats);
 *   - the motor: L di/dt = V - R i - Ke w, J dw/dt = Kt i - B w - friction - load,
 *     stepped exactly (zero-order hold of the matrix exponential) at every pin edge
 *     and at least every 4 us (64 cycles), so each PWM pulse is integrated as the
 *     winding sees it; Coulomb friction holds a rotor at rest (stiction);
 *   - the sensors: ACS712 (2.5 V + gain * i, plus noise) on ADC0, the supply
 *     divider on ADC1, the terminal dividers (with their RC low-pass) on ADC2/ADC3,
 *     sampled when the ADC's sample-and-hold closes (1.5 ADC clocks after the start);
 *   - the encoder: the shaft angle drives quadrature edges on PD2/PD3 (INT0/INT1);
 *   - the UART: bridged to a pseudo-terminal (served by a thread of its own, so a pty
 *     call blocked in the kernel never holds up the board's clock), host bytes fed at
 *     the wire rate.
 *
 * By default simulated time is held to the wall clock, so a host on the pty sees a
 * board at its real speed: ahead, it sleeps; behind (its process was starved), it
 * catches up as fast as its CPU lets it, as a crystal-clocked board never lags; paused
 * (SIGSTOP/SIGCONT) or more than 1 s behind, the lost time is counted and not made up,
 * and being behind is reported (stats, and a line on stderr past 0.25 s). A board has
 * a CPU of its own: --cpu-share F reserves F of a core with SCHED_DEADLINE where
 * permitted, so no other task (real-time ones included) holds it up, and the kernel
 * never gives it more, whatever it does. --free-run runs as fast as it can, for
 * measurements with the built-in scripted host (--host), which speaks the protocol
 * through the same UART (the portable core of firmware/protocol encodes its frames
 * and parses the board's) and reports drops, latency, the watchdog and the encoder.
 *
 * Measurements in the --stats JSON: CPU use of the sketch from cycle counts (cycles
 * in interrupts, in the sample routine (D13 high), in host-byte handling (D12 high),
 * idle), when each sample's count was latched (D11) and its routine started, against
 * the grid instant its telemetry names (the board's output is decoded here, whatever
 * the host), ADC conversions, command-to-PWM latency, encoder edges and missed counts
 * (the firmware's pmdc_encoder_count compared with the emitted edges whenever no
 * encoder interrupt is pending), the emulator's own CPU time per simulated second and
 * how far it fell behind the wall clock.
 *
 * Signals: SIGINT/SIGTERM end it (the pty disappears: a pulled cable); SIGUSR1
 * resets the AVR (as a brown-out would; the motor keeps turning); SIGUSR2 cuts or
 * reconnects the serial line with the board powered. SIGSTOP/SIGCONT pause it: the
 * board's clock stops too, and resumes in real time (no catch-up burst).
 * It also ends when its parent process does (PR_SET_PDEATHSIG and a parent check).
 *
 * Build: firmware/emulator/build.py. Usage: pmdc_emu --help.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <pthread.h>
#include <sys/eventfd.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "avr_adc.h"
#include "avr_ioport.h"
#include "avr_timer.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_irq.h"

#include "pmdc_protocol.h"

#define F_CPU 16000000.0
#define TICK_CYCLES 64 /* the motor is stepped at least every 4 us (and at every edge) */
#define TWO_PI 6.283185307179586
/* ATmega328P data-space addresses */
#define R_PIND 0x29
#define R_DDRB 0x24
#define R_PORTB 0x25
#define R_EIFR 0x3C
#define R_TCCR0B 0x45
#define R_EIMSK 0x3D
#define R_ADCSRA 0x7A
#define R_TCCR1A 0x80
#define R_OCR1AL 0x88
#define R_TCCR1B 0x81
#define R_ICR1L 0x86
#define R_OCR1BL 0x8A
#define DIODE_V 0.7

/* ---- options ------------------------------------------------------------------ */
typedef struct {
    const char *firmware;
    double R, L, Ke, Kt, J, B, Tc, Tload;
    double supply_v, acs_v_per_a, divider, term_tau_s, current_noise_a;
    unsigned long seed;
    long counts_per_rev;
    long baud;
    int realtime;
    double duration_s;
    const char *link;
    long parent;
    const char *stats;
    const char *profile;
    double cpu_share; /* SCHED_DEADLINE reservation, fraction of a core (0: none) */
    /* encoder test: the shaft is driven at a speed ramping 0 -> ramp_w over ramp_s */
    double ramp_w, ramp_s, ramp_start_s;
    /* scripted host */
    long host_period_us;
    double host_silent_at_s; /* stop sending at this time (watchdog test), 0 = never */
    double host_step_v, host_step_every_s;
} options_t;

static options_t opt = {
    .R = 1.375, .L = 298.75e-6, .Ke = 0.0662, .Kt = 0.0674, .J = 0.00099, .B = 0.00007,
    .Tc = 0.0256, .Tload = 0.0, .supply_v = 24.0, .acs_v_per_a = 0.100, .divider = 11.0,
    .term_tau_s = 1e-3, .current_noise_a = 0.0, .seed = 1, .counts_per_rev = 2048,
    .baud = 115200, .realtime = 1, .duration_s = 0.0, .parent = 0,
    .host_step_v = 6.0, .host_step_every_s = 0.05, .cpu_share = 0.0,
};

/* ---- globals -------------------------------------------------------------------- */
static avr_t *avr;
static volatile sig_atomic_t sig_stop, sig_reset, sig_cut, sig_cont;
static int line_cut;

/* motor state */
static double m_i, m_w, m_th;
static uint64_t m_t; /* cycle of the state */
static int br_en, br_rp, br_lp; /* bridge inputs as the motor sees them */
static int oc1a, oc1b;          /* Timer1 compare outputs */
static uint64_t t1_period;      /* Timer1 PWM period, cycles; 0 = not in mode 14 */
static double node_p, node_n;   /* terminal divider nodes after their RC, V at the pin */
/* exact ZOH of [i, w]' = A [i, w]' + G [V, T]' for h = 1..TICK_CYCLES cycles */
static double PHI[TICK_CYCLES + 1][2][2], GAM[TICK_CYCLES + 1][2][2];
static double E_RL[TICK_CYCLES + 1], RC_A[TICK_CYCLES + 1];

/* encoder */
static int64_t enc_emitted; /* count the pins show */
static avr_irq_t *pin_a, *pin_b;
static int64_t enc_offset;
static int enc_armed;
static uint64_t enc_edges, enc_double, enc_missed, enc_checks;
static double enc_first_miss_rate = -1.0, enc_max_rate;
static uint16_t enc_addr;

/* ADC */
static avr_irq_t *adc_irq;
static uint64_t adc_conversions;
static int adc_pending_src = -1;
static uint32_t adc_prescaler = 128;

/* CPU accounting (cycles) */
static uint64_t cyc_isr, cyc_sample, cyc_rx, cyc_idle, n_samples_pin;
static uint64_t sample_hi_since, sample_max_cycles, rx_hi_since, rx_max_cycles;
static int sample_pin, rx_pin, capture_pin;

/* Sample instants: when the firmware latched the encoder (its capture pulse on D11) and
 * when its sample routine started (D13 rising), against the grid instant the telemetry
 * names (time_us, on the board's micros() clock = (cycle - t0_cycle) / 16). */
typedef struct {
    uint64_t n;
    double sum, min, max;
} lateness_t;
#define RING 8
static uint64_t cap_ring[RING], start_ring[RING];
static unsigned cap_w, start_w;
static lateness_t late_cap = {0, 0, 1e9, -1e9}, late_start = {0, 0, 1e9, -1e9};
static lateness_t bridge_after = {0, 0, 1e9, -1e9}; /* bridge reprogrammed: us after a latch */
static uint64_t t0_cycle;
static int t0_seen;
static pmdc_parser_t mon_parser; /* the board's output, as a host would read it */

/* UART bridge */
static avr_irq_t *uart_in;
static int uart_xon = 1;
static uint8_t rx_buf[8192];
static size_t rx_head, rx_len;
/* The pty is served by a thread of its own (see pty_thread): board -> host bytes go
 * through tx_ring, host -> board bytes through in_ring (one writer, one reader each). */
#define PTY_RING (1u << 16)
static uint8_t tx_ring[PTY_RING], in_ring[PTY_RING];
static size_t tx_head, tx_tail, in_head, in_tail; /* __atomic: head by the writer */
static int tx_event = -1, in_event = -1;            /* eventfds: bytes to write / read */
static volatile int pty_stop;
static pthread_t pty_tid;
static int pty_thread_on;
static uint64_t bytes_to_host, bytes_from_host, bytes_lost;
static uint32_t cycles_per_byte;
static int pty_master = -1, pty_slave = -1;
static char pty_name[128];

/* latency: end of a host frame -> the bridge programmed differently */
static uint64_t last_delim_end;
static int latency_open;
static uint64_t lat_n, lat_sum, lat_max;
static uint32_t bridge_sig;

/* scripted host */
static pmdc_parser_t host_parser;
static uint8_t host_seq;
static int host_streaming;
static uint64_t host_frames, host_dropped, host_last_counter, host_have_counter, host_errors;
static uint64_t host_boots, host_watchdog_open_cycle, host_silent_cycle;
static double host_watchdog_s = -1.0, host_open_after_frame_s = -1.0;
static int64_t host_enc_last;
static uint64_t stalled_cycles;
/* real-time pacing: how far behind the wall clock the board fell, and how it is scheduled */
static double behind_max_s, behind_total_s;
static char sched_text[96] = "normal";
static uint64_t *profile; /* cycles per flash word (--profile) */

static double now_s(void) { return (double)avr->cycle / F_CPU; }

/* ---- small numerics --------------------------------------------------------------- */
/* exp(M h) of the 4x4 augmented matrix [[A, G], [0, 0]] by its Taylor series (|M h| is
 * tiny for h <= 1 us); fills PHI/GAM[k] for h = k cycles. */
static void build_tables(void)
{
    double A[2][2] = {{-opt.R / opt.L, -opt.Ke / opt.L}, {opt.Kt / opt.J, -opt.B / opt.J}};
    double G[2][2] = {{1.0 / opt.L, 0.0}, {0.0, -1.0 / opt.J}};
    for (int k = 1; k <= TICK_CYCLES; ++k) {
        double h = k / F_CPU;
        double M[4][4] = {{0}}, T[4][4], S[4][4];
        for (int r = 0; r < 2; ++r)
            for (int c = 0; c < 2; ++c) {
                M[r][c] = A[r][c] * h;
                M[r][c + 2] = G[r][c] * h;
            }
        memset(S, 0, sizeof S);
        memset(T, 0, sizeof T);
        for (int r = 0; r < 4; ++r) S[r][r] = T[r][r] = 1.0;
        for (int n = 1; n < 20; ++n) {
            double U[4][4];
            for (int r = 0; r < 4; ++r)
                for (int c = 0; c < 4; ++c) {
                    double s = 0;
                    for (int q = 0; q < 4; ++q) s += T[r][q] * M[q][c];
                    U[r][c] = s / n;
                }
            memcpy(T, U, sizeof T);
            for (int r = 0; r < 4; ++r)
                for (int c = 0; c < 4; ++c) S[r][c] += T[r][c];
        }
        for (int r = 0; r < 2; ++r)
            for (int c = 0; c < 2; ++c) {
                PHI[k][r][c] = S[r][c];
                GAM[k][r][c] = S[r][c + 2];
            }
        E_RL[k] = exp(-h * opt.R / opt.L);
        RC_A[k] = 1.0 - exp(-h / opt.term_tau_s);
    }
}

static uint64_t rng_state = 88172645463325252ULL;
static double gauss(void)
{
    /* xorshift64 + Box-Muller: reproducible from --seed */
    double u1, u2;
    do {
        rng_state ^= rng_state << 13;
        rng_state ^= rng_state >> 7;
        rng_state ^= rng_state << 17;
        u1 = (rng_state >> 11) * (1.0 / 9007199254740992.0);
    } while (u1 <= 0.0);
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    u2 = (rng_state >> 11) * (1.0 / 9007199254740992.0);
    return sqrt(-2.0 * log(u1)) * cos(TWO_PI * u2);
}

static int sgn(double x) { return (x > 0) - (x < 0); }

/* ---- the bridge and the motor ---------------------------------------------------------- */
static void bridge_refresh(void)
{
    uint8_t ddr = avr->data[R_DDRB], port = avr->data[R_PORTB], tccr = avr->data[R_TCCR1A];
    br_en = (ddr & 0x01) && (port & 0x01);
    int rp = (tccr & 0xC0) && t1_period ? oc1a : (port >> 1) & 1;
    int lp = (tccr & 0x30) && t1_period ? oc1b : (port >> 2) & 1;
    br_rp = (ddr & 0x02) && rp;
    br_lp = (ddr & 0x04) && lp;
    /* what the firmware programmed (for the latency figure) */
    uint32_t sig = (uint32_t)(port & 0x07) | ((uint32_t)(tccr & 0xF0) << 4) |
                   ((uint32_t)avr->data[R_OCR1AL] << 12) | ((uint32_t)avr->data[R_OCR1BL] << 20) |
                   ((uint32_t)(avr->data[R_OCR1AL + 1] & 0x0F) << 28);
    if (sig != bridge_sig) {
        bridge_sig = sig;
        if (cap_w) { /* streaming: when, after the last sample instant, the change came */
            double us = (double)(avr->cycle - cap_ring[(cap_w - 1) % RING]) / 16.0;
            bridge_after.n++;
            bridge_after.sum += us;
            if (us < bridge_after.min) bridge_after.min = us;
            if (us > bridge_after.max) bridge_after.max = us;
        }
        if (latency_open && avr->cycle >= last_delim_end) {
            uint64_t lat = avr->cycle - last_delim_end;
            lat_n++;
            lat_sum += lat;
            if (lat > lat_max) lat_max = lat;
            latency_open = 0;
        }
    }
}

/* Terminal voltages (M+, M-) for the current bridge state. */
static void terminals(double *vp, double *vn)
{
    if (br_en) {
        *vp = br_rp ? opt.supply_v : 0.0;
        *vn = br_lp ? opt.supply_v : 0.0;
    } else if (m_i > 0) { /* freewheeling: low-side diode of M+, high-side diode of M- */
        *vp = -DIODE_V;
        *vn = opt.supply_v + DIODE_V;
    } else if (m_i < 0) {
        *vp = opt.supply_v + DIODE_V;
        *vn = -DIODE_V;
    } else { /* floating winding, centred by the two dividers */
        *vp = 0.5 * opt.Ke * m_w;
        *vn = -0.5 * opt.Ke * m_w;
    }
}

static void emit_encoder(void)
{
    double counts = m_th / TWO_PI * (double)opt.counts_per_rev;
    int64_t target = (int64_t)floor(counts);
    int64_t gap = target - enc_emitted;
    if (gap > 1 || gap < -1) enc_double++;
    while (enc_emitted != target) {
        enc_emitted += target > enc_emitted ? 1 : -1;
        /* Gray code: 0 -> (A0 B0), 1 -> (A1 B0), 2 -> (A1 B1), 3 -> (A0 B1) */
        int q = (int)(((enc_emitted % 4) + 4) % 4);
        int a = q == 1 || q == 2, b = q >= 2;
        if ((int)pin_a->value != a) avr_raise_irq(pin_a, (uint32_t)a);
        if ((int)pin_b->value != b) avr_raise_irq(pin_b, (uint32_t)b);
        enc_edges++;
    }
}

static void motor_step(int h)
{
    double vp, vn;
    terminals(&vp, &vn);
    double v = vp - vn;
    double w0 = m_w;
    if (opt.ramp_s > 0) { /* encoder test: the shaft is driven, the winding ignored */
        double t = now_s() - opt.ramp_start_s;
        double w = t <= 0 ? 0 : t >= opt.ramp_s ? opt.ramp_w : opt.ramp_w * t / opt.ramp_s;
        m_th += 0.5 * (m_w + w) * h / F_CPU;
        m_w = w;
    } else if (!br_en && m_i == 0.0) { /* open and floating: the rotor coasts */
        double tf = m_w != 0 ? opt.Tc * sgn(m_w) + opt.Tload : 0.0;
        double w = m_w + h / F_CPU * (-opt.B * m_w - tf) / opt.J;
        if (m_w != 0 && sgn(w) != sgn(m_w)) w = 0;
        if (m_w == 0 && fabs(opt.Tload) > opt.Tc) w = -sgn(opt.Tload) * 1e-9;
        m_th += 0.5 * (m_w + w) * h / F_CPU;
        m_w = w;
    } else {
        double text;
        int stuck = 0;
        if (m_w != 0) {
            text = opt.Tc * sgn(m_w) + opt.Tload;
        } else {
            double drive = opt.Kt * m_i - opt.Tload;
            if (fabs(drive) <= opt.Tc) {
                stuck = 1;
                text = 0;
            } else {
                text = opt.Tc * sgn(drive) + opt.Tload;
            }
        }
        double i0 = m_i;
        if (stuck) {
            double inf = v / opt.R;
            m_i = inf + (m_i - inf) * E_RL[h];
        } else {
            double i = PHI[h][0][0] * m_i + PHI[h][0][1] * m_w + GAM[h][0][0] * v + GAM[h][0][1] * text;
            double w = PHI[h][1][0] * m_i + PHI[h][1][1] * m_w + GAM[h][1][0] * v + GAM[h][1][1] * text;
            if (w0 != 0 && sgn(w) != sgn(w0)) w = 0; /* friction stopped it */
            m_i = i;
            m_w = w;
        }
        if (!br_en && sgn(m_i) != sgn(i0)) m_i = 0.0; /* diodes block the reverse */
        m_th += 0.5 * (w0 + m_w) * h / F_CPU;
    }
    /* terminal dividers with their RC low-pass (pins clamp to the rails) */
    double tp = vp / opt.divider, tn = vn / opt.divider;
    tp = tp < 0 ? 0 : tp > 5 ? 5 : tp;
    tn = tn < 0 ? 0 : tn > 5 ? 5 : tn;
    node_p += (tp - node_p) * RC_A[h];
    node_n += (tn - node_n) * RC_A[h];
}

/* Bring the motor (and encoder) to the current cycle under the bridge state held since. */
static void motor_advance(void)
{
    while (m_t < avr->cycle) {
        uint64_t left = avr->cycle - m_t;
        int h = left > TICK_CYCLES ? TICK_CYCLES : (int)left;
        motor_step(h);
        m_t += (uint64_t)h;
        emit_encoder();
    }
}

static void on_pin_change(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)value;
    (void)param;
    motor_advance();
    bridge_refresh();
}

static void on_portb(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    motor_advance();
    bridge_refresh();
    int hi = (value >> 5) & 1; /* D13: the sample routine */
    if (hi && !sample_pin) {
        sample_hi_since = avr->cycle;
        n_samples_pin++;
        start_ring[start_w++ % RING] = avr->cycle;
    } else if (!hi && sample_pin) {
        uint64_t d = avr->cycle - sample_hi_since;
        if (d > sample_max_cycles) sample_max_cycles = d;
    }
    sample_pin = hi;
    hi = (value >> 4) & 1; /* D12: a host byte is handled */
    if (hi && !rx_pin) {
        rx_hi_since = avr->cycle;
    } else if (!hi && rx_pin) {
        uint64_t d = avr->cycle - rx_hi_since;
        if (d > rx_max_cycles) rx_max_cycles = d;
    }
    rx_pin = hi;
    hi = (value >> 3) & 1; /* D11: the encoder count is latched for a sample */
    if (hi && !capture_pin) cap_ring[cap_w++ % RING] = avr->cycle;
    capture_pin = hi;
}

/* The instant in `ring` that belongs to the grid instant `expect` (cycles): the first at
 * or after it, less the 4 us steps of micros(). */
static void lateness_add(lateness_t *l, const uint64_t *ring, unsigned written, uint64_t expect)
{
    uint64_t best = 0;
    int found = 0;
    unsigned n = written < RING ? written : RING;
    for (unsigned k = 0; k < n; ++k) {
        uint64_t c = ring[k];
        if (c + 64 >= expect && (!found || c < best)) {
            best = c;
            found = 1;
        }
    }
    if (!found) return;
    double us = ((double)best - (double)expect) / 16.0;
    l->n++;
    l->sum += us;
    if (us < l->min) l->min = us;
    if (us > l->max) l->max = us;
}

/* A telemetry frame the board sent: how late its sample was taken. */
static void timing_on_telemetry(uint32_t time_us)
{
    if (!t0_seen) return;
    uint64_t expect = t0_cycle + (uint64_t)time_us * 16;
    lateness_add(&late_cap, cap_ring, cap_w, expect);
    lateness_add(&late_start, start_ring, start_w, expect);
}

static void monitor_byte(uint8_t byte)
{
    uint8_t payload[PMDC_MAX_PAYLOAD];
    pmdc_msg_t m;
    int n = pmdc_parser_feed(&mon_parser, byte, payload);
    if (n > 0 && pmdc_decode_payload(payload, (size_t)n, &m) == PMDC_OK &&
        m.type == PMDC_TELEMETRY)
        timing_on_telemetry(m.u.telemetry.time_us);
}

/* ---- Timer1's waveform generator ---------------------------------------------------
 * simavr 1.6 maps the ATmega328P's mode 14 (fast PWM, TOP = ICR1) to its phase-correct
 * model and then ignores OCR1x writes, so its OC1A/OC1B pins do not follow the
 * duty. The rig therefore generates OC1A/OC1B itself from the registers, as the
 * datasheet (ch. 15.9.3) describes mode 14: the counter restarts when TCCR1B is
 * written, OCR1x is latched at BOTTOM, the output is set at BOTTOM and cleared on
 * the compare match (high for OCR1x + 1 of the ICR1 + 1 timer steps). The sketch
 * never reads TCNT1 or uses Timer1 interrupts, so nothing else depends on it. */
static uint8_t t1_tccrb = 0xFF;
static uint16_t t1_icr;
static int t1_warned;
static uint64_t t1_gen; /* bumps when the timer is reconfigured: stale events drop out */

static uint16_t reg16(int lo) { return (uint16_t)(avr->data[lo] | (avr->data[lo + 1] << 8)); }

static avr_cycle_count_t on_t1_fall(struct avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a;
    (void)when;
    uint64_t p = (uint64_t)(uintptr_t)param;
    if ((p >> 1) != (t1_gen & 0x7FFFFFFF)) return 0;
    motor_advance();
    if (p & 1) oc1b = 0;
    else oc1a = 0;
    bridge_refresh();
    return 0;
}

static avr_cycle_count_t on_t1_bottom(struct avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a;
    if ((uint64_t)(uintptr_t)param != t1_gen || !t1_period) return 0;
    motor_advance();
    static const uint16_t prescale[8] = {0, 1, 8, 64, 256, 1024, 0, 0};
    uint64_t ps = prescale[t1_tccrb & 7];
    uint16_t top = t1_icr;
    for (int ch = 0; ch < 2; ++ch) {
        uint16_t ocr = reg16(ch ? R_OCR1BL : R_OCR1AL);
        int *oc = ch ? &oc1b : &oc1a;
        if (ocr >= top) {
            *oc = 1; /* OCR1x = TOP: constantly high */
        } else {
            *oc = 1;
            uintptr_t tag = (uintptr_t)(((t1_gen & 0x7FFFFFFF) << 1) | (uint64_t)ch);
            avr_cycle_timer_register(avr, (ocr + 1) * ps, on_t1_fall, (void *)tag);
        }
    }
    bridge_refresh();
    return when + t1_period;
}

/* Called every tick: a TCCR1B or ICR1 write restarts the counter (as it does in simavr). */
static void t1_watch(void)
{
    uint8_t b = avr->data[R_TCCR1B];
    uint16_t icr = reg16(R_ICR1L);
    if (b == t1_tccrb && icr == t1_icr) return;
    t1_tccrb = b;
    t1_icr = icr;
    t1_gen++;
    uint8_t mode = (uint8_t)(((b >> 3) & 3) << 2) | (avr->data[R_TCCR1A] & 3);
    static const uint16_t prescale[8] = {0, 1, 8, 64, 256, 1024, 0, 0};
    uint64_t ps = prescale[b & 7];
    motor_advance();
    oc1a = oc1b = 0;
    if (mode == 14 && ps && icr > 0) {
        t1_period = (uint64_t)(icr + 1) * ps;
        avr_cycle_timer_register(avr, 1, on_t1_bottom, (void *)(uintptr_t)t1_gen);
    } else {
        t1_period = 0;
        if ((avr->data[R_TCCR1A] & 0xF0) && !t1_warned && ps) {
            t1_warned = 1;
            fprintf(stderr, "pmdc_emu: Timer1 mode %u drives OC1A/OC1B: only mode 14 (fast "
                            "PWM, TOP = ICR1) is modelled; the pins follow PORTB\n", mode);
        }
    }
    bridge_refresh();
}

/* ---- encoder check: firmware count against the emitted edges -------------------------- */
static void encoder_check(void)
{
    if (!enc_addr || !avr->sreg[S_I] || (avr->data[R_EIFR] & 0x03)) return;
    if ((avr->data[R_EIMSK] & 0x03) != 0x03) {
        enc_armed = 0;
        return;
    }
    int16_t fw;
    memcpy(&fw, &avr->data[enc_addr], 2); /* the ISR's 16-bit counter */
    int64_t diff = (int16_t)(uint16_t)((uint64_t)enc_emitted - (uint64_t)(uint16_t)fw);
    if (!enc_armed) {
        enc_armed = 1;
        enc_offset = diff;
        return;
    }
    enc_checks++;
    if (diff != enc_offset) {
        int64_t d = (int16_t)(uint16_t)(diff - enc_offset);
        enc_missed += (uint64_t)(d > 0 ? d : -d);
        double rate = fabs(m_w) * (double)opt.counts_per_rev / TWO_PI;
        if (enc_first_miss_rate < 0) enc_first_miss_rate = rate;
        enc_offset = diff;
    }
}

static avr_cycle_count_t on_tick(struct avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a;
    (void)param;
    motor_advance();
    t1_watch();
    bridge_refresh(); /* catches TCCR1A (COM bits) writes, which raise no IRQ */
    if (!t0_seen && (avr->data[R_TCCR0B] & 7)) { /* Timer0 started: micros() counts */
        t0_seen = 1;
        t0_cycle = avr->cycle;
    }
    double rate = fabs(m_w) * (double)opt.counts_per_rev / TWO_PI;
    if (rate > enc_max_rate) enc_max_rate = rate;
    if ((when & 0x3FF) < TICK_CYCLES) encoder_check();
    return when + TICK_CYCLES;
}

/* ---- ADC: the value is taken when the sample-and-hold closes -------------------------- */
static avr_cycle_count_t on_adc_hold(struct avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a;
    (void)when;
    (void)param;
    motor_advance();
    int src = adc_pending_src;
    double v = 0.0;
    switch (src) {
    case 0: v = 2.5 + opt.acs_v_per_a * (m_i + opt.current_noise_a * gauss()); break;
    case 1: v = opt.supply_v / opt.divider; break;
    case 2: v = node_p; break;
    case 3: v = node_n; break;
    default: v = 0.0; break;
    }
    if (v < 0) v = 0;
    if (v > 5) v = 5;
    if (src >= 0 && src < 8) avr_raise_irq(adc_irq + ADC_IRQ_ADC0 + src, (uint32_t)lround(v * 1000.0));
    return 0;
}

static void on_adc_trigger(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    union {
        avr_adc_mux_t mux;
        uint32_t v;
    } e = {.v = value};
    adc_conversions++;
    adc_pending_src = e.mux.kind == ADC_MUX_SINGLE ? (int)e.mux.src : -1;
    uint8_t ps = avr->data[R_ADCSRA] & 7;
    adc_prescaler = ps ? (1u << ps) : 2u;
    avr_cycle_timer_register(avr, adc_prescaler * 3 / 2, on_adc_hold, NULL);
}

/* ---- UART <-> pty / scripted host ------------------------------------------------------ */
static void host_on_byte(uint8_t byte);

static void on_uart_out(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    uint8_t b = (uint8_t)value;
    monitor_byte(b);
    if (opt.host_period_us) {
        host_on_byte(b);
        return;
    }
    if (line_cut) {
        __atomic_fetch_add(&bytes_lost, 1, __ATOMIC_RELAXED);
        return;
    }
    size_t head = __atomic_load_n(&tx_head, __ATOMIC_RELAXED);
    if (head - __atomic_load_n(&tx_tail, __ATOMIC_ACQUIRE) < PTY_RING) {
        tx_ring[head % PTY_RING] = b;
        __atomic_store_n(&tx_head, head + 1, __ATOMIC_RELEASE);
    } else {
        __atomic_fetch_add(&bytes_lost, 1, __ATOMIC_RELAXED); /* the adapter is full */
    }
}

static void on_xon(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)value;
    (void)param;
    uart_xon = 1;
}

static void on_xoff(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)value;
    (void)param;
    uart_xon = 0;
}

/* One host byte onto the wire every byte time (a UART at the host's baud). */
static avr_cycle_count_t on_rx_feed(struct avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a;
    (void)param;
    if (!rx_len) return 0;
    if (!uart_xon) return when + cycles_per_byte / 4;
    uint8_t b = rx_buf[rx_head];
    rx_head = (rx_head + 1) % sizeof rx_buf;
    rx_len--;
    avr_raise_irq(uart_in, b);
    bytes_from_host++;
    if (b == 0) {
        last_delim_end = when + cycles_per_byte;
        latency_open = 1;
    }
    return rx_len ? when + cycles_per_byte : 0;
}

static void host_send(const uint8_t *data, size_t n)
{
    int idle = rx_len == 0;
    for (size_t k = 0; k < n && rx_len < sizeof rx_buf; ++k) {
        rx_buf[(rx_head + rx_len) % sizeof rx_buf] = data[k];
        rx_len++;
    }
    if (idle && rx_len && avr_cycle_timer_status(avr, on_rx_feed, NULL) == 0)
        avr_cycle_timer_register(avr, 1, on_rx_feed, NULL);
}

/* ---- the scripted host ------------------------------------------------------------------ */
static void host_msg(pmdc_msg_t *m)
{
    uint8_t out[PMDC_MAX_WIRE];
    m->seq = ++host_seq;
    size_t n = pmdc_encode_frame(m, out);
    host_send(out, n);
}

static void host_hello(void)
{
    pmdc_msg_t m;
    memset(&m, 0, sizeof m);
    m.type = PMDC_HELLO;
    m.u.hello.host_version = PMDC_PROTOCOL_VERSION;
    host_msg(&m);
}

static void host_on_byte(uint8_t byte)
{
    uint8_t payload[PMDC_MAX_PAYLOAD];
    pmdc_msg_t m;
    bytes_to_host++;
    int n = pmdc_parser_feed(&host_parser, byte, payload);
    if (n <= 0) return;
    if (pmdc_decode_payload(payload, (size_t)n, &m) != PMDC_OK) {
        host_errors++;
        return;
    }
    if (m.type == PMDC_BOOT) {
        host_boots++;
        host_streaming = 0;
        host_have_counter = 0;
        host_hello();
    } else if (m.type == PMDC_HELLO_ACK) {
        pmdc_msg_t s;
        memset(&s, 0, sizeof s);
        s.type = PMDC_START_STREAM;
        s.u.start_stream.period_us = (uint32_t)opt.host_period_us;
        s.u.start_stream.watchdog_ms = 500;
        host_msg(&s);
    } else if (m.type == PMDC_ACK && m.u.ack.acked_type == PMDC_START_STREAM) {
        host_streaming = 1;
    } else if (m.type == PMDC_ERROR) {
        host_errors++;
        fprintf(stderr, "pmdc_emu: host: board refused type %u (code %u, detail %lu)\n",
                m.u.error.refused_type, m.u.error.code, (unsigned long)m.u.error.detail);
    } else if (m.type == PMDC_TELEMETRY) {
        pmdc_telemetry_t *t = &m.u.telemetry;
        if (host_have_counter && t->counter != host_last_counter + 1)
            host_dropped += (uint64_t)(t->counter - host_last_counter - 1);
        host_have_counter = 1;
        host_last_counter = t->counter;
        host_enc_last = t->encoder_count;
        host_frames++;
        if ((t->faults & PMDC_FAULT_WATCHDOG) && host_watchdog_s < 0 && host_silent_cycle)
            host_watchdog_s = (double)(avr->cycle - host_silent_cycle) / F_CPU;
    }
}

/* Every millisecond of board time: the host's commands (voltage steps, pings). */
static avr_cycle_count_t on_host_tick(struct avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a;
    (void)param;
    static uint64_t k;
    double t = now_s();
    if (opt.host_silent_at_s > 0 && t >= opt.host_silent_at_s) {
        if (!host_silent_cycle) host_silent_cycle = when;
        if (!br_en && !host_watchdog_open_cycle) {
            host_watchdog_open_cycle = when;
            host_open_after_frame_s = (double)(when - last_delim_end) / F_CPU;
        }
        return when + 16000;
    }
    if (host_streaming) {
        uint64_t every = (uint64_t)(opt.host_step_every_s * 1000.0 + 0.5);
        if (every && k % every == 0) {
            pmdc_msg_t m;
            memset(&m, 0, sizeof m);
            m.type = PMDC_SET_VOLTAGE;
            m.u.set_voltage.millivolts = (k / every) % 2 ? 0 : (int32_t)(opt.host_step_v * 1000);
            if (opt.ramp_s > 0) m.type = PMDC_PING; /* the shaft is driven: no command */
            host_msg(&m);
        } else if (k % 100 == 0) {
            pmdc_msg_t m;
            memset(&m, 0, sizeof m);
            m.type = PMDC_PING;
            m.u.ping.token = (uint32_t)k;
            host_msg(&m);
        }
        k++;
    }
    return when + 16000;
}

/* ---- pty ---------------------------------------------------------------------------------- */
static int open_pty(void)
{
    pty_master = posix_openpt(O_RDWR | O_NOCTTY);
    if (pty_master < 0 || grantpt(pty_master) || unlockpt(pty_master)) return -1;
    const char *name = ptsname(pty_master);
    if (!name) return -1;
    snprintf(pty_name, sizeof pty_name, "%s", name);
    /* Keep the slave open ourselves so the pty survives host reconnects. */
    pty_slave = open(pty_name, O_RDWR | O_NOCTTY);
    if (pty_slave < 0) return -1;
    struct termios tio;
    if (tcgetattr(pty_slave, &tio) == 0) {
        cfmakeraw(&tio);
        tcsetattr(pty_slave, TCSANOW, &tio);
    }
    if (tcgetattr(pty_master, &tio) == 0) {
        cfmakeraw(&tio);
        tcsetattr(pty_master, TCSANOW, &tio);
    }
    fcntl(pty_master, F_SETFL, fcntl(pty_master, F_GETFL) | O_NONBLOCK);
    return 0;
}

/* The pty's side of the UART, in its own thread: a pty read or write can block in the
 * kernel for tens of milliseconds (its locks are shared with the host's side, whose
 * threads a busy machine holds up), and the board's clock must not wait for it. */
static void *pty_thread(void *arg)
{
    (void)arg;
    uint8_t buf[4096];
    uint64_t drop;
    while (!pty_stop) {
        size_t head = __atomic_load_n(&tx_head, __ATOMIC_ACQUIRE);
        size_t tail = __atomic_load_n(&tx_tail, __ATOMIC_RELAXED);
        struct pollfd p[2] = {{.fd = pty_master, .events = POLLIN | (head != tail ? POLLOUT : 0)},
                              {.fd = tx_event, .events = POLLIN}};
        if (poll(p, 2, 100) < 0 && errno != EINTR) break;
        if (p[1].revents & POLLIN) (void)!read(tx_event, &drop, sizeof drop);
        for (;;) { /* host -> board */
            size_t ih = __atomic_load_n(&in_head, __ATOMIC_RELAXED);
            size_t room = PTY_RING - (ih - __atomic_load_n(&in_tail, __ATOMIC_ACQUIRE));
            if (!room) break; /* the board reads them at the line rate: wait */
            ssize_t n = read(pty_master, buf, room < sizeof buf ? room : sizeof buf);
            if (n <= 0) break;
            for (ssize_t k = 0; k < n; ++k) in_ring[(ih + (size_t)k) % PTY_RING] = buf[k];
            __atomic_store_n(&in_head, ih + (size_t)n, __ATOMIC_RELEASE);
            uint64_t one = 1;
            (void)!write(in_event, &one, sizeof one);
        }
        while (tail != head) { /* board -> host */
            size_t chunk = head - tail, at = tail % PTY_RING;
            if (chunk > PTY_RING - at) chunk = PTY_RING - at;
            ssize_t n = write(pty_master, tx_ring + at, chunk);
            if (n <= 0) {
                if (n < 0 && errno == EAGAIN) break; /* the host reads slowly: later */
                __atomic_fetch_add(&bytes_lost, head - tail, __ATOMIC_RELAXED);
                tail = head; /* nobody reads: a UART sends into the void */
                break;
            }
            tail += (size_t)n;
            __atomic_fetch_add(&bytes_to_host, (uint64_t)n, __ATOMIC_RELAXED);
        }
        __atomic_store_n(&tx_tail, tail, __ATOMIC_RELEASE);
    }
    return NULL;
}

static int pty_thread_start(void)
{
    tx_event = eventfd(0, EFD_NONBLOCK);
    in_event = eventfd(0, EFD_NONBLOCK);
    if (tx_event < 0 || in_event < 0) return -1;
    if (pthread_create(&pty_tid, NULL, pty_thread, NULL) != 0) return -1;
    pty_thread_on = 1;
    return 0;
}

/* The emulation's side: take the host's bytes, hand the board's over. */
static void pty_io(void)
{
    if (!pty_thread_on) return;
    uint8_t buf[4096];
    size_t tail = __atomic_load_n(&in_tail, __ATOMIC_RELAXED);
    size_t head = __atomic_load_n(&in_head, __ATOMIC_ACQUIRE);
    while (tail != head) {
        size_t n = head - tail, k;
        if (n > sizeof buf) n = sizeof buf;
        for (k = 0; k < n; ++k) buf[k] = in_ring[(tail + k) % PTY_RING];
        tail += n;
        if (!line_cut) host_send(buf, n);
    }
    __atomic_store_n(&in_tail, tail, __ATOMIC_RELEASE);
    if (__atomic_load_n(&tx_head, __ATOMIC_RELAXED) != __atomic_load_n(&tx_tail, __ATOMIC_ACQUIRE)) {
        uint64_t one = 1;
        (void)!write(tx_event, &one, sizeof one);
    }
}

/* ---- set-up ---------------------------------------------------------------------------------- */
static void on_signal(int sig)
{
    if (sig == SIGUSR1) sig_reset = 1;
    else if (sig == SIGUSR2) sig_cut = 1;
    else if (sig == SIGCONT) sig_cont = 1;
    else sig_stop = 1;
}

/* SCHED_DEADLINE: the kernel reserves `share` of a core for this process in every 10 ms
 * and never gives it more. The board keeps its time on a busy machine (no other task,
 * real-time ones included, can hold it up), and a catching-up emulator cannot take a
 * whole core (a real-time priority would let it starve the host it serves). Needs
 * CAP_SYS_NICE; where refused, it runs as started (the caller may have niced it). */
struct pmdc_sched_attr {
    uint32_t size, sched_policy;
    uint64_t sched_flags;
    int32_t sched_nice;
    uint32_t sched_priority;
    uint64_t sched_runtime, sched_deadline, sched_period;
};

static void reserve_cpu(double share)
{
    errno = 0;
    int nice_v = getpriority(PRIO_PROCESS, 0);
    snprintf(sched_text, sizeof sched_text, "normal, nice %d", nice_v);
    if (share <= 0) return;
#ifdef SYS_sched_setattr
    struct pmdc_sched_attr a;
    memset(&a, 0, sizeof a);
    a.size = sizeof a;
    a.sched_policy = 6; /* SCHED_DEADLINE */
    a.sched_period = a.sched_deadline = 10000000ULL;
    a.sched_runtime = (uint64_t)(share * 1e7);
    if (syscall(SYS_sched_setattr, 0, &a, 0) == 0) {
        snprintf(sched_text, sizeof sched_text, "deadline, %.2f of a core", share);
        return;
    }
    snprintf(sched_text, sizeof sched_text, "normal, nice %d (deadline refused: %s)", nice_v,
             strerror(errno));
#endif
}

static double wall_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void register_timers(void)
{
    avr_cycle_timer_register(avr, TICK_CYCLES, on_tick, NULL);
    t1_tccrb = 0xFF; /* re-arm the waveform generator */
    if (opt.host_period_us) avr_cycle_timer_register(avr, 16000, on_host_tick, NULL);
    if (rx_len) avr_cycle_timer_register(avr, 1, on_rx_feed, NULL);
}

static void write_stats(double wall_s)
{
    if (!opt.stats) return;
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    double cpu = ru.ru_utime.tv_sec + ru.ru_utime.tv_usec * 1e-6 + ru.ru_stime.tv_sec +
                 ru.ru_stime.tv_usec * 1e-6;
    double sim = now_s();
    double total = (double)(cyc_isr + cyc_sample + cyc_rx + cyc_idle);
    if (total <= 0) total = 1;
    char tmp[4096];
    snprintf(tmp, sizeof tmp, "%s.tmp%ld", opt.stats, (long)getpid());
    FILE *f = fopen(tmp, "w");
    if (!f) return;
    fprintf(f,
            "{\"sim_s\": %.6f, \"wall_s\": %.6f, \"cpu_s\": %.6f, \"stalled_s\": %.6f,\n"
            " \"cpu\": {\"isr\": %.6f, \"sample\": %.6f, \"rx\": %.6f, \"idle\": %.6f},\n"
            " \"samples_pin\": %llu, \"sample_max_us\": %.2f, \"rx_max_us\": %.2f,\n"
            " \"timing\": {\"capture_late_us\": {\"n\": %llu, \"mean\": %.2f, \"min\": %.2f, "
            "\"max\": %.2f}, \"start_late_us\": {\"n\": %llu, \"mean\": %.2f, \"min\": %.2f, "
            "\"max\": %.2f}, \"bridge_after_capture_us\": {\"n\": %llu, \"mean\": %.2f, "
            "\"min\": %.2f, \"max\": %.2f}},\n"
            " \"realtime\": {\"sched\": \"%s\", \"behind_max_s\": %.4f, \"behind_s\": %.3f},\n"
            " \"adc\": {\"conversions\": %llu, \"prescaler\": %u, \"conversion_us\": %.3f},\n"
            " \"latency_us\": {\"n\": %llu, \"mean\": %.2f, \"max\": %.2f},\n"
            " \"encoder\": {\"counts_per_rev\": %ld, \"edges\": %llu, \"missed\": %llu, "
            "\"checks\": %llu, \"first_miss_edge_rate\": %.1f, \"max_edge_rate\": %.1f, "
            "\"emulator_double_edges\": %llu, \"emitted\": %lld},\n"
            " \"uart\": {\"to_host\": %llu, \"from_host\": %llu, \"lost\": %llu},\n"
            " \"host\": {\"frames\": %llu, \"dropped\": %llu, \"errors\": %llu, \"boots\": %llu, "
            "\"parser_errors\": %lu, \"watchdog_s\": %.6f, \"open_after_silent_s\": %.6f, "
            "\"open_after_last_frame_s\": %.6f, "
            "\"last_encoder_count\": %lld},\n"
            " \"motor\": {\"i\": %.6f, \"w\": %.6f, \"theta\": %.6f}}\n",
            sim, wall_s, cpu, stalled_cycles / F_CPU, cyc_isr / total, cyc_sample / total,
            cyc_rx / total, cyc_idle / total, (unsigned long long)n_samples_pin,
            sample_max_cycles / 16.0, rx_max_cycles / 16.0, (unsigned long long)late_cap.n,
            late_cap.n ? late_cap.sum / late_cap.n : 0.0, late_cap.n ? late_cap.min : 0.0,
            late_cap.n ? late_cap.max : 0.0, (unsigned long long)late_start.n,
            late_start.n ? late_start.sum / late_start.n : 0.0, late_start.n ? late_start.min : 0.0,
            late_start.n ? late_start.max : 0.0, (unsigned long long)bridge_after.n,
            bridge_after.n ? bridge_after.sum / bridge_after.n : 0.0,
            bridge_after.n ? bridge_after.min : 0.0, bridge_after.n ? bridge_after.max : 0.0,
            sched_text, behind_max_s, behind_total_s,
            (unsigned long long)adc_conversions, adc_prescaler,
            13.0 * adc_prescaler / 16.0, (unsigned long long)lat_n,
            lat_n ? lat_sum / 16.0 / lat_n : 0.0, lat_max / 16.0, opt.counts_per_rev,
            (unsigned long long)enc_edges, (unsigned long long)enc_missed,
            (unsigned long long)enc_checks, enc_first_miss_rate, enc_max_rate,
            (unsigned long long)enc_double, (long long)enc_emitted,
            (unsigned long long)bytes_to_host, (unsigned long long)bytes_from_host,
            (unsigned long long)bytes_lost, (unsigned long long)host_frames,
            (unsigned long long)host_dropped, (unsigned long long)host_errors,
            (unsigned long long)host_boots, (unsigned long)pmdc_parser_errors(&host_parser),
            host_watchdog_s,
            host_watchdog_open_cycle && host_silent_cycle
                ? (double)(host_watchdog_open_cycle - host_silent_cycle) / F_CPU
                : -1.0,
            host_open_after_frame_s, (long long)host_enc_last, m_i, m_w, m_th);
    fclose(f);
    rename(tmp, opt.stats);
}

static void usage(FILE *f)
{
    fprintf(f,
            "usage: pmdc_emu --firmware ELF [options]\n"
            "  --motor R,L,Ke,Kt,J,B,Tc[,Tload]  motor (SI units; Tc Coulomb friction, N*m)\n"
            "  --supply V  --acs712 V_PER_A  --divider RATIO  --terminal-tau S\n"
            "  --current-noise A  --seed N  --counts-per-rev N  --baud N (host side)\n"
            "  --free-run (no wall-clock pacing)  --duration S (simulated)  --link PATH\n"
            "  --parent PID  --stats FILE (JSON at exit)\n"
            "  --ramp W,S[,START]  drive the shaft at a speed ramp 0 -> W rad/s over S s\n"
            "  --host PERIOD_US  scripted host instead of the pty: HELLO, START_STREAM,\n"
            "                    voltage steps (--step V,EVERY_S), pings\n"
            "  --host-silent-at S  the scripted host falls silent at S (watchdog test)\n"
            "  --profile FILE  cycles spent per flash address (\"ADDR CYCLES\" lines)\n"
            "  --cpu-share F  reserve F of a core (0.05..0.95) with SCHED_DEADLINE where\n"
            "                 permitted: always served, never more (else it runs as started)\n");
}

static int parse(int argc, char **argv)
{
    static struct option lo[] = {
        {"firmware", 1, 0, 'f'}, {"motor", 1, 0, 'm'}, {"supply", 1, 0, 's'},
        {"acs712", 1, 0, 'a'}, {"divider", 1, 0, 'd'}, {"terminal-tau", 1, 0, 't'},
        {"current-noise", 1, 0, 'n'}, {"seed", 1, 0, 'S'}, {"counts-per-rev", 1, 0, 'c'},
        {"baud", 1, 0, 'b'}, {"free-run", 0, 0, 'F'}, {"duration", 1, 0, 'D'},
        {"link", 1, 0, 'l'}, {"parent", 1, 0, 'p'}, {"stats", 1, 0, 'j'},
        {"ramp", 1, 0, 'r'}, {"host", 1, 0, 'H'}, {"host-silent-at", 1, 0, 'w'},
        {"step", 1, 0, 'x'}, {"profile", 1, 0, 'P'}, {"cpu-share", 1, 0, 'C'},
        {"help", 0, 0, 'h'}, {0, 0, 0, 0}};
    int c;
    while ((c = getopt_long(argc, argv, "", lo, NULL)) != -1) {
        switch (c) {
        case 'f': opt.firmware = optarg; break;
        case 'm': {
            double v[8] = {0};
            int n = sscanf(optarg, "%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf", &v[0], &v[1], &v[2], &v[3],
                           &v[4], &v[5], &v[6], &v[7]);
            if (n < 7) {
                fprintf(stderr, "pmdc_emu: --motor needs R,L,Ke,Kt,J,B,Tc[,Tload]\n");
                return -1;
            }
            opt.R = v[0], opt.L = v[1], opt.Ke = v[2], opt.Kt = v[3], opt.J = v[4];
            opt.B = v[5], opt.Tc = v[6], opt.Tload = n > 7 ? v[7] : 0.0;
            break;
        }
        case 's': opt.supply_v = atof(optarg); break;
        case 'a': opt.acs_v_per_a = atof(optarg); break;
        case 'd': opt.divider = atof(optarg); break;
        case 't': opt.term_tau_s = atof(optarg); break;
        case 'n': opt.current_noise_a = atof(optarg); break;
        case 'S': opt.seed = strtoul(optarg, NULL, 0); break;
        case 'c': opt.counts_per_rev = atol(optarg); break;
        case 'b': opt.baud = atol(optarg); break;
        case 'F': opt.realtime = 0; break;
        case 'D': opt.duration_s = atof(optarg); break;
        case 'l': opt.link = optarg; break;
        case 'p': opt.parent = atol(optarg); break;
        case 'j': opt.stats = optarg; break;
        case 'r': {
            opt.ramp_start_s = 0.5;
            if (sscanf(optarg, "%lf,%lf,%lf", &opt.ramp_w, &opt.ramp_s, &opt.ramp_start_s) < 2) {
                fprintf(stderr, "pmdc_emu: --ramp needs W,S[,START]\n");
                return -1;
            }
            break;
        }
        case 'H': opt.host_period_us = atol(optarg); break;
        case 'w': opt.host_silent_at_s = atof(optarg); break;
        case 'x':
            if (sscanf(optarg, "%lf,%lf", &opt.host_step_v, &opt.host_step_every_s) != 2) {
                fprintf(stderr, "pmdc_emu: --step needs V,EVERY_S\n");
                return -1;
            }
            break;
        case 'P': opt.profile = optarg; break;
        case 'C': opt.cpu_share = atof(optarg); break;
        case 'h': usage(stdout); exit(0);
        default: usage(stderr); return -1;
        }
    }
    if (!opt.firmware) {
        fprintf(stderr, "pmdc_emu: --firmware ELF is required\n");
        return -1;
    }
    if (!(opt.R > 0 && opt.L > 0 && opt.Ke > 0 && opt.Kt > 0 && opt.J > 0 && opt.B >= 0 &&
          opt.Tc >= 0 && opt.supply_v > 0 && opt.counts_per_rev > 0 && opt.baud >= 300 &&
          opt.term_tau_s > 0 && opt.divider > 0 && opt.acs_v_per_a > 0 &&
          (opt.cpu_share == 0.0 || (opt.cpu_share >= 0.05 && opt.cpu_share <= 0.95)))) {
        fprintf(stderr, "pmdc_emu: motor, supply, sensor and encoder values must be positive, "
                        "--cpu-share within 0.05..0.95\n");
        return -1;
    }
    return 0;
}

int main(int argc, char **argv)
{
    if (parse(argc, argv)) return 2;
    /* End with the parent: the kernel signals us when it dies, and we check it too. */
    if (opt.parent > 0) {
        prctl(PR_SET_PDEATHSIG, SIGTERM);
        if (getppid() != (pid_t)opt.parent) return 0;
    }
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGHUP, &sa, NULL);
    sigaction(SIGUSR1, &sa, NULL);
    sigaction(SIGUSR2, &sa, NULL);
    sigaction(SIGCONT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    rng_state ^= (uint64_t)opt.seed * 0x9E3779B97F4A7C15ULL;

    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(opt.firmware, &fw) != 0) {
        fprintf(stderr, "pmdc_emu: cannot read firmware %s\n", opt.firmware);
        return 1;
    }
    avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) {
        fprintf(stderr, "pmdc_emu: simavr has no atmega328p core\n");
        return 1;
    }
    avr_init(avr);
    avr->log = 0; /* the firmware's warnings are ours to judge, not simavr's to print */
    avr->frequency = (uint32_t)F_CPU;
    avr->vcc = avr->avcc = avr->aref = 5000;
    avr_load_firmware(avr, &fw);
    for (uint32_t k = 0; k < fw.symbolcount; ++k) {
        if (strcmp(fw.symbol[k]->symbol, "pmdc_encoder_count") == 0 &&
            fw.symbol[k]->addr >= 0x800000)
            enc_addr = (uint16_t)(fw.symbol[k]->addr - 0x800000);
    }

    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~(uint32_t)(AVR_UART_FLAG_POLL_SLEEP | AVR_UART_FLAG_STDIO);
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            on_uart_out, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
                            on_xon, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
                            on_xoff, NULL);
    cycles_per_byte = (uint32_t)(10.0 * F_CPU / (double)opt.baud + 0.5);

    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), IOPORT_IRQ_REG_PORT),
                            on_portb, NULL);
    avr_irq_register_notify(
        avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), IOPORT_IRQ_DIRECTION_ALL), on_pin_change,
        NULL);
    adc_irq = avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, 0);
    avr_irq_register_notify(adc_irq + ADC_IRQ_OUT_TRIGGER, on_adc_trigger, NULL);
    pin_a = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2);
    pin_b = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 3);
    avr_raise_irq(pin_a, 0);
    avr_raise_irq(pin_b, 0);
    build_tables();
    if (opt.profile) profile = calloc(0x4000, sizeof *profile);
    node_p = node_n = 0.0;
    pmdc_parser_init(&host_parser);
    pmdc_parser_init(&mon_parser);
    register_timers();

    if (!opt.host_period_us) {
        if (open_pty() != 0) {
            fprintf(stderr, "pmdc_emu: cannot open a pseudo-terminal: %s\n", strerror(errno));
            return 1;
        }
        if (opt.link) {
            unlink(opt.link);
            if (symlink(pty_name, opt.link) != 0) {
                fprintf(stderr, "pmdc_emu: cannot link %s: %s\n", opt.link, strerror(errno));
                return 1;
            }
        }
        if (pty_thread_start() != 0) {
            fprintf(stderr, "pmdc_emu: cannot start the pty thread: %s\n", strerror(errno));
            return 1;
        }
        printf("pty %s\n", pty_name);
        fflush(stdout);
    }
    reserve_cpu(opt.cpu_share); /* after the pty thread: a SCHED_DEADLINE task cannot clone */

    const uint64_t slice = 4096; /* 256 us of board time between I/O and pacing */
    double wall0 = wall_now(), wall_start = wall0, sim0 = 0.0, last_parent = wall0;
    double last_wall = wall0, last_warn = -1e9;
    uint64_t end_cycle = opt.duration_s > 0 ? (uint64_t)(opt.duration_s * F_CPU) : UINT64_MAX;
    int status = 0;
    while (!sig_stop && avr->cycle < end_cycle) {
        uint64_t stop = avr->cycle + slice;
        while (avr->cycle < stop) {
            uint64_t c0 = avr->cycle;
            int isr = !avr->sreg[S_I];
            uint8_t port = avr->data[R_PORTB];
            uint32_t pc = avr->pc;
            int st = avr_run(avr);
            uint64_t d = avr->cycle - c0;
            if (profile) profile[(pc >> 1) & 0x3FFF] += d;
            if (isr) cyc_isr += d;
            else if (port & 0x20) cyc_sample += d;
            else if (port & 0x10) cyc_rx += d;
            else cyc_idle += d;
            if (st == cpu_Done || st == cpu_Crashed) {
                fprintf(stderr, "pmdc_emu: the AVR %s at %.6f s (pc 0x%04x)\n",
                        st == cpu_Done ? "stopped" : "crashed", now_s(), avr->pc);
                status = 1;
                goto out;
            }
        }
        if (sig_reset) {
            sig_reset = 0;
            motor_advance();
            avr_reset(avr); /* clears the cycle timers: ours go back on */
            enc_armed = 0;
            t0_seen = 0; /* micros() starts again */
            cap_w = start_w = 0;
            oc1a = oc1b = 0;
            rx_len = 0;
            uart_xon = 1;
            register_timers();
            bridge_refresh();
            fprintf(stderr, "pmdc_emu: AVR reset at %.3f s\n", now_s());
        }
        if (sig_cut) {
            sig_cut = 0;
            line_cut = !line_cut;
            fprintf(stderr, "pmdc_emu: serial line %s\n", line_cut ? "cut" : "reconnected");
        }
        pty_io();
        double wall = wall_now();
        if (opt.realtime) {
            /* Paced by the wall clock: ahead, it waits; behind, it catches up as fast as
             * its CPU reservation lets it (a crystal-clocked board never lags). Paused
             * (SIGSTOP, then SIGCONT), or more than 1 s behind, the board's clock stood
             * still: the lost time is counted, not made up in a burst. */
            double ahead = (now_s() - sim0) - (wall - wall0);
            if (sig_cont || ahead < -1.0) {
                if (!sig_cont) {
                    fprintf(stderr,
                            "pmdc_emu: the board's clock stood still for %.2f s at board "
                            "time %.1f s: the emulator got no CPU (%s; raise --cpu-share)\n",
                            -ahead, now_s(), sched_text);
                }
                sig_cont = 0;
                double lost = ahead < 0 ? -ahead : 0.0;
                wall0 += lost;
                stalled_cycles += (uint64_t)(lost * F_CPU);
                ahead = 0.0;
            } else if (ahead < 0.0) {
                if (-ahead > behind_max_s) behind_max_s = -ahead;
                if (ahead < -0.05) behind_total_s += wall - last_wall;
                if (ahead < -0.25 && wall - last_warn > 10.0) {
                    last_warn = wall;
                    fprintf(stderr,
                            "pmdc_emu: the board runs %.2f s behind real time at board time "
                            "%.1f s: the emulator gets too little CPU (%s; raise --cpu-share)\n",
                            -ahead, now_s(), sched_text);
                }
            }
            last_wall = wall;
            if (ahead > 0.0005) { /* wait, for host bytes at most */
                struct pollfd p = {.fd = in_event, .events = POLLIN};
                int ms = (int)(ahead * 1000.0);
                if (ms > 5) ms = 5;
                if (in_event >= 0) {
                    uint64_t drop;
                    if (poll(&p, 1, ms) > 0) (void)!read(in_event, &drop, sizeof drop);
                } else {
                    usleep((useconds_t)(ahead * 1e6));
                }
            }
        }
        if (opt.parent > 0 && wall - last_parent > 0.1) {
            last_parent = wall;
            if (getppid() != (pid_t)opt.parent) break;
        }
    }
out:
    if (pty_thread_on) { /* its counters are final once it ends */
        uint64_t one = 1;
        pty_stop = 1;
        (void)!write(tx_event, &one, sizeof one);
        pthread_join(pty_tid, NULL);
        pty_thread_on = 0;
    }
    write_stats(wall_now() - wall_start);
    if (profile) {
        FILE *f = fopen(opt.profile, "w");
        for (int k = 0; f && k < 0x4000; ++k)
            if (profile[k]) fprintf(f, "%04x %llu\n", k * 2, (unsigned long long)profile[k]);
        if (f) fclose(f);
    }
    if (opt.link) {
        char target[256];
        ssize_t n = readlink(opt.link, target, sizeof target - 1);
        if (n > 0) {
            target[n] = 0;
            if (strcmp(target, pty_name) == 0) unlink(opt.link);
        }
    }
    if (pty_slave >= 0) close(pty_slave);
    if (pty_master >= 0) close(pty_master);
    return status;
}
