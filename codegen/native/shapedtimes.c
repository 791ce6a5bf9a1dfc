/* The time of every master event of a linear machine's shaped blocks (codegen/motion/shaped_crossings.py has the
 * numpy version, which this must match to the bit: tests/motion/test_shaped_native.py): the pieces' keys and the
 * events' targets both rise, so one walk finds each event's piece, whose quadratic is then solved. Each
 * expression is written in the numpy version's order, so the floating-point results are the same.
 *
 * Built at first use into the user's cache (codegen/native/__init__.py) and called through ctypes.
 */
#include <math.h>
#include <stdint.h>

/* moving (N): the blocks with master events, count (N) their events; per block (B): offset, base (the master's
 * rounded start past its exact one, signed), first and last piece; per piece (K): key (sorted), progress, speed
 * and accel along the master (steps, steps/s, steps/s^2), breaks (K + 1). Writes time and phase per event. */
void shaped_crossings(int64_t blocks, const int64_t *moving, const int64_t *count, const double *offset,
                      const double *base, const int64_t *first, const int64_t *last, int64_t pieces,
                      const double *key, const double *progress, const double *speed, const double *accel,
                      const double *breaks, double *time, int8_t *phase)
{
    int64_t below = 0; /* keys <= the event's target: numpy's searchsorted "right" */
    int64_t e = 0;
    for (int64_t i = 0; i < blocks; i++) {
        int64_t b = moving[i];
        for (int64_t k = 1; k <= count[i]; k++, e++) {
            double target = base[b] + (double)k - 0.5;
            double wanted = offset[b] + target;
            while (below < pieces && key[below] <= wanted)
                below++;
            int64_t piece = below - 1;
            piece = piece < first[b] ? first[b] : (piece > last[b] ? last[b] : piece);
            double s = speed[piece], acc = accel[piece];
            double ahead = target - progress[piece];
            ahead = ahead > 0.0 ? ahead : 0.0;
            double square = s * s + 2.0 * acc * ahead;
            double root = sqrt(square > 0.0 ? square : 0.0);
            double tau = s + root > 0.0 ? 2.0 * ahead / (s + root) : 0.0;
            double h = breaks[piece + 1] - breaks[piece];
            tau = tau < 0.0 ? 0.0 : (tau > h ? h : tau);
            time[e] = breaks[piece] + tau;
            phase[e] = acc > 0.0 ? 0 : (acc < 0.0 ? 2 : 1);
        }
    }
}
