/* Greedy rate-run fitting: the longest run (interval, add, count) from each event on that keeps every event's
 * time within its window. The algorithm, its units and its reasoning are in codegen/runfit.py, whose pure-Python
 * version this must match exactly (tests/test_runfit.py); it is C because a run's search follows the runs before
 * it, a loop numpy cannot vectorise. Integer arithmetic only.
 *
 * Built at first use into the user's cache (codegen/native/__init__.py) and called through ctypes.
 */
#include <stdint.h>

#define NO_FAIL 0

static int64_t floor_div(int64_t a, int64_t b) /* b > 0 */
{
    int64_t q = a / b;
    return (a % b != 0 && a < 0) ? q - 1 : q;
}

static int64_t ceil_div(int64_t a, int64_t b) /* b > 0 */
{
    int64_t q = a / b;
    return (a % b != 0 && a > 0) ? q + 1 : q;
}

static int smaller_magnitude(int64_t a, int64_t b)
{
    return (a < 0 ? -a : a) < (b < 0 ? -b : b);
}

struct reach {
    int64_t count;    /* events the run keeps within their windows */
    int64_t i_lo;     /* the intervals that do it, for all `count` events */
    int64_t i_hi;
    int64_t band;     /* the widest window among the events tried (1/256 tick) */
    int wants;        /* where it stopped: +1 the next event needs a larger add, -1 a smaller one, 0 it did not */
};

/* How far a run with this `add` reaches from event `first`, starting at position `p0`. */
static struct reach extend(int64_t add, int64_t first, int64_t events, const int64_t *lo, const int64_t *hi,
                           int64_t first_lo, int64_t p0, int64_t max_count, int64_t max_interval)
{
    struct reach r = {0, 0, 0, 0, NO_FAIL};
    int64_t i_lo = INT64_MIN, i_hi = INT64_MAX;
    for (int64_t k = 1; k <= max_count && first + k - 1 < events; k++) {
        const int64_t j = first + k - 1;
        const int64_t low = (k == 1) ? first_lo : lo[j];
        const int64_t shift = p0 + add * (k * (k - 1) / 2);
        const int64_t a = low - shift, b = hi[j] - shift;
        int64_t new_lo = i_lo, new_hi = i_hi;
        /* Divide only when the bound tightens. */
        if (k == 1 || k * i_lo < a)
            new_lo = ceil_div(a, k);
        if (k == 1 || k * i_hi > b)
            new_hi = floor_div(b, k);
        /* Every event's own interval, interval + add * (k - 1), within [0, max_interval]. */
        const int64_t own = add * (k - 1);
        if (new_lo < -own)
            new_lo = -own;
        if (new_hi > max_interval - own)
            new_hi = max_interval - own;
        if (new_lo > new_hi) {
            r.wants = (ceil_div(a, k) > i_hi || -own > i_hi) ? +1 : -1;
            if (k == 1)
                r.wants = NO_FAIL;
            break;
        }
        i_lo = new_lo;
        i_hi = new_hi;
        if (hi[j] - low > r.band)
            r.band = hi[j] - low;
        r.count = k;
    }
    r.i_lo = i_lo;
    r.i_hi = i_hi;
    return r;
}

/* The add range any run at least `count` long can use, around an add that reaches `count`: two quadratic
 * sequences within the same band of width `band` at events m and n (m = n / 2) differ in add by at most
 * 2 band (m + n) / (m n (n - m)). */
static int64_t add_spread(int64_t count, int64_t band)
{
    const int64_t n = count, m = count / 2;
    return (2 * band * (m + n)) / (m * n * (n - m)) + 1;
}

/* Fit runs over `events` events. lo, hi: each event's position window in 1/256 tick (the event happens at tick
 * floor(position / 256)); needed: the fewest ticks from the event before; p0: the position before the first
 * event, prev_tick: its tick. Writes count, interval, add per run and the tick of every event; returns the
 * number of runs. */
int64_t fit_runs(int64_t events, const int64_t *lo, const int64_t *hi, const int64_t *needed, const int64_t *guess,
                 int64_t p0, int64_t prev_tick, int64_t max_count, int64_t max_add, int64_t max_interval,
                 int64_t *run_count, int64_t *run_interval, int64_t *run_add, int64_t *tick)
{
    int64_t runs = 0, first = 0, pos = p0, last_tick = prev_tick;
    while (first < events) {
        int64_t first_lo = 256 * (last_tick + needed[first]);
        if (first_lo < lo[first])
            first_lo = lo[first];
        int64_t a_min = -max_add, a_max = max_add, add = guess[first];
        if (add < a_min)
            add = a_min;
        if (add > a_max)
            add = a_max;
        struct reach best = {0, 0, 0, 0, NO_FAIL};
        int64_t best_add = 0;
        for (;;) {
            struct reach r = extend(add, first, events, lo, hi, first_lo, pos, max_count, max_interval);
            if (r.count > best.count || (r.count == best.count && r.count > 0 && smaller_magnitude(add, best_add))) {
                best = r;
                best_add = add;
            }
            if (r.wants == NO_FAIL)
                break;
            if (best.count >= 2) {
                const int64_t spread = add_spread(best.count, best.band);
                if (a_min < best_add - spread)
                    a_min = best_add - spread;
                if (a_max > best_add + spread)
                    a_max = best_add + spread;
            }
            if (r.wants > 0 && a_min < add + 1)
                a_min = add + 1;
            if (r.wants < 0 && a_max > add - 1)
                a_max = add - 1;
            if (a_min > a_max)
                break;
            add = a_min + (a_max - a_min) / 2;
        }
        int64_t count = best.count, interval;
        if (count == 0) {
            /* Not even one event fits its window after the one before: the earliest time the player allows. */
            count = 1;
            best_add = 0;
            interval = first_lo - pos;
            if (interval > max_interval)
                interval = max_interval;
        } else {
            /* The interval that puts the run's last event nearest the middle of its window. */
            const int64_t j = first + count - 1;
            const int64_t low = (count == 1) ? first_lo : lo[j];
            const int64_t target = floor_div(low + hi[j], 2) - pos - best_add * (count * (count - 1) / 2);
            interval = floor_div(2 * target + count, 2 * count);
            if (interval < best.i_lo)
                interval = best.i_lo;
            if (interval > best.i_hi)
                interval = best.i_hi;
        }
        /* Play it: every event's tick; the run ends early where an event comes too soon after the one before. */
        int64_t k = 1, p = pos;
        for (; k <= count; k++) {
            p += interval + best_add * (k - 1);
            const int64_t t = p >> 8;
            if (k > 1 && t - last_tick < needed[first + k - 1]) {
                p -= interval + best_add * (k - 1);
                break;
            }
            tick[first + k - 1] = t;
            last_tick = t;
        }
        count = k - 1;
        run_count[runs] = count;
        run_interval[runs] = interval;
        run_add[runs] = best_add;
        runs++;
        first += count;
        pos = p;
    }
    return runs;
}
