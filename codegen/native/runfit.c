/* Rate runs: each event's timing window, then the greedy fit of runs (interval, add, count) that keep every event
 * within its window. The algorithm, its units and its reasoning are in codegen/tables/runfit.py; its Python version and
 * the numpy windows of codegen/tables/compress.py are the reference this must match exactly (tests/native/test_tables.py). It
 * is C because a run's search follows the runs before it, a loop numpy cannot vectorise; the windows come along
 * so that numpy's two dozen passes over the events become two (and leave_room's a third, backwards).
 *
 * Built at first use into the user's cache (codegen/native/__init__.py) and called through ctypes.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#define NO_FAIL 0
#define GUESS_STRIDE 8 /* codegen/tables/runfit.py */

/* The timing windows of codegen/tables/compress.py (`numpy_windows`), each expression in numpy's order so that the
 * floating-point results are the same bits (np.cumsum and np.maximum.accumulate are sequential too): the planned
 * ticks pushed apart (a running maximum of the planned tick less the pushes' running sum) and each event's window,
 * as a range of positions counted from tick `base`. block_first: B + 1 entries, from 0 to the number of events;
 * `rate_gap`: per block, the gap (ticks) pushed events catch up with at most, or NULL; `block_extra`: per block,
 * the ticks its first event needs beyond block_gap (runtime records), or NULL. */
void timing_windows(int64_t blocks, const int64_t *block_first, const double *time, const double *rate_gap,
                    const int64_t *block_extra, double tick_hz, int64_t run_gap, int64_t block_gap, double origin, int64_t base, double share,
                    double min_ticks, double max_ticks, int64_t *needed, double *ideal, double *window,
                    int64_t *lo, int64_t *hi)
{
    const double run_push = 1.1 * (double)run_gap + 2.0;
    double planned_before = origin, total = 0.0, pushed = -INFINITY, ideal_before = origin;
    for (int64_t b = 0; b < blocks; b++) {
        const int64_t first = block_first[b], end = block_first[b + 1];
        const int64_t gap = block_gap + (block_extra != NULL ? block_extra[b] : 0);
        const double block_push = 1.1 * (double)gap + 2.0;
        /* Two loops over the block's events (the second's arithmetic does not wait on the running sum). */
        for (int64_t k = first; k < end; k++) {
            needed[k] = k == first ? gap : run_gap;
            const double planned = time[k] * tick_hz;
            double push = k == first ? block_push : run_push;
            if (rate_gap != NULL) {
                const double catch_up = rate_gap[b] < planned - planned_before ? rate_gap[b]
                                                                               : planned - planned_before;
                push = push > catch_up ? push : catch_up;
            }
            planned_before = planned;
            total += push;
            const double behind = planned - total;
            pushed = pushed > behind ? pushed : behind;
            ideal[k] = (pushed > origin ? pushed : origin) + total;
        }
        for (int64_t k = first; k < end; k++) {
            double w = share * (ideal[k] - ideal_before);
            w = w > min_ticks ? w : min_ticks;
            w = w < max_ticks ? w : max_ticks;
            window[k] = w;
            ideal_before = ideal[k];
            /* ceil and floor as numpy's, then to whole ticks: the truncated value, one up or down when not whole */
            const double early = ideal[k] - w - (double)base, late = ideal[k] + w - (double)base;
            const int64_t e = (int64_t)early, l = (int64_t)late;
            lo[k] = 256 * (e + (early > (double)e));
            hi[k] = 256 * (l - (late < (double)l)) + 255;
        }
    }
}

static int64_t floor_div(int64_t a, int64_t b) /* b > 0 */
{
    int64_t q = a / b;
    return (a % b != 0 && a < 0) ? q - 1 : q;
}

static int smaller_magnitude(int64_t a, int64_t b)
{
    return (a < 0 ? -a : a) < (b < 0 ? -b : b);
}

/* `leave_room` of codegen/tables/runfit.py backwards: room[k] = min(hi[k], room[k + 1] - 256 * needed[k + 1]). */
static void leave_room(int64_t events, const int64_t *hi, const int64_t *needed, int64_t *room)
{
    for (int64_t k = events - 1; k >= 0; k--)
        room[k] = (k + 1 < events && room[k + 1] - 256 * needed[k + 1] < hi[k]) ? room[k + 1] - 256 * needed[k + 1]
                                                                                : hi[k];
}

