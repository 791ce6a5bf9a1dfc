/* printer-codegen simavr harness: run a firmware .hex and log pin level changes with exact cycle times.
 *
 * usage: harness MCU F_CPU FIRMWARE.hex EDGES.bin CYCLE_BUDGET PIN...     (PIN like F0, L3, B5)
 *
 * EDGES.bin receives one 10-byte record per real level change of a watched pin:
 *   cycle u64 little-endian, pin index u8 (position in the PIN list), level u8.
 * The last line on stdout is "state=<done|crashed|budget> cycles=<n> timer_start=<cycle or -1>".
 * Exit status: 0 done (the firmware slept with interrupts off), 1 crashed, 2 budget exhausted, 3 bad usage.
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <avr_ioport.h>
#include <sim_avr.h>
#include <sim_elf.h>
#include <sim_hex.h>
#include <sim_io.h>

#define MAX_PINS 32
#define TCCR1B_ADDR 0x81 /* data-space address of Timer1's clock select register */
#define TIMER1_CLOCK_BITS 0x07 /* CS12..CS10: non-zero once the timer runs */

static avr_t *avr;
static FILE *edges;
static uint8_t last_level[MAX_PINS]; /* pins start low after reset */
static long long timer_start = -1;

/* Every PORT write re-raises all 8 pin IRQs: keep the last level and log real changes only. */
static void pin_notify(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    uint8_t index = (uint8_t)(uintptr_t)param;
    uint8_t level = value ? 1 : 0;
    if (level == last_level[index])
        return;
    last_level[index] = level;
    uint8_t record[10];
    for (int i = 0; i < 8; i++)
        record[i] = (uint8_t)(avr->cycle >> (8 * i));
    record[8] = index;
    record[9] = level;
    fwrite(record, sizeof record, 1, edges);
}

/* Shares TCCR1B with the timer module (simavr dispatches to both) to note tick 0. */
static void tccr1b_written(struct avr_t *core, avr_io_addr_t addr, uint8_t value, void *param)
{
    (void)core;
    (void)addr;
    (void)param;
    if (timer_start < 0 && (value & TIMER1_CLOCK_BITS))
        timer_start = (long long)avr->cycle;
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

int main(int argc, char **argv)
{
    if (argc < 7 || argc - 6 > MAX_PINS) {
        fprintf(stderr, "usage: %s MCU F_CPU FIRMWARE.hex EDGES.bin CYCLE_BUDGET PIN...\n", argv[0]);
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
    edges = fopen(argv[4], "wb");
    if (!edges) {
        perror(argv[4]);
        return 3;
    }
    for (int i = 6; i < argc; i++) {
        char port = argv[i][0];
        int bit = argv[i][1] - '0';
        if (port < 'A' || port > 'L' || bit < 0 || bit > 7 || argv[i][2]) {
            fprintf(stderr, "bad pin %s (expected e.g. F0)\n", argv[i]);
            return 3;
        }
        avr_irq_t *irq = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(port), bit);
        if (!irq) {
            fprintf(stderr, "no port %c on %s\n", port, fw.mmcu);
            return 3;
        }
        avr_irq_register_notify(irq, pin_notify, (void *)(uintptr_t)(i - 6));
    }
    avr_register_io_write(avr, TCCR1B_ADDR, tccr1b_written, NULL);

    int state = cpu_Running;
    while (state != cpu_Done && state != cpu_Crashed && avr->cycle < budget)
        state = avr_run(avr);

    fclose(edges);
    const char *name = state == cpu_Done ? "done" : state == cpu_Crashed ? "crashed" : "budget";
    printf("state=%s cycles=%llu timer_start=%lld\n", name, (unsigned long long)avr->cycle, timer_start);
    return state == cpu_Done ? 0 : state == cpu_Crashed ? 1 : 2;
}
