/* The twin's player in one pass (codegen/tables/twin.py has the numpy version, which this must match exactly:
 * tests/native/test_tables.py): every event's tick and the motor positions after it, every pulse in time order
 * (events in order, motors in table order within an event), and each motor's own pulses. Integer arithmetic
 * only; the semantics are codegen/tables/schedule.py's.
 *
 * Built at first use into the user's cache (codegen/native/__init__.py) and called through ctypes.
 */
#include <stddef.h>
#include <stdint.h>

/* blocks: steps (B x M, signed), modulus, init (B x M), events of each block; runs: count, interval, add (24.8
 * and 16.8 fixed point ticks); origin_fx: the player's clock (1/256 tick) before the first event; position
 * (M): the motors' steps before it. Writes event_tick, event_block, event_position (E x M); pulse_tick,
 * pulse_motor, pulse_dir, pulse_event (P, in time order); motor_tick and motor_dir (P, each motor's pulses
 * together, motor m's from motor_first[m] on). */
void play(int64_t blocks, int64_t motors, const int64_t *steps, const int64_t *modulus, const int64_t *init,
          const int64_t *block_events, int64_t runs, const int64_t *count, const int64_t *interval,
          const int64_t *add, int64_t origin_fx, const int64_t *position, int64_t *event_tick,
          int64_t *event_block, int64_t *event_position, int64_t *pulse_tick, int64_t *pulse_motor,
          int64_t *pulse_dir, int64_t *pulse_event, const int64_t *motor_first, int64_t *motor_tick,
          int64_t *motor_dir)
{
    int64_t here[8], acc[8], next_of_motor[8];
    for (int64_t m = 0; m < motors; m++) {
        here[m] = position[m];
        next_of_motor[m] = motor_first[m];
    }
    int64_t pos = origin_fx, run = 0, left = runs ? count[0] : 0, step = runs ? interval[0] : 0;
    int64_t event = 0, pulse = 0;
    for (int64_t b = 0; b < blocks; b++) {
        const int64_t *d = steps + b * motors;
        for (int64_t m = 0; m < motors; m++)
            acc[m] = init[b * motors + m];
        for (int64_t i = 0; i < block_events[b]; i++, event++) {
            if (left == 0) { /* the next run */
                run++;
                left = count[run];
                step = interval[run];
            }
            pos += step;
            step += add[run];
            left--;
            const int64_t tick = pos >> 8;
            event_tick[event] = tick;
            event_block[event] = b;
            for (int64_t m = 0; m < motors; m++) {
                const int64_t size = d[m] < 0 ? -d[m] : d[m];
                acc[m] -= size;
                if (acc[m] < 0) {
                    acc[m] += modulus[b];
                    const int64_t dir = d[m] < 0 ? -1 : 1;
                    here[m] += dir;
                    pulse_tick[pulse] = tick;
                    pulse_motor[pulse] = m;
                    pulse_dir[pulse] = dir;
                    pulse_event[pulse] = event;
                    pulse++;
                    motor_tick[next_of_motor[m]] = tick;
                    motor_dir[next_of_motor[m]] = dir;
                    next_of_motor[m]++;
                }
                event_position[event * motors + m] = here[m];
            }
        }
    }
}