/* `add_guess` of codegen/tables/runfit.py at one event (the last sample's for the events it cannot reach). */
static int64_t add_guess(int64_t events, const int64_t *lo, const int64_t *hi, int64_t k)
{
    const int64_t s = GUESS_STRIDE;
    if (events < 2 * s + 1)
        return 0;
    if (k > events - 2 * s - 1)
        k = events - 2 * s - 1;
    const double m0 = (double)(lo[k] + hi[k]) / 2.0, m1 = (double)(lo[k + s] + hi[k + s]) / 2.0,
                 m2 = (double)(lo[k + 2 * s] + hi[k + 2 * s]) / 2.0;
    return (int64_t)rint((m2 - 2.0 * m1 + m0) / (double)(s * s));
}

struct reach {
    int64_t count;    /* events the run keeps within their windows */
    int64_t i_lo;     /* the intervals that do it, for all `count` events */
    int64_t i_hi;
    int wants;        /* where it stopped: +1 the next event needs a larger add, -1 a smaller one, 0 it did not */
};

/* What the tries of one run share. The k-th event (k >= 2) is in its window [lo, hi] when
 * lo - pos <= k * interval + add * k (k - 1) / 2 <= hi - pos, that is interval >= ceil((lo - pos) / k - e / 2) with
 * e = add * (k - 1): ceil((lo - pos) / k) - e / 2 for e even, ceil((lo - pos) / k - 1 / 2) - (e - 1) / 2 for e odd
 * (and the same for hi, rounded down). So one division per event and run gives its bounds for every add; e is odd
 * only for an odd add and an even k. */
struct run_start {
    const int64_t *lo, *hi;      /* from the run's first event on */
    int64_t pos, max_interval;
    int64_t reach;               /* events the run may have */
    int64_t first_lo, first_hi;  /* the first event's intervals (they do not depend on the add) */
    int64_t known;               /* the tables hold k = 2 .. known */
    int64_t *even, *odd;         /* for an even and an odd add: per k, the lowest and highest interval + e >> 1 */
    int64_t *band;               /* per k, the widest window of events 1 .. k */
};

/* Event k's bounds, for both tables. */
static inline void learn(struct run_start *s, int64_t k)
{
    const int64_t c = s->lo[k - 1] - s->pos, d = s->hi[k - 1] - s->pos;
    int64_t qc, qd;
    if ((uint64_t)c <= UINT32_MAX && (uint64_t)d <= UINT32_MAX && k <= UINT32_MAX) {  /* the usual case: faster */
        qc = (uint32_t)c / (uint32_t)k;
        qd = (uint32_t)d / (uint32_t)k;
    } else {
        qc = floor_div(c, k);
        qd = floor_div(d, k);
    }
    const int64_t rc = c - qc * k, rd = d - qd * k;
    s->even[2 * k] = qc + (rc > 0);
    s->even[2 * k + 1] = qd;
    s->odd[2 * k] = (k & 1) ? qc + (rc > 0) : qc + (2 * rc > k);
    s->odd[2 * k + 1] = (k & 1) ? qd : qd - (2 * rd < k);
    const int64_t width = s->hi[k - 1] - s->lo[k - 1];
    s->band[k] = width > s->band[k - 1] ? width : s->band[k - 1];
    s->known = k;
}

/* How far a run with this `add` reaches; `clamped`: every event's own interval, interval + e, kept within
 * [0, max_interval] too (`extend` leaves that out where it cannot matter: a shorter loop). */
