/* Link mode of the simavr harness (#included by simavr_harness.c): a host in Python (codegen/sim/avr_link.py)
 * talks to the firmware's USART0 over stdin and stdout, in lockstep on simulated time.
 *
 * Options: link=BYTE_CYCLES (CPU cycles per byte on the line: 10 bit times, 8N1), check=ADDR (a code byte
 * address where the player is about to read a record: the ring's free space is read there; several), free=ADDR
 * (the data address of the ring's free space, u16).
 *
 * The host's bytes go onto the RX line back to back, each complete BYTE_CYCLES after the one before (or after it
 * was given, on an idle line); a complete byte goes into the USART's FIFO and RXC rises at once (simavr's own
 * pacing, 11 bit times from UBRR, is not used; UBRR's rate is the firmware's business). A byte arriving while the
 * one before is still unread (or with the receiver off) is counted in `lost`: a real USART would lose it (simavr
 * keeps it). The firmware's bytes reach the host BYTE_CYCLES after it writes UDR (its transmit pacing is set to
 * BYTE_CYCLES too).
 *
 * Stdin, little-endian: a command is wake u64 (a cycle; UINT64_MAX: none), budget u64 (a cycle), flags u8 (1:
 * reset the figures), n u32, then n bytes for the line. The harness runs until a frame from the firmware has
 * fully arrived, the wake cycle, the budget, a start of the player's timer (so that the
 * host sees every resume after a hold in timer_start), or the firmware stops; then it answers on
 * stdout: cycle u64, state u8 (0 running, 1 done, 2 crashed), why u8 (STOP_*), timer_start i64, lost u32,
 * max_free u32 (UINT32_MAX: no record read), sp_min u16, rx_bytes u32, then per interrupt (USART0 RX, UDRE):
 * longest u32, total u64 cycles from its dispatch to its RETI, count u32; then n u32 and n x (cycle u64, byte u8).
 * Before the first command it runs until the firmware turns its receiver on (the host opens the port after the
 * boot). With plant=FILE the thermal plants follow in link mode too (the tune firmware: codegen/sim/avr_tune.py),
 * and with key= the jog keys (simavr_keys.c; with dump=, its line " dump=<hex>" comes once stdin has closed).
 */

#define MAX_CHECKS 16
#define SP_ADDR 0x5D /* SPL, SPH */
#define UBRR0L_ADDR 0xC4
#define LINK_VECTORS 2
static const uint8_t link_vector[LINK_VECTORS] = {25, 26}; /* USART0_RX, USART0_UDRE on the ATmega2560 */
enum { STOP_FRAME, STOP_WAKE, STOP_BUDGET, STOP_END, STOP_BOOT, STOP_TIMER };

typedef struct {
    uint64_t cycle; /* when it has arrived at the host */
    uint8_t byte;
} out_byte_t;

static struct {
    avr_cycle_count_t byte_cycles; /* 0: not link mode */
    avr_uart_t *uart;
    avr_irq_t *input;
    uint8_t *line; /* bytes for the RX line: line[sent..queued) still to go */
    size_t sent, queued, line_cap;
    int line_busy;
    avr_cycle_count_t line_free; /* when the last byte completed */
    out_byte_t *out; /* bytes from the firmware: out[0..delivered) have arrived */
    size_t out_n, delivered, out_cap;
    int frame_left; /* bytes of the firmware's frame still to arrive; 0: between frames */
    int frame_done, deliver_pending;
    uint64_t wake;
    uint16_t checks[MAX_CHECKS], free_addr;
    int n_checks;
    uint32_t lost, max_free, rx_bytes;
    uint16_t sp_min;
    avr_cycle_count_t isr_start[LINK_VECTORS];
    uint32_t isr_max[LINK_VECTORS];
    uint64_t isr_total[LINK_VECTORS];
    uint32_t isr_count[LINK_VECTORS];
} link;

static int link_option(const char *text)
{
    unsigned long value = strtoul(strchr(text, '=') + 1, NULL, 0);
    if (strncmp(text, "link=", 5) == 0)
        link.byte_cycles = value;
    else if (strncmp(text, "free=", 5) == 0)
        link.free_addr = (uint16_t)value;
    else if (strncmp(text, "check=", 6) == 0 && link.n_checks < MAX_CHECKS)
        link.checks[link.n_checks++] = (uint16_t)value;
    else {
        fprintf(stderr, "bad option %s\n", text);
        return -1;
    }
    return 0;
}

