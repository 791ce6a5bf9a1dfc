/* printer-codegen simavr harness: a first-order thermal plant per heater, closed through the firmware's ADC and
 * PWM, with faults injected at simulated times; and a probe of the heater runtime's stages.
 *
 * Plant: C dT/dt = P - k (T - T_ambient), P = heater_w x duty, integrated exactly every 1 ms (STEPS_PER_S) with
 * the duty the timer's registers give at that moment: the compare output connected (COMnx1 in TCCRnA): duty =
 * (OCR + 1) / 256, the pin's 8-bit hardware fast PWM (simavr's pin keeps OCR = TOP low, a real one high);
 * disconnected: the PORT bit, 0 or 1.
 * Sensor: the thermistor divider's millivolts at T, interpolated in the table the plant file gives; the ADC reads
 * floor(1024 x mV / AVCC), at most 1023 (an ideal 10-bit converter, as codegen/heaters/sensors.py models it).
 * simavr 1.6 mishandles ADC8..15 (MUX5), so the harness replaces the ADCL and ADCH read handlers: ADCL computes
 * the reading of the channel ADMUX and ADCSRB select, ADCH returns its high byte.
 * Faults from a cycle on: open (the pin at AVCC), short (at 0 V), dead (heater power 0), loose (the sensor reads
 * ambient).
 *
 * Plant file (text, numbers separated by blanks; written by codegen/sim/avr_plant.py):
 *   log PATH                     where the trace goes
 *   avcc MV  sample CYCLES       AVCC in millivolts; a sample of every heater every CYCLES
 *   heater ADC OCR TCCRA COM_MASK PORT BIT CAPACITY_J_PER_K LOSS_W_PER_K HEATER_W AMBIENT_C START_C FIRST_C STEP_C N MV...
 *       (data-space addresses; OCR: the low byte, the timer in 8-bit fast PWM)
 *   fault HEATER open|short|dead|loose CYCLE
 *   stage ADDR                   the byte address of the firmware's heaters_poll: its calls are measured
 *   fan OCR TCCRA COM_MASK PORT BIT   a fan's PWM output (no plant): its duty is logged
 * Trace lines: "A cycle heater reading" at each ADC read of a heater's channel, "D cycle heater duty256" at
 * each change of a heater's duty (seen at the 1 ms steps), "F cycle duty256" at each change of the fan's duty
 * (likewise), "S cycle heater temp_c duty256" every sample; at the
 * end "P port value" for the PORT registers A..L, "H heater duty256" (the registers' duty), "T tccr1b timsk1"
 * and "I max_cycles count": the longest call of heaters_poll (one stage, from its first instruction to its
 * return) while Timer1 runs (the player plays), and how many there were.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <sim_avr.h>

#include "simavr_plant.h"

#define MAX_HEATERS 4
#define MAX_FAULTS 8
#define STEPS_PER_S 1000 /* the plants' integration step: 1 ms */
#define ADCL_ADDR 0x78
#define ADCH_ADDR 0x79
#define ADCSRB_ADDR 0x7B
#define ADMUX_ADDR 0x7C
#define MUX5_MASK 0x08 /* ADCSRB */
#define ADLAR_MASK 0x20 /* ADMUX */
#define SPL_ADDR 0x5D
#define SPH_ADDR 0x5E
#define TCCR1B_ADDR 0x81
#define TIMSK1_ADDR 0x6F

enum fault_kind { FAULT_OPEN, FAULT_SHORT, FAULT_DEAD, FAULT_LOOSE, FAULT_KINDS };
static const char *const FAULT_NAMES[FAULT_KINDS] = {"open", "short", "dead", "loose"};

typedef struct {
    int adc;                           /* ADC channel */
    uint16_t ocr, tccra, port;         /* data-space addresses */
    uint8_t com_mask, port_mask;
    double capacity, loss, watts, ambient;
    double temp;                       /* degC */
    double first_c, step_c;            /* the millivolt table: mv[i] at first_c + i x step_c */
    double *mv;
    int n_mv;
    int faulty[FAULT_KINDS];           /* active faults */
    int duty;                          /* duty256 at the last step */
} plant_t;

typedef struct {
    int heater, kind;
    avr_cycle_count_t at;
} fault_t;

static plant_t plants[MAX_HEATERS];
static plant_t fan; /* its PWM registers only; fan.tccra 0: none */
static int n_plants;
static fault_t faults[MAX_FAULTS];
static int n_faults;
static FILE *trace;
static double avcc = 5000.0;
static avr_cycle_count_t sample_cycles = 1600000, step_cycles, next_step, next_sample;
static uint8_t adch; /* the high byte of the last conversion read through ADCL */
static avr_flashaddr_t stage_pc; /* heaters_poll; 0: not measured */
static int in_stage;
static uint16_t stage_sp; /* the stack pointer in the stage's first instruction: above it, it has returned */
static avr_cycle_count_t stage_since, stage_max, stages;

