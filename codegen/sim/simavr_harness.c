/* printer-codegen simavr harness: run a firmware .hex, log pin level changes with exact cycle times, and
 * drive endstop switches from the simulated motor positions; in link mode, carry a host's bytes to USART0 and the
 * firmware's back (the host, in Python, drives it through stdin and stdout: simavr_link.c).
 *
 * usage: harness MCU F_CPU FIRMWARE.hex EDGES.bin CYCLE_BUDGET [OPTION...] PIN...     (PIN like F0, L3, B5)
 *   OPTION: a SWITCH, or key=PIN,PRESS,RELEASE and dump=ADDR,LEN (jog keys pressed at given cycles, RAM reported
 *   at the end: simavr_keys.c), or link=BYTE_CYCLES, check=ADDR, fill=ADDR (link mode: simavr_link.c; the budget is
 *   then the boot's, until the firmware turns its receiver on), or plant=FILE (thermal plants behind the ADC and
 *   the heaters' PWM: simavr_plant.c), or duty=ADDR (a 16-bit PWM compare register at data address ADDR, its
 *   high byte at ADDR + 1: each write of its low byte, which completes the 16-bit write, is logged), or top=ADDR
 *   (the same for the PWM's TOP register: its period), or held=CYCLES (the run ends CYCLES after the player started its timer
 *   if the firmware has not halted by then: an image that holds its heaters after the table never halts; counted
 *   from the latest start, and not while the player holds: its timer stopped before the end of the table)
 *   SWITCH: switch=PIN,CLOSED,AT,STEP,DIR,INVERT,COEF[,STEP,DIR,INVERT,COEF]   e.g. switch=E4,0,400,0,1,0,1
 *     an endstop on PIN that reads CLOSED (0/1) while closed and the other level while open, moved by one or two
 *     motors: each motor's STEP and DIR pins are watched pins number STEP and DIR (DIR level 1 = + unless INVERT
 *     is 1). The harness counts each motor's position in steps from 0 at every STEP rising edge, and the switch
 *     is closed while the sum of COEF x position over its motors is AT or more, open otherwise (AT = "never":
 *     always open). A corexy's x switch: both belts with COEF -1 (x = (a + b) / 2, homing to x_min). It changes
 *     at once, without bounce.
 *
 * EDGES.bin receives one 10-byte record per real level change of a watched pin:
 *   cycle u64 little-endian, pin index u8 (position in the PIN list), level u8;
 * and with duty=, two per write of the compare register: pin DUTY_LOW_PIN with the value's low byte, then
 * DUTY_HIGH_PIN with its high byte, both at the write's cycle (with top=, TOP_LOW_PIN and TOP_HIGH_PIN the
 * same for the TOP register); and one per start of the player's timer (each
 * write listed in starts= below): pin START_PIN, level 0, at the write's cycle (so the records alone tell a run's
 * clock, read while the harness writes them: codegen/sim/avr_edges.py).
 * The last line on stdout is "state=<done|crashed|budget> cycles=<n> timer_start=<cycle or -1>
 * status=<GPIOR0> status1=<GPIOR1> status2=<GPIOR2> starts=<cycle,...|->"; timer_start is the player's tick 0: the
 * first write that starts Timer1 while one of its interrupts is enabled (homing runs Timer1 with its interrupts
 * off); starts lists every such write (a player that holds at a temperature wait restarts its timer there).
 * Exit status: 0 done (the firmware slept with interrupts off), 1 crashed, 2 budget exhausted, 3 bad usage,
 * 4 held (with held=CYCLES: still running CYCLES after the player started its timer).
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <avr_extint.h>
#include <avr_ioport.h>
#include <avr_uart.h>
#include <sim_avr.h>
#include <sim_elf.h>
#include <sim_hex.h>
#include <sim_io.h>

#include "simavr_plant.h"

#define MAX_PINS 32
#define MAX_SWITCHES 8
#define MAX_SWITCH_MOTORS 2 /* a corexy's belts */
#define TCCR1B_ADDR 0x81 /* data-space address of Timer1's clock select register */
#define TIMER1_CLOCK_BITS 0x07 /* CS12..CS10: non-zero once the timer runs */
#define TIMSK1_ADDR 0x6F /* Timer1 interrupt mask: the player enables one before it starts the timer, homing none */
#define GPIOR0_ADDR 0x3E /* the firmware's status bytes (data-space addresses) */
#define GPIOR1_ADDR 0x4A
#define GPIOR2_ADDR 0x4B
#define PLAYER_DONE_MASK 0x01 /* GPIOR0: the flash player has played its end marker */
#define MAX_EXTINT 8 /* INT0..INT7 on the ATmega2560 */
#define MAX_STARTS 256 /* timer starts listed (a hold's resume each) */
#define START_PIN 0xFD /* EDGES.bin's pin index of a start of the player's timer */
#define DUTY_LOW_PIN 0xFE /* EDGES.bin's pin index of a duty write's low byte (duty=) */
#define DUTY_HIGH_PIN 0xFF
#define TOP_LOW_PIN 0xFB /* EDGES.bin's pin index of a TOP write's low byte (top=) */
#define TOP_HIGH_PIN 0xFC

