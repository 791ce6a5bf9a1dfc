/* Jog keys for the simavr harness (#included by simavr_harness.c): keys to ground pressed and released at given
 * cycles, and a block of the firmware's RAM reported at the end (its jog position counts).
 *
 *   key=PIN,PRESS,RELEASE   PIN (e.g. A1) reads low from cycle PRESS to cycle RELEASE, high otherwise (the
 *                           pull-up); a pin may have several presses
 *   dump=ADDR,LEN           the last line gets " dump=<hex>": LEN bytes of data space from ADDR (LEN <= 64)
 *
 * A PORT write re-raises every pin of the port with its PORT bit (simavr's pull-up model): the key's level wins
 * again after the instruction, as a real key to ground would hold the pin low. */

#define MAX_KEY_PRESSES 64
#define MAX_KEY_PINS 16
#define MAX_DUMP 64

typedef struct {
    avr_irq_t *irq;
    uint8_t driven; /* the level the harness drives: 0 pressed, 1 released */
} key_pin_t;

typedef struct {
    int pin; /* index into key_pins */
    unsigned long long press, release;
} key_press_t;

static key_pin_t key_pins[MAX_KEY_PINS];
static int n_key_pins;
static key_press_t key_presses[MAX_KEY_PRESSES];
static int n_key_presses;
static unsigned long long keys_next = ~0ULL; /* the next cycle at which a key changes */
static int keys_reassert;
static unsigned dump_addr, dump_len;

static void key_notify(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    if ((value ? 1 : 0) != ((key_pin_t *)param)->driven)
        keys_reassert = 1;
}

/* key=... or dump=...: 0, or -1 on a bad option. */
static int key_option(const char *spec)
{
    if (strncmp(spec, "dump=", 5) == 0)
        return sscanf(spec, "dump=%u,%u", &dump_addr, &dump_len) == 2 && dump_len <= MAX_DUMP ? 0 : -1;
    char pin[4];
    unsigned long long press, release;
    if (n_key_presses == MAX_KEY_PRESSES
        || sscanf(spec, "key=%3[^,],%llu,%llu", pin, &press, &release) != 3 || press >= release) {
        fprintf(stderr, "bad key %s\n", spec);
        return -1;
    }
    avr_irq_t *irq = port_pin(pin);
    if (!irq)
        return -1;
    int k = 0;
    while (k < n_key_pins && key_pins[k].irq != irq)
        k++;
    if (k == n_key_pins) {
        if (n_key_pins == MAX_KEY_PINS)
            return -1;
        key_pins[k].irq = irq;
        key_pins[k].driven = 2; /* none yet */
        avr_irq_register_notify(irq, key_notify, &key_pins[k]);
        n_key_pins++;
    }
    key_presses[n_key_presses++] = (key_press_t){k, press, release};
    keys_next = 0;
    return 0;
}

/* After each instruction: the keys' levels at this cycle, and again after a PORT write overrode them. */
static void keys_follow(void)
{
    if (avr->cycle >= keys_next) {
        keys_next = ~0ULL;
        for (int k = 0; k < n_key_pins; k++) {
            uint8_t level = 1;
            for (int i = 0; i < n_key_presses; i++) {
                const key_press_t *p = &key_presses[i];
                if (p->pin != k)
                    continue;
                if (avr->cycle >= p->press && avr->cycle < p->release)
                    level = 0;
                if (p->press > avr->cycle && p->press < keys_next)
                    keys_next = p->press;
                if (p->release > avr->cycle && p->release < keys_next)
                    keys_next = p->release;
            }
            if (level != key_pins[k].driven) {
                key_pins[k].driven = level;
                avr_raise_irq(key_pins[k].irq, level);
            }
        }
    }
    if (keys_reassert) {
        keys_reassert = 0;
        for (int k = 0; k < n_key_pins; k++)
            if ((key_pins[k].irq->value ? 1 : 0) != key_pins[k].driven)
                avr_raise_irq(key_pins[k].irq, key_pins[k].driven);
    }
}

/* " dump=<hex>" for the last line, when asked for. */
static void keys_report(void)
{
    if (!dump_len)
        return;
    printf(" dump=");
    for (unsigned i = 0; i < dump_len; i++)
        printf("%02x", avr->data[dump_addr + i]);
}
