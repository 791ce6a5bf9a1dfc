/* Douglas and Peucker's cuts of a linear machine's shaped motion into blocks whose slaves stay near their chords
 * (codegen/motion/chord_cuts.py has the numpy version, which this must match exactly:
 * tests/motion/test_shaped_native.py). Block by block, depth first: a block that strays too far is cut at its worst
 * point (or at its middle where its master makes too many steps), its left part walked before its right, so the
 * bounds come out sorted. The arithmetic is in the numpy version's order, without FMA.
 *
 * Built at first use into the user's cache (codegen/native/__init__.py) and called through ctypes.
 */
#include <math.h>
#include <stdint.h>

#define MAX_MOTORS 8
#define MAX_STACK 128

struct motion {
    int64_t pieces, motors;
    const double *breaks, *p, *v, *a; /* breaks (K + 1); p, v, a (K x M) steps, steps/s, steps/s^2 */
};

/* The piece that holds t (at a break, the one that begins there), as numpy's clipped searchsorted "right" - 1. */
static int64_t piece_of(const struct motion *m, double t)
{
    int64_t lo = 0, hi = m->pieces + 1; /* the first break > t lies in [lo, hi) */
    while (lo < hi) {
        int64_t mid = (lo + hi) / 2;
        if (m->breaks[mid] <= t)
            lo = mid + 1;
        else
            hi = mid;
    }
    int64_t k = lo - 1;
    return k < 0 ? 0 : (k > m->pieces - 1 ? m->pieces - 1 : k);
}

static void position(const struct motion *m, double t, double *out)
{
    int64_t k = piece_of(m, t);
    double dt = t - m->breaks[k];
    for (int64_t j = 0; j < m->motors; j++) {
        int64_t i = k * m->motors + j;
        out[j] = m->p[i] + m->v[i] * dt + 0.5 * m->a[i] * dt * dt;
    }
}

/* Where block [t0, t1] is to be cut (returns 1 and sets *at), or 0. */
static int cut_of(const struct motion *m, double t0, double t1, double limit, double max_span, double *at)
{
    double x0[MAX_MOTORS], x1[MAX_MOTORS], ratio[MAX_MOTORS];
    int64_t motors = m->motors, master = 0;
    double longest = -1.0;
    position(m, t0, x0);
    position(m, t1, x1);
    for (int64_t j = 0; j < motors; j++) {
        double span = fabs(rint(x1[j]) - rint(x0[j]));
        if (span > longest) {
            longest = span;
            master = j;
        }
    }
    double span = x1[master] - x0[master];
    for (int64_t j = 0; j < motors; j++)
        ratio[j] = span != 0.0 ? (x1[j] - x0[j]) / span : 0.0;
    int64_t first = piece_of(m, t0);
    double worst = -1.0, worst_time = t0;
    for (int64_t k = first; k < m->pieces && (k == first || m->breaks[k] < t1); k++) {
        double begin = m->breaks[k] > t0 ? m->breaks[k] : t0;
        double end = m->breaks[k + 1] < t1 ? m->breaks[k + 1] : t1;
        double h = end - begin, dt = begin - m->breaks[k];
        const double *p = m->p + k * motors, *v = m->v + k * motors, *a = m->a + k * motors;
        double start_u = p[master] + v[master] * dt + 0.5 * a[master] * dt * dt;
        double speed_u = v[master] + a[master] * dt;
        double best = -1.0, best_inside = 0.0, best_start = 0.0, best_tau = 0.0;
        for (int64_t j = 0; j < motors; j++) {
            double start = p[j] + v[j] * dt + 0.5 * a[j] * dt * dt;
            double speed = v[j] + a[j] * dt;
            double off = start - x0[j] - ratio[j] * (start_u - x0[master]);
            double c1 = speed - ratio[j] * speed_u;
            double c2 = a[j] - ratio[j] * a[master];
            double tau = c2 != 0.0 ? -c1 / c2 : 0.0;
            if (!(tau > 0.0 && tau < h))
                tau = 0.0;
            double inside = fabs(off + c1 * tau + 0.5 * c2 * tau * tau);
            double at_start = k == first ? 0.0 : fabs(off);
            double stray = inside > at_start ? inside : at_start;
            if (stray > best) {
                best = stray;
                best_inside = inside;
                best_start = at_start;
                best_tau = tau;
            }
        }
        if (best >= worst) { /* of equals, the latest piece */
            worst = best;
            worst_time = begin + (best_inside >= best_start ? best_tau : 0.0);
        }
    }
    double cut;
    if (worst > limit && span != 0.0)
        cut = worst_time;
    else if (longest > max_span)
        cut = 0.5 * (t0 + t1);
    else
        return 0;
    if (!(cut > t0 && cut < t1))
        return 0;
    *at = cut;
    return 1;
}

/* bounds (B + 1): the blocks' ends before; fresh (B): the blocks to cut (the others are known to need none);
 * writes every bound after (sorted) to out and returns their count, or -1 where more than `capacity` would be
 * written. */
int64_t chord_cuts(int64_t pieces, int64_t motors, const double *breaks, const double *p, const double *v,
                   const double *a, int64_t bounds_count, const double *bounds, const uint8_t *fresh, double limit,
                   double max_span, int64_t max_depth, double *out, int64_t capacity)
{
    struct motion m = {pieces, motors, breaks, p, v, a};
    double stack_end[MAX_STACK];
    int64_t stack_depth[MAX_STACK];
    if (motors > MAX_MOTORS || max_depth >= MAX_STACK || capacity < 1)
        return -1;
    int64_t count = 0;
    out[count++] = bounds[0];
    for (int64_t b = 0; b + 1 < bounds_count; b++) {
        double begin = bounds[b];
        int64_t top = 0;
        stack_end[0] = bounds[b + 1];
        stack_depth[0] = fresh[b] ? 0 : max_depth;
        while (top >= 0) {
            double at, end = stack_end[top];
            int64_t depth = stack_depth[top];
            if (depth < max_depth && cut_of(&m, begin, end, limit, max_span, &at)) {
                stack_depth[top] = depth + 1; /* the right part waits under the left */
                top++;
                stack_end[top] = at;
                stack_depth[top] = depth + 1;
                continue;
            }
            if (count == capacity)
                return -1;
            out[count++] = end;
            begin = end;
            top--;
        }
    }
    return count;
}
