/* How far the shaped tool gets from the planned one at the same moment, at its largest, sampled along every shaped
 * piece (codegen/motion/shaped_motion.py `smoothing` has the numpy version, which this must match to the bit:
 * tests/motion/test_shaped_native.py). The samples' times rise, so one walk finds each one's planned piece.
 * Each expression is written in the numpy version's order, so the floating-point results are the same.
 *
 * Built at first use into the user's cache (codegen/native/__init__.py) and called through ctypes.
 */
#include <math.h>
#include <stdint.h>

#define AXES 4

/* shaped: breaks (S + 1), position, velocity, accel (S x 4); planned likewise (P pieces); share (N): where along a
 * piece each sample is (0 to 1); shift: s the shaped clock runs behind the planned. Returns the worst sample's
 * index (piece * N + sample) and writes its distance (mm, x y z). */
int64_t shaped_smoothing(int64_t shaped_pieces, const double *s_breaks, const double *s_p, const double *s_v,
                         const double *s_a, int64_t planned_pieces, const double *p_breaks, const double *p_p,
                         const double *p_v, const double *p_a, int64_t samples, const double *share, double shift,
                         double *worst)
{
    int64_t best = 0, below = 0; /* planned breaks <= the sample's time */
    double far = -1.0, first = p_breaks[0], last = p_breaks[planned_pieces];
    for (int64_t k = 0; k < shaped_pieces; k++) {
        double h = s_breaks[k + 1] - s_breaks[k];
        for (int64_t j = 0; j < samples; j++) {
            double t = s_breaks[k] + h * share[j];
            double dt = t - s_breaks[k];
            double u = t - shift;
            u = u < first ? first : (u > last ? last : u);
            while (below < planned_pieces + 1 && p_breaks[below] <= u)
                below++;
            while (below > 0 && p_breaks[below - 1] > u) /* a sample a rounding earlier than the one before */
                below--;
            int64_t q = below - 1;
            q = q < 0 ? 0 : (q > planned_pieces - 1 ? planned_pieces - 1 : q);
            double du = u - p_breaks[q];
            double sum = 0.0;
            for (int64_t axis = 0; axis < 3; axis++) {
                int64_t i = k * AXES + axis, m = q * AXES + axis;
                double here = s_p[i] + s_v[i] * dt + 0.5 * s_a[i] * dt * dt;
                double there = p_p[m] + p_v[m] * du + 0.5 * p_a[m] * du * du;
                double d = here - there;
                sum += d * d;
            }
            double distance = sqrt(sum);
            if (distance > far) {
                far = distance;
                best = k * samples + j;
            }
        }
    }
    *worst = far;
    return best;
}