typedef struct {
    int step, dir;      /* the motor's watched STEP and DIR pins */
    int invert;         /* DIR level 1 means - */
    int coef;           /* its weight in the switch's sum */
    long long position; /* steps, from 0 at the start */
} switch_motor_t;

typedef struct {
    avr_irq_t *irq;       /* the switch's input pin */
    uint8_t closed_level; /* pin level while closed */
    int never;            /* never closes */
    long long at;         /* closed while the weighted sum of positions is this or more */
    switch_motor_t motors[MAX_SWITCH_MOTORS];
    int n_motors;
    uint8_t driven; /* the level the harness drives */
} endstop_t;

static avr_t *avr;
static FILE *edges;
static uint8_t last_level[MAX_PINS]; /* pins start low after reset */
static long long timer_start = -1;
static unsigned long long timer_starts; /* how many times the player's timer has started */
static long long starts[MAX_STARTS]; /* every start of the player's timer */
static int n_starts;
static endstop_t endstops[MAX_SWITCHES];
static int n_endstops;
static int reassert; /* a PORT write (the pull-up) overrode a driven switch level */
static int moved;    /* a motor stepped: the switches follow once the instruction is over */
static int every_start; /* link mode: timer_start is the latest start of the player's timer (each session's) */
static unsigned long long held_after; /* held=CYCLES: the run ends this long after timer_start; 0: never */

static void drive(endstop_t *s)
{
    long long sum = 0;
    for (int i = 0; i < s->n_motors; i++)
        sum += s->motors[i].coef * s->motors[i].position;
    int closed = !s->never && sum >= s->at;
    uint8_t level = closed ? s->closed_level : !s->closed_level;
    if (level == s->driven)
        return;
    s->driven = level;
    avr_raise_irq(s->irq, level);
}

/* simavr raises an input's pin IRQ with the PORT bit on PORT writes (the pull-up) and sets PIN from it; the
 * external switch wins on a real board, so the main loop raises the driven level again. */
static void switch_notify(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    if ((value ? 1 : 0) != ((endstop_t *)param)->driven)
        reassert = 1;
}

static void step_edge(uint8_t index)
{
    for (int i = 0; i < n_endstops; i++) {
        endstop_t *s = &endstops[i];
        for (int j = 0; j < s->n_motors; j++) {
            switch_motor_t *m = &s->motors[j];
            if (m->step != index)
                continue;
            m->position += (last_level[m->dir] ^ m->invert) ? 1 : -1;
            moved = 1;
        }
    }
}

/* One 10-byte record of EDGES.bin at the current cycle. */
static void write_record(uint8_t pin, uint8_t level)
{
    uint8_t record[10];
    for (int i = 0; i < 8; i++)
        record[i] = (uint8_t)(avr->cycle >> (8 * i));
    record[8] = pin;
    record[9] = level;
    fwrite(record, sizeof record, 1, edges);
}

/* Every PORT write re-raises all 8 pin IRQs: keep the last level and log real changes only. */
static void pin_notify(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    uint8_t index = (uint8_t)(uintptr_t)param;
    uint8_t level = value ? 1 : 0;
    if (level == last_level[index])
        return;
    last_level[index] = level;
    write_record(index, level);
    if (level)
        step_edge(index);
}

/* Shares the compare register's low byte with the timer module (simavr dispatches to both): the 16-bit value
 * written (the high byte was stored before). */
static void duty_written(struct avr_t *core, avr_io_addr_t addr, uint8_t value, void *param)
{
    (void)core;
    (void)param;
    write_record(DUTY_LOW_PIN, value);
    write_record(DUTY_HIGH_PIN, avr->data[addr + 1]);
}

/* The same for the PWM's TOP register (top=). */
static void top_written(struct avr_t *core, avr_io_addr_t addr, uint8_t value, void *param)
{
    (void)core;
    (void)param;
    write_record(TOP_LOW_PIN, value);
    write_record(TOP_HIGH_PIN, avr->data[addr + 1]);
}

