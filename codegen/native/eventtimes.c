/* Event times in one pass (codegen/motion/stepgen.py and codegen/motion/curve_timing.py have the numpy versions, which this
 * must match to the bit: tests/native/test_tables.py): every master event of every block timed on the plan's
 * trapezoids where the master crosses a half-step point along its chord, or along the curve (a Hermite cubic
 * of the master's position) where curve timing applies; a dwell's step-less events spread evenly over it. Each
 * expression is written in the numpy version's order, so the floating-point results are the same.
 *
 * Built at first use into the user's cache (codegen/native/__init__.py) and called through ctypes.
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>

struct plan {
    const double *v_entry, *v_peak, *accel, *s_acc, *s_cruise, *t_start;
};

/* What Planner.time_at computes of a segment whatever the position: the time spent accelerating and cruising
 * when past each (the same expressions, so the same bits). */
struct trapezoid {
    int64_t seg;
    double t_acc, t_cruise;
};

static void trapezoid_of(const struct plan *p, int64_t seg, struct trapezoid *tr)
{
    const double v0 = p->v_entry[seg], vp = p->v_peak[seg], a = p->accel[seg], s_acc = p->s_acc[seg];
    tr->seg = seg;
    tr->t_acc = 2.0 * s_acc / fmax(v0 + sqrt(v0 * v0 + 2.0 * a * s_acc), 1e-300);
    tr->t_cruise = p->s_cruise[seg] > 0 ? p->s_cruise[seg] / fmax(vp, 1e-300) : 0.0;
}

/* Planner.time_at: when the tool is s mm into segment `seg` (whose trapezoid is `tr` when it is at hand). A term
 * that is zero there adds +0.0 in numpy, which changes nothing: it is left out. */
static double time_at(const struct plan *p, int64_t seg, double s, struct trapezoid *tr)
{
    if (tr->seg != seg)
        trapezoid_of(p, seg, tr);
    const double vp = p->v_peak[seg], a = p->accel[seg];
    const double s_acc = p->s_acc[seg], s_cr = p->s_cruise[seg];
    double t;
    if (s < s_acc) {
        const double v0 = p->v_entry[seg];
        t = 2.0 * s / fmax(v0 + sqrt(v0 * v0 + 2.0 * a * s), 1e-300);
    } else {
        t = tr->t_acc;
    }
    const double in_cruise = fmin(fmax(s - s_acc, 0.0), s_cr);
    if (in_cruise > 0)
        t = t + (in_cruise == s_cr ? tr->t_cruise : in_cruise / fmax(vp, 1e-300));
    const double in_dec = fmax(s - s_acc - s_cr, 0.0);
    if (in_dec > 0)
        t = t + 2.0 * in_dec / fmax(vp + sqrt(fmax(vp * vp - 2.0 * a * in_dec, 0.0)), 1e-300);
    return p->t_start[seg] + t;
}

static double clip01(double x)
{
    return fmin(fmax(x, 0.0), 1.0);
}

/* Blocks: their segment and event count. Per segment: the master's exact start (steps), its signed span, its
 * rounded start and direction, the plan's length, the dwell (s, > 0 marks one) and the plan's trapezoid.
 * Curve timing, per block (null `smooth`: none): which blocks keep it, whether the block before / after is
 * joined to it, the Hermite slopes at its ends, the master's start, unsigned span and direction.
 * Writes each event's time (s) and phase (0 accelerating, 1 cruising, 2 decelerating, 3 dwell). */
void event_times(int64_t blocks, const int64_t *block_seg, const int64_t *count, const double *x0,
                 const double *span, const double *p0, const double *sign, const double *length,
                 const double *dwell, const double *v_entry, const double *v_peak, const double *accel,
                 const double *s_acc, const double *s_cruise, const double *t_start, const uint8_t *smooth,
                 const uint8_t *has_prev, const uint8_t *has_next, const double *slope_in,
                 const double *slope_out, const double *u0, const double *cspan, const double *csign,
                 double *time, int8_t *phase)
{
    const struct plan plan = {v_entry, v_peak, accel, s_acc, s_cruise, t_start};
    struct trapezoid here = {-1, 0.0, 0.0}, there = {-1, 0.0, 0.0};
    int64_t e = 0;
    for (int64_t b = 0; b < blocks; b++) {
        const int64_t seg = block_seg[b];
        for (int64_t i = 0; i < count[b]; i++, e++) {
            const double k = (double)(i + 1);
            if (dwell[seg] > 0) {
                time[e] = t_start[seg] + dwell[seg] * k / (double)count[b];
                phase[e] = 3;
                continue;
            }
            const double frac = span[seg] != 0 ? (p0[seg] + sign[seg] * (k - 0.5) - x0[seg]) / span[seg] : 0.0;
            const double s = clip01(frac) * length[seg];
            time[e] = time_at(&plan, seg, s, &here);
            phase[e] = s < s_acc[seg] ? 0 : (s <= s_acc[seg] + s_cruise[seg] ? 1 : 2);
            if (!smooth || !smooth[b])
                continue;
            /* On the curve: a step rounded past its chord's end is timed on the neighbouring piece. */
            const double u = rint(u0[b]) + csign[b] * (k - 0.5);
            const double d = csign[b] * (u - u0[b]);
            int64_t w = b;
            if (d < 0 && has_prev[b])
                w = b - 1;
            else if (d > cspan[b] && has_next[b])
                w = b + 1;
            if (!smooth[w])
                continue;
            const double tau = clip01(csign[b] * (u - u0[w]) / cspan[w]);
            const double h = cspan[w], len = length[block_seg[w]];
            const double h10 = tau * ((1 - tau) * (1 - tau)), h01 = tau * tau * (3 - 2 * tau);
            const double h11 = tau * tau * (tau - 1);
            const double at = h10 * h * slope_in[w] + h01 * len + h11 * h * slope_out[w];
            time[e] = time_at(&plan, block_seg[w], fmin(fmax(at, 0.0), len), w == b ? &here : &there);
        }
    }
}
