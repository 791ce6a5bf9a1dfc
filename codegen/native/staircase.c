/* How far the Bresenham staircase of each block strays from its segment's line (codegen/motion/staircase.py has the
 * numpy version, which this must match exactly: tests/native/test_frontend.py): the player's accumulators
 * step the motors event by event, the tool's position after each event is taken through the linear
 * kinematics' inverse, and its distance to the segment's line (not clamped to the segment) is measured.
 * Linear kinematics only (cartesian, corexy); the arithmetic is in the numpy version's order, without FMA.
 *
 * Built at first use into the user's cache (codegen/native/__init__.py) and called through ctypes.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>

#define MAX_MOTORS 8

/* blocks: steps (B x M, signed), modulus, init (B x M); first_step (B x M): each motor's rounded start (steps,
 * as a float); steps_per_mm (M); inverse (3 x M): each of x, y, z from the motors' mm, for the axes in driven
 * (3: 1 where the motors move the axis, else the axis stays at the segment's start); start, end (B x 4) mm.
 * Writes worst (B): the largest distance (mm) after any event of the block, 0 for a block without events. */
void staircase_error(int64_t blocks, int64_t motors, const int64_t *steps, const int64_t *modulus,
                     const int64_t *init, const double *first_step, const double *steps_per_mm,
                     const double *inverse, const int64_t *driven, const double *start, const double *end,
                     double *worst)
{
    int64_t acc[MAX_MOTORS], size[MAX_MOTORS], dir[MAX_MOTORS], done[MAX_MOTORS];
    for (int64_t b = 0; b < blocks; b++) {
        const int64_t *d = steps + b * motors;
        const double *s = start + b * 4, *e = end + b * 4, *r0 = first_step + b * motors;
        int64_t events = 0;
        for (int64_t m = 0; m < motors; m++) {
            size[m] = d[m] < 0 ? -d[m] : d[m];
            dir[m] = d[m] < 0 ? -1 : 1;
            acc[m] = init[b * motors + m];
            done[m] = 0;
            if (size[m] > events)
                events = size[m];
        }
        const double ab[3] = {e[0] - s[0], e[1] - s[1], e[2] - s[2]};
        const double denom = (ab[0] * ab[0] + ab[1] * ab[1]) + ab[2] * ab[2];
        double far = 0.0;
        for (int64_t i = 0; i < events; i++) {
            double motor_mm[MAX_MOTORS];
            for (int64_t m = 0; m < motors; m++) {
                acc[m] -= size[m];
                if (acc[m] < 0) {
                    acc[m] += modulus[b];
                    done[m] += dir[m];
                }
                motor_mm[m] = ((double)done[m] + r0[m]) / steps_per_mm[m];
            }
            double p[3];
            for (int a = 0; a < 3; a++) {
                if (!driven[a]) {
                    p[a] = s[a];
                    continue;
                }
                double sum = motor_mm[0] * inverse[a * motors];
                for (int64_t m = 1; m < motors; m++)
                    sum = sum + motor_mm[m] * inverse[a * motors + m];
                p[a] = sum;
            }
            const double ap[3] = {p[0] - s[0], p[1] - s[1], p[2] - s[2]};
            const double t = denom > 0.0 ? ((ap[0] * ab[0] + ap[1] * ab[1]) + ap[2] * ab[2]) / denom : 0.0;
            double off[3];
            for (int a = 0; a < 3; a++)
                off[a] = p[a] - (s[a] + t * ab[a]);
            const double dist = sqrt((off[0] * off[0] + off[1] * off[1]) + off[2] * off[2]);
            if (dist > far)
                far = dist;
        }
        worst[b] = far;
    }
}