/* Shares TCCR1B with the timer module (simavr dispatches to both) to note the player's tick 0. */
static void tccr1b_written(struct avr_t *core, avr_io_addr_t addr, uint8_t value, void *param)
{
    (void)core;
    (void)addr;
    (void)param;
    if (!(value & TIMER1_CLOCK_BITS) || !avr->data[TIMSK1_ADDR])
        return;
    if (timer_start < 0 || every_start)
        timer_start = (long long)avr->cycle;
    timer_starts++;
    write_record(START_PIN, 0);
    if (n_starts < MAX_STARTS)
        starts[n_starts++] = (long long)avr->cycle;
}

/* held=: the run has gone on `held_after` cycles since the latest start, and the player does not hold (its timer
 * stopped before the end marker). */
static int held_long_enough(void)
{
    if (!held_after || n_starts == 0 || avr->cycle < (unsigned long long)starts[n_starts - 1] + held_after)
        return 0;
    int holding = !(avr->data[TCCR1B_ADDR] & TIMER1_CLOCK_BITS) && !(avr->data[GPIOR0_ADDR] & PLAYER_DONE_MASK);
    return !holding;
}

/* The default sleep callback usleeps to keep real time; simulated time is all we need. */
static void no_sleep(struct avr_t *core, avr_cycle_count_t how_long)
{
    (void)core;
    (void)how_long;
}

/* Merge every flash chunk of the .hex (a table above 64 KB spans several) into one image. */
static int load_hex(const char *path, elf_firmware_t *fw)
{
    ihex_chunk_p chunks = NULL;
    int count = read_ihex_chunks(path, &chunks);
    if (count <= 0)
        return -1;
    uint32_t end = 0;
    for (int i = 0; i < count; i++)
        if (chunks[i].baseaddr + chunks[i].size > end)
            end = chunks[i].baseaddr + chunks[i].size;
    fw->flash = calloc(end ? end : 1, 1);
    if (!fw->flash)
        return -1;
    for (int i = 0; i < count; i++)
        memcpy(fw->flash + chunks[i].baseaddr, chunks[i].data, chunks[i].size);
    fw->flashsize = end;
    fw->flashbase = 0;
    free_ihex_chunks(chunks);
    free(chunks);
    return 0;
}

static avr_irq_t *port_pin(const char *text)
{
    char port = text[0];
    int bit = text[1] - '0';
    if (port < 'A' || port > 'L' || bit < 0 || bit > 7 || text[2]) {
        fprintf(stderr, "bad pin %s (expected e.g. F0)\n", text);
        return NULL;
    }
    avr_irq_t *irq = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(port), bit);
    if (!irq)
        fprintf(stderr, "no port %c\n", port);
    return irq;
}

/* switch=PIN,CLOSED,AT,STEP,DIR,INVERT,COEF[,STEP,DIR,INVERT,COEF] */
static int parse_switch(const char *spec, int n_pins)
{
    char pin[4], at[32];
    endstop_t *s = &endstops[n_endstops];
    int closed, used = 0;
    memset(s, 0, sizeof *s);
    if (n_endstops == MAX_SWITCHES
        || sscanf(spec, "switch=%3[^,],%d,%31[^,]%n", pin, &closed, at, &used) != 3 || (closed != 0 && closed != 1)) {
        fprintf(stderr, "bad switch %s\n", spec);
        return -1;
    }
    for (const char *rest = spec + used; *rest; s->n_motors++) {
        switch_motor_t *m = &s->motors[s->n_motors];
        int more = 0;
        if (s->n_motors == MAX_SWITCH_MOTORS
            || sscanf(rest, ",%d,%d,%d,%d%n", &m->step, &m->dir, &m->invert, &m->coef, &more) != 4
            || m->step < 0 || m->step >= n_pins || m->dir < 0 || m->dir >= n_pins) {
            fprintf(stderr, "bad switch motor in %s\n", spec);
            return -1;
        }
        rest += more;
    }
    if (s->n_motors == 0) {
        fprintf(stderr, "switch without motors: %s\n", spec);
        return -1;
    }
    if (!(s->irq = port_pin(pin)))
        return -1;
    s->closed_level = (uint8_t)closed;
    s->never = strcmp(at, "never") == 0;
    s->at = s->never ? 0 : strtoll(at, NULL, 10);
    s->driven = 2; /* none yet */
    avr_irq_register_notify(s->irq, switch_notify, s);
    n_endstops++;
    return 0;
}

/* After each instruction: the switches follow the motors, a driven level wins over a PORT write. */
static void follow_switches(void)
{
    if (moved) { /* after the whole port write: belts that step together move a corexy's switch once */
        moved = 0;
        for (int i = 0; i < n_endstops; i++)
            drive(&endstops[i]);
    }
    if (reassert) {
        reassert = 0;
        for (int i = 0; i < n_endstops; i++)
            if ((endstops[i].irq->value ? 1 : 0) != endstops[i].driven)
                avr_raise_irq(endstops[i].irq, endstops[i].driven);
    }
}

