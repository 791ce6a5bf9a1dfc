/* Pressure advance's smoothed extruder g at many times in one pass (codegen/motion/advance.py `smoothed` has the
 * numpy version, which this must match to rounding: tests/motion/test_advance.py): for each time t, the exact
 * integral of f(x) (h - |t - x|) / h^2 over the pieces of f under [t - h, t + h], each relative to f(t).
 * The same operations in the same order as the numpy version, so the sums agree to the last bits.
 *
 * Built at first use into the user's cache (codegen/native/__init__.py) and called through ctypes.
 */
#include <stdint.h>

/* The index of the first of `count` breaks after x (count: none), no break before `from` being after it: galloping
 * from there, then halving (sorted times walk on from the time before's). */
static int64_t first_after(const double *breaks, int64_t count, double x, int64_t from)
{
    int64_t lo = from, hi = from, step = 1;
    while (hi < count && breaks[hi] <= x) {
        lo = hi + 1;
        hi += step;
        step *= 2;
    }
    if (hi > count)
        hi = count;
    while (lo < hi) {
        const int64_t mid = lo + (hi - lo) / 2;
        if (breaks[mid] <= x)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* The piece of the first break after it (numpy's searchsorted side="right" less 1), clipped to the pieces. */
static int64_t clipped(int64_t after, int64_t pieces)
{
    return after < 1 ? 0 : (after > pieces ? pieces - 1 : after - 1);
}

static double clip(double x, double lo, double hi)
{
    return x < lo ? lo : (x > hi ? hi : x);
}

/* The integral of (half + side u)(c0 + c1 u + c2 u^2) from u0 to u1 (0 where u1 <= u0). */
static double weighted(double c0, double c1, double c2, double half, double side, double u0, double u1)
{
    const double q0 = half * c0, q1 = half * c1 + side * c0, q2 = half * c2 + side * c1, q3 = side * c2;
    if (u1 < u0)
        u1 = u0;
    const double a1 = u1 * (q0 + u1 * (q1 / 2 + u1 * (q2 / 3 + u1 * q3 / 4)));
    const double a0 = u0 * (q0 + u0 * (q1 / 2 + u0 * (q2 / 3 + u0 * q3 / 4)));
    return a1 - a0;
}

/* f: `pieces` quadratics from breaks (pieces + 1), position, velocity, accel; t (n, any order); writes g (n). */
void smoothed(int64_t n, const double *t, int64_t pieces, const double *breaks, const double *position,
              const double *velocity, const double *accel, double half, double *g)
{
    int64_t start = 0; /* the first break after the time before's t - half */
    for (int64_t i = 0; i < n; i++) {
        const double centre = t[i];
        if (i > 0 && !(centre >= t[i - 1])) /* unsorted (or NaN): search from the first break */
            start = 0;
        start = first_after(breaks, pieces + 1, centre - half, start);
        const double inside = clip(centre, breaks[0], breaks[pieces]); /* no break before `start` lies after it */
        const int64_t at = clipped(first_after(breaks, pieces + 1, inside, start), pieces);
        const double dt = inside - breaks[at];
        const double reference = position[at] + velocity[at] * dt + 0.5 * accel[at] * dt * dt;
        const int64_t lo = clipped(start, pieces);
        const double end = centre + half;
        double area = 0.0;
        for (int64_t k = lo; k == lo || (k < pieces && breaks[k] <= end); k++) {
            const double d = centre - breaks[k];
            const double c0 = position[k] + velocity[k] * d + 0.5 * accel[k] * d * d - reference;
            const double c1 = velocity[k] + accel[k] * d;
            const double c2 = 0.5 * accel[k];
            const double u0 = clip(breaks[k] - centre, -half, half); /* the piece under the triangle */
            const double u1 = clip(breaks[k + 1] - centre, -half, half);
            area += weighted(c0, c1, c2, half, 1.0, u0, u1 < 0.0 ? u1 : 0.0)
                    + weighted(c0, c1, c2, half, -1.0, u0 > 0.0 ? u0 : 0.0, u1);
        }
        g[i] = reference + area / (half * half);
    }
}