static void *grow(void *buffer, size_t *cap, size_t need, size_t size)
{
    if (need <= *cap)
        return buffer;
    *cap = need * 2;
    buffer = realloc(buffer, *cap * size);
    if (!buffer) {
        perror("realloc");
        exit(3);
    }
    return buffer;
}

static void reset_figures(void)
{
    link.lost = link.rx_bytes = 0;
    link.max_free = UINT32_MAX;
    link.sp_min = UINT16_MAX;
    memset(link.isr_max, 0, sizeof link.isr_max);
    memset(link.isr_total, 0, sizeof link.isr_total);
    memset(link.isr_count, 0, sizeof link.isr_count);
}

/* The next byte of the line is complete. */
static avr_cycle_count_t line_byte(struct avr_t *core, avr_cycle_count_t when, void *param)
{
    (void)param;
    avr_uart_t *u = link.uart;
    int receiving = avr_regbit_get(core, u->rxen);
    link.rx_bytes++;
    if (!receiving || u->input.read != u->input.write) /* the one before is unread */
        link.lost++;
    avr_raise_irq(link.input, link.line[link.sent++]);
    if (receiving) {
        avr_raise_interrupt(core, &u->rxc);
        u->rxc_raise_time = when;
        u->rx_cnt = 0;
    }
    if (link.sent < link.queued)
        return when + link.byte_cycles;
    link.sent = link.queued = 0;
    link.line_busy = 0;
    link.line_free = when;
    return 0;
}

/* Firmware bytes whose last bit has gone: they have arrived; a frame's last byte ends the run. */
static avr_cycle_count_t deliver(struct avr_t *core, avr_cycle_count_t when, void *param)
{
    (void)core;
    (void)param;
    while (link.delivered < link.out_n && link.out[link.delivered].cycle <= when) {
        uint8_t byte = link.out[link.delivered++].byte;
        if (link.frame_left == 0) /* between frames: SYNC, else a stray byte */
            link.frame_left = byte == 0x7E ? -1 : 0;
        else if (link.frame_left == -1) /* LEN: SEQ, TYPE, the payload and the CRC follow */
            link.frame_left = byte + 4;
        else
            link.frame_left--;
        if (link.frame_left == 0)
            link.frame_done = 1;
    }
    if (link.delivered < link.out_n)
        return link.out[link.delivered].cycle;
    link.deliver_pending = 0;
    return 0;
}

static void uart_output(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    link.out = grow(link.out, &link.out_cap, link.out_n + 1, sizeof *link.out);
    link.out[link.out_n++] = (out_byte_t){avr->cycle + link.byte_cycles, (uint8_t)value};
    if (!link.deliver_pending) {
        link.deliver_pending = 1;
        avr_cycle_timer_register(avr, link.byte_cycles, deliver, NULL);
    }
}

/* The firmware set its rate: transmit at the line's. */
static void ubrr_written(struct avr_t *core, avr_io_addr_t addr, uint8_t value, void *param)
{
    (void)core;
    (void)addr;
    (void)value;
    (void)param;
    link.uart->cycles_per_byte = link.byte_cycles;
}

static void isr_running(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    int k = (int)(intptr_t)param;
    if (value) {
        link.isr_start[k] = avr->cycle;
        return;
    }
    uint64_t spent = avr->cycle - link.isr_start[k];
    link.isr_total[k] += spent;
    link.isr_count[k]++;
    if (spent > link.isr_max[k])
        link.isr_max[k] = (uint32_t)spent;
}

static avr_cycle_count_t wake_up(struct avr_t *core, avr_cycle_count_t when, void *param)
{
    (void)core;
    (void)when;
    (void)param;
    return 0; /* only ends a sleep there */
}

static int link_run(uint64_t budget, int *state)
{
    const unsigned long long starts_before = timer_starts;
    for (;;) {
        if (timer_starts != starts_before)
            return STOP_TIMER; /* the player's timer has started (a resume after a hold): the host sees each */
        if (*state == cpu_Done || *state == cpu_Crashed)
            return STOP_END;
        if (link.frame_done) {
            link.frame_done = 0;
            return STOP_FRAME;
        }
        if (avr->cycle >= link.wake)
            return STOP_WAKE;
        if (avr->cycle >= budget)
            return STOP_BUDGET;
        *state = avr_run(avr);
        follow_switches();
        keys_follow(); /* with key=: the jog keys (simavr_keys.c); else nothing */
        plant_follow(avr); /* with plant=FILE: the heaters' plants (simavr_plant.c); else nothing */
        uint16_t sp = avr->data[SP_ADDR] | avr->data[SP_ADDR + 1] << 8;
        if (sp < link.sp_min)
            link.sp_min = sp;
        for (int i = 0; i < link.n_checks; i++)
            if (avr->pc == link.checks[i]) {
                uint32_t free = avr->data[link.free_addr] | avr->data[link.free_addr + 1] << 8;
                if (link.max_free == UINT32_MAX || free > link.max_free)
                    link.max_free = free;
            }
    }
}