#include "simavr_keys.c"
#include "simavr_link.c"

int main(int argc, char **argv)
{
    int n_options = 0;
    while (6 + n_options < argc && strchr(argv[6 + n_options], '='))
        n_options++;
    const int first_pin = 6 + n_options, n_pins = argc - first_pin;
    if (argc < 7 || n_pins < 1 || n_pins > MAX_PINS) {
        fprintf(stderr, "usage: %s MCU F_CPU FIRMWARE.hex EDGES.bin CYCLE_BUDGET [OPTION...] PIN...\n", argv[0]);
        return 3;
    }
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    snprintf(fw.mmcu, sizeof fw.mmcu, "%s", argv[1]);
    fw.frequency = (uint32_t)strtoul(argv[2], NULL, 10);
    unsigned long long budget = strtoull(argv[5], NULL, 10);
    if (load_hex(argv[3], &fw) != 0) {
        fprintf(stderr, "cannot load %s\n", argv[3]);
        return 3;
    }
    avr = avr_make_mcu_by_name(fw.mmcu);
    if (!avr) {
        fprintf(stderr, "unknown MCU %s\n", fw.mmcu);
        return 3;
    }
    avr_init(avr);
    avr_load_firmware(avr, &fw);
    avr->sleep = no_sleep;
    avr->log = 0;
    /* simavr polls a low INTn pin every cycle (strict level triggering) whatever EIMSK says: an endstop on INT2..5
     * that stays closed after homing made a sleeping firmware 20x slower to simulate. No firmware here enables
     * INTn, so the edge-only model gives the same run. */
    for (uint8_t n = 0; n < MAX_EXTINT; n++)
        avr_extint_set_strict_lvl_trig(avr, n, 0);
    edges = fopen(argv[4], "wb");
    if (!edges) {
        perror(argv[4]);
        return 3;
    }
    for (int i = first_pin; i < argc; i++) {
        avr_irq_t *irq = port_pin(argv[i]);
        if (!irq)
            return 3;
        avr_irq_register_notify(irq, pin_notify, (void *)(uintptr_t)(i - first_pin));
    }
    for (int i = 6; i < first_pin; i++)
        if (strncmp(argv[i], "held=", 5) == 0)
            held_after = strtoull(argv[i] + 5, NULL, 10);
        else if (strncmp(argv[i], "duty=", 5) == 0)
            avr_register_io_write(avr, (avr_io_addr_t)strtoul(argv[i] + 5, NULL, 0), duty_written, NULL);
        else if (strncmp(argv[i], "top=", 4) == 0)
            avr_register_io_write(avr, (avr_io_addr_t)strtoul(argv[i] + 4, NULL, 0), top_written, NULL);
        else if (strncmp(argv[i], "switch=", 7) == 0   ? parse_switch(argv[i], n_pins)
                 : strncmp(argv[i], "plant=", 6) == 0 ? plant_setup(avr, argv[i] + 6)
                 : strncmp(argv[i], "key=", 4) == 0 || strncmp(argv[i], "dump=", 5) == 0 ? key_option(argv[i])
                                                       : link_option(argv[i]))
            return 3;
    for (int i = 0; i < n_endstops; i++)
        drive(&endstops[i]);
    avr_register_io_write(avr, TCCR1B_ADDR, tccr1b_written, NULL);
    if (link.byte_cycles) {
        every_start = 1;
        return link_serve(budget);
    }

    int state = cpu_Running, held = 0;
    while (state != cpu_Done && state != cpu_Crashed && avr->cycle < budget && !held) {
        state = avr_run(avr);
        follow_switches();
        keys_follow();
        plant_follow(avr);
        held = held_long_enough();
    }

    plant_finish(avr);
    fclose(edges);
    const char *name = state == cpu_Done      ? "done"
                       : state == cpu_Crashed ? "crashed"
                       : held                 ? "held"
                                              : "budget";
    printf("state=%s cycles=%llu timer_start=%lld status=%u status1=%u status2=%u starts=", name,
           (unsigned long long)avr->cycle, timer_start, avr->data[GPIOR0_ADDR], avr->data[GPIOR1_ADDR],
           avr->data[GPIOR2_ADDR]);
    for (int i = 0; i < n_starts; i++)
        printf("%s%lld", i ? "," : "", starts[i]);
    printf("%s", n_starts ? "" : "-");
    keys_report();
    printf("\n");
    return state == cpu_Done ? 0 : state == cpu_Crashed ? 1 : held ? 4 : 2;
}