static int duty256(avr_t *avr, const plant_t *p)
{
    if (avr->data[p->tccra] & p->com_mask)
        return avr->data[p->ocr] + 1; /* 8-bit fast PWM, TOP 0xFF: OCR 255 is always on */
    return (avr->data[p->port] & p->port_mask) ? 256 : 0;
}

static double sensor_mv(const plant_t *p)
{
    if (p->faulty[FAULT_OPEN])
        return avcc;
    if (p->faulty[FAULT_SHORT])
        return 0.0;
    double t = p->faulty[FAULT_LOOSE] ? p->ambient : p->temp;
    double x = (t - p->first_c) / p->step_c;
    if (x <= 0)
        return p->mv[0];
    if (x >= p->n_mv - 1)
        return p->mv[p->n_mv - 1];
    int i = (int)x;
    return p->mv[i] + (x - i) * (p->mv[i + 1] - p->mv[i]);
}

/* ADCL: the selected channel's reading now (replaces simavr's handler, see above). */
static uint8_t adcl_read(avr_t *avr, avr_io_addr_t addr, void *param)
{
    (void)addr;
    (void)param;
    int channel = (avr->data[ADMUX_ADDR] & 0x07) | ((avr->data[ADCSRB_ADDR] & MUX5_MASK) ? 8 : 0);
    int reading = 0;
    for (int k = 0; k < n_plants; k++) {
        if (plants[k].adc != channel)
            continue;
        reading = (int)floor(1024.0 * sensor_mv(&plants[k]) / avcc);
        reading = reading > 1023 ? 1023 : reading < 0 ? 0 : reading;
        fprintf(trace, "A %llu %d %d\n", (unsigned long long)avr->cycle, k, reading);
    }
    uint16_t value = (avr->data[ADMUX_ADDR] & ADLAR_MASK) ? (uint16_t)(reading << 6) : (uint16_t)reading;
    adch = (uint8_t)(value >> 8);
    avr->data[ADCL_ADDR] = (uint8_t)value;
    avr->data[ADCH_ADDR] = adch;
    return (uint8_t)value;
}

static uint8_t adch_read(avr_t *avr, avr_io_addr_t addr, void *param)
{
    (void)avr;
    (void)addr;
    (void)param;
    return adch;
}

static int read_heater(FILE *f, plant_t *p)
{
    unsigned ocr, tccra, com, port, bit;
    double start;
    if (fscanf(f, "%d %x %x %x %x %u %lf %lf %lf %lf %lf %lf %lf %d", &p->adc, &ocr, &tccra, &com, &port, &bit,
               &p->capacity, &p->loss, &p->watts, &p->ambient, &start, &p->first_c, &p->step_c, &p->n_mv) != 14
        || p->n_mv < 2 || p->step_c <= 0 || bit > 7)
        return -1;
    p->ocr = (uint16_t)ocr;
    p->tccra = (uint16_t)tccra;
    p->com_mask = (uint8_t)com;
    p->port = (uint16_t)port;
    p->port_mask = (uint8_t)(1u << bit);
    p->temp = start;
    p->mv = malloc(sizeof(double) * (size_t)p->n_mv);
    for (int i = 0; i < p->n_mv; i++)
        if (!p->mv || fscanf(f, "%lf", &p->mv[i]) != 1)
            return -1;
    return 0;
}