static inline struct reach walk(int64_t add, struct run_start *s, const int clamped)
{
    struct reach r = {0, INT64_MIN, INT64_MAX, NO_FAIL};
    int64_t i_lo = s->first_lo, i_hi = s->first_hi;
    if (i_lo > i_hi)
        return r;
    const int64_t reach = s->reach, max_interval = s->max_interval, *table = (add & 1) ? s->odd : s->even;
    int64_t k = 2, e = 0;
    for (; k <= reach; k++) {
        e += add;
        if (k > s->known)
            learn(s, k);
        const int64_t half = e >> 1, need_lo = table[2 * k] - half, need_hi = table[2 * k + 1] - half;
        int64_t new_lo = need_lo, new_hi = need_hi;
        if (clamped) {
            if (new_lo < -e)
                new_lo = -e;
            if (new_hi > max_interval - e)
                new_hi = max_interval - e;
        }
        if (new_lo < i_lo)
            new_lo = i_lo;
        if (new_hi > i_hi)
            new_hi = i_hi;
        if (new_lo > new_hi) {
            r.wants = (need_lo > i_hi || (clamped && -e > i_hi)) ? +1 : -1;
            break;
        }
        i_lo = new_lo;
        i_hi = new_hi;
    }
    r.count = k - 1;
    r.i_lo = i_lo;
    r.i_hi = i_hi;
    return r;
}

/* The first event leaves 0 <= i_lo <= i_hi <= max_interval, and the range only narrows: the own intervals' limits
 * cannot bind while e stays within [-i_lo, max_interval - i_hi] of the first event. Where e did up to the last
 * event the walk without them tried, it found what the walk with them finds; else that one is made (2 % of the
 * Benchy's tries). */
static struct reach extend(int64_t add, struct run_start *s)
{
    const struct reach r = walk(add, s, 0);
    const int64_t most = add * (r.count + (r.wants != NO_FAIL) - 1);
    if (add > 0 ? most > s->max_interval - s->first_hi : -most > s->first_lo)
        return walk(add, s, 1);
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

/* Fit runs over `events` events. lo, hi: each event's position window in 1/256 tick, counted from tick `base` (the
 * event happens at tick base + floor(position / 256)); needed: the fewest ticks from the event before; p0: the
 * position of the event before the first. Writes the windows' upper ends lowered by `leave_room` to `room` (it
 * may be `hi`), count, interval, add per run and the tick of every event; returns the number of runs (-1: out of
 * memory). */
int64_t fit_runs(int64_t events, const int64_t *lo, const int64_t *hi, const int64_t *needed, int64_t p0,
                 int64_t base, int64_t max_count, int64_t max_add, int64_t max_interval, int64_t *room,
                 int64_t *run_count, int64_t *run_interval, int64_t *run_add, int64_t *tick)
{
    const int64_t longest = max_count < events ? max_count : events;
    int64_t *scratch = malloc(sizeof(int64_t) * 5 * (longest + 1));
    if (scratch == NULL)
        return -1;
    leave_room(events, hi, needed, room);
    struct run_start s = {.max_interval = max_interval, .even = scratch, .odd = scratch + 2 * (longest + 1),
                          .band = scratch + 4 * (longest + 1)};
    int64_t runs = 0, first = 0, pos = p0, last_tick = p0 >> 8;  /* ticks from base */
    while (first < events) {
        int64_t first_lo = 256 * (last_tick + needed[first]);
        if (first_lo < lo[first])
            first_lo = lo[first];
        s.lo = lo + first;
        s.hi = room + first;
        s.pos = pos;
        s.reach = events - first < max_count ? events - first : max_count;
        s.first_lo = first_lo - pos > 0 ? first_lo - pos : 0;
        s.first_hi = room[first] - pos < max_interval ? room[first] - pos : max_interval;
        s.known = 1;
        s.band[1] = room[first] - first_lo > 0 ? room[first] - first_lo : 0;
        int64_t a_min = -max_add, a_max = max_add, add = add_guess(events, lo, room, first);
        if (add < a_min)
            add = a_min;
        if (add > a_max)
            add = a_max;
        struct reach best = {0, 0, 0, NO_FAIL};
        int64_t best_add = 0;
        for (;;) {
            struct reach r = extend(add, &s);
            const int better = r.count > best.count
                               || (r.count == best.count && r.count > 0 && smaller_magnitude(add, best_add));
            if (better) {
                best = r;
                best_add = add;
            }
            if (r.wants == NO_FAIL)
                break;
            if (better && best.count >= 2) {  /* (while the best stays, its spread narrows nothing more) */
                const int64_t spread = add_spread(best.count, s.band[best.count]);
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
            const int64_t target = floor_div(low + room[j], 2) - pos - best_add * (count * (count - 1) / 2);
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
            tick[first + k - 1] = base + t;
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
    free(scratch);
    return runs;
}