static void put(const void *data, size_t size)
{
    if (fwrite(data, size, 1, stdout) != 1)
        exit(3);
}

static void link_answer(int state, int why)
{
    uint64_t cycle = avr->cycle;
    uint8_t code[2] = {state == cpu_Done ? 1 : state == cpu_Crashed ? 2 : 0, (uint8_t)why};
    int64_t start = timer_start;
    uint32_t n = (uint32_t)link.delivered;
    put(&cycle, 8);
    put(code, 2);
    put(&start, 8);
    put(&link.lost, 4);
    put(&link.max_free, 4);
    put(&link.sp_min, 2);
    put(&link.rx_bytes, 4);
    for (int k = 0; k < LINK_VECTORS; k++) {
        put(&link.isr_max[k], 4);
        put(&link.isr_total[k], 8);
        put(&link.isr_count[k], 4);
    }
    put(&n, 4);
    for (size_t i = 0; i < link.delivered; i++) {
        put(&link.out[i].cycle, 8);
        put(&link.out[i].byte, 1);
    }
    memmove(link.out, link.out + link.delivered, (link.out_n - link.delivered) * sizeof *link.out);
    link.out_n -= link.delivered;
    link.delivered = 0;
    fflush(edges);
    fflush(stdout);
}

/* Serve commands until stdin closes. */
static int link_serve(uint64_t boot_budget)
{
    for (avr_io_t *io = avr->io_port; io; io = io->next)
        if (io->irq_ioctl_get == AVR_IOCTL_UART_GETIRQ('0'))
            link.uart = (avr_uart_t *)io;
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags); /* no stdio echo, no sleeping while polled */
    link.input = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_output, NULL);
    avr_register_io_write(avr, UBRR0L_ADDR, ubrr_written, NULL);
    for (int k = 0; k < LINK_VECTORS; k++)
        avr_irq_register_notify(avr_get_interrupt_irq(avr, link_vector[k]) + AVR_INT_IRQ_RUNNING, isr_running,
                                (void *)(intptr_t)k);
    reset_figures();

    int state = cpu_Running;
    link.wake = UINT64_MAX;
    while (!avr_regbit_get(avr, link.uart->rxen) && state != cpu_Done && state != cpu_Crashed
           && avr->cycle < boot_budget) {
        state = avr_run(avr);
        follow_switches();
        keys_follow();
        plant_follow(avr);
    }
    link_answer(state, STOP_BOOT);
    for (;;) {
        uint64_t budget;
        uint8_t reset;
        uint32_t n;
        if (fread(&link.wake, 8, 1, stdin) != 1 || fread(&budget, 8, 1, stdin) != 1
            || fread(&reset, 1, 1, stdin) != 1 || fread(&n, 4, 1, stdin) != 1) {
            plant_finish(avr); /* the plants' end state (heater duties, PORTs, Timer1) in their trace */
            keys_report(); /* with dump=: the jog positions, one line */
            printf("\n");
            return 0;
        }
        link.line = grow(link.line, &link.line_cap, link.queued + n, 1);
        if (n && fread(link.line + link.queued, n, 1, stdin) != 1)
            return 3;
        if (reset)
            reset_figures();
        if (n && !link.line_busy) {
            avr_cycle_count_t start = link.line_free > avr->cycle ? link.line_free : avr->cycle;
            avr_cycle_timer_register(avr, start + link.byte_cycles - avr->cycle, line_byte, NULL);
            link.line_busy = 1;
        }
        link.queued += n;
        if (link.wake != UINT64_MAX && link.wake > avr->cycle)
            avr_cycle_timer_register(avr, link.wake - avr->cycle, wake_up, &link.wake);
        if (budget > avr->cycle)
            avr_cycle_timer_register(avr, budget - avr->cycle, wake_up, &link.line_free);
        link_answer(state, link_run(budget, &state));
    }
}