int plant_setup(avr_t *avr, const char *path)
{
    FILE *f = fopen(path, "r");
    char word[16], name[4096];
    if (!f) {
        perror(path);
        return -1;
    }
    while (fscanf(f, "%15s", word) == 1) {
        int ok;
        if (!strcmp(word, "log"))
            ok = fscanf(f, " %4095[^\n]", name) == 1 && (trace = fopen(name, "w")) != NULL;
        else if (!strcmp(word, "avcc"))
            ok = fscanf(f, "%lf", &avcc) == 1;
        else if (!strcmp(word, "sample"))
            ok = fscanf(f, "%llu", (unsigned long long *)&sample_cycles) == 1 && sample_cycles > 0;
        else if (!strcmp(word, "heater"))
            ok = n_plants < MAX_HEATERS && read_heater(f, &plants[n_plants++]) == 0;
        else if (!strcmp(word, "fault")) {
            fault_t *x = &faults[n_faults];
            char kind[16];
            ok = n_faults < MAX_FAULTS && fscanf(f, "%d %15s %llu", &x->heater, kind, (unsigned long long *)&x->at) == 3;
            for (x->kind = 0; ok && x->kind < FAULT_KINDS && strcmp(kind, FAULT_NAMES[x->kind]); x->kind++)
                ;
            ok = ok && x->kind < FAULT_KINDS && x->heater >= 0 && x->heater < n_plants;
            n_faults += ok;
        } else if (!strcmp(word, "fan")) {
            unsigned ocr, tccra, com, port, bit;
            ok = fscanf(f, "%x %x %x %x %u", &ocr, &tccra, &com, &port, &bit) == 5 && bit <= 7;
            fan.ocr = (uint16_t)ocr;
            fan.tccra = (uint16_t)tccra;
            fan.com_mask = (uint8_t)com;
            fan.port = (uint16_t)port;
            fan.port_mask = (uint8_t)(1u << bit);
        } else if (!strcmp(word, "stage")) {
            unsigned long pc;
            ok = fscanf(f, "%lx", &pc) == 1;
            stage_pc = (avr_flashaddr_t)pc;
        } else
            ok = 0;
        if (!ok) {
            fprintf(stderr, "%s: bad or misplaced `%s'\n", path, word);
            fclose(f);
            return -1;
        }
    }
    fclose(f);
    if (!trace) {
        fprintf(stderr, "%s: no log\n", path);
        return -1;
    }
    avr->io[AVR_DATA_TO_IO(ADCL_ADDR)].r.c = adcl_read;
    avr->io[AVR_DATA_TO_IO(ADCL_ADDR)].r.param = NULL;
    avr->io[AVR_DATA_TO_IO(ADCH_ADDR)].r.c = adch_read;
    avr->io[AVR_DATA_TO_IO(ADCH_ADDR)].r.param = NULL;
    step_cycles = avr->frequency / STEPS_PER_S;
    next_step = step_cycles;
    next_sample = 0;
    return 0;
}

static void step(avr_t *avr, double seconds)
{
    for (int k = 0; k < n_plants; k++) {
        plant_t *p = &plants[k];
        int duty = duty256(avr, p);
        if (duty != p->duty)
            fprintf(trace, "D %llu %d %d\n", (unsigned long long)avr->cycle, k, duty);
        p->duty = duty;
        double power = p->faulty[FAULT_DEAD] ? 0.0 : p->watts * duty / 256.0;
        double steady = p->ambient + power / p->loss;
        p->temp = steady + (p->temp - steady) * exp(-seconds * p->loss / p->capacity);
    }
    if (fan.tccra) {
        int duty = duty256(avr, &fan);
        if (duty != fan.duty)
            fprintf(trace, "F %llu %d\n", (unsigned long long)avr->cycle, duty);
        fan.duty = duty;
    }
}

void plant_follow(avr_t *avr)
{
    if (!trace)
        return;
    if (stage_pc) {
        uint16_t sp = (uint16_t)(avr->data[SPL_ADDR] | avr->data[SPH_ADDR] << 8);
        if (!in_stage && avr->pc == stage_pc && (avr->data[TCCR1B_ADDR] & 7)) { /* Timer1 runs: the player plays */
            in_stage = 1;
            stage_sp = sp;
            stage_since = avr->cycle;
        } else if (in_stage && sp > stage_sp) {
            in_stage = 0;
            stages++;
            if (avr->cycle - stage_since > stage_max)
                stage_max = avr->cycle - stage_since;
        }
    }
    if (avr->cycle < next_step && avr->cycle < next_sample)
        return;
    for (int i = 0; i < n_faults; i++)
        if (avr->cycle >= faults[i].at)
            plants[faults[i].heater].faulty[faults[i].kind] = 1;
    while (avr->cycle >= next_step) {
        step(avr, 1.0 / STEPS_PER_S);
        next_step += step_cycles;
    }
    if (avr->cycle >= next_sample) {
        for (int k = 0; k < n_plants; k++)
            fprintf(trace, "S %llu %d %.4f %d\n", (unsigned long long)avr->cycle, k, plants[k].temp, plants[k].duty);
        next_sample += sample_cycles;
    }
}

void plant_finish(avr_t *avr)
{
    static const uint16_t PORTS[] = {0x22, 0x25, 0x28, 0x2B, 0x2E, 0x31, 0x34, 0x102, 0x105, 0x108, 0x10B};
    static const char NAMES[] = "ABCDEFGHJKL";
    if (!trace)
        return;
    for (int i = 0; i < (int)(sizeof PORTS / sizeof PORTS[0]); i++)
        fprintf(trace, "P %c %u\n", NAMES[i], avr->data[PORTS[i]]);
    for (int k = 0; k < n_plants; k++)
        fprintf(trace, "H %d %d\n", k, duty256(avr, &plants[k]));
    fprintf(trace, "T %u %u\n", avr->data[TCCR1B_ADDR], avr->data[TIMSK1_ADDR]);
    fprintf(trace, "I %llu %llu\n", (unsigned long long)stage_max, (unsigned long long)stages);
    fclose(trace);
    trace = NULL;
}
