/* The path check's distances in one pass (codegen/tables/checks.py has the numpy version, which this must match to
 * rounding: tests/native/test_tables.py): from each tool position (xyz) to the job's path along its segment, lines
 * exactly, arcs by their radius at the position's angle (a spiral's grows with it), other curves by their
 * samples; a position further than `near` from its own segment is measured against either neighbour too (a step
 * just past a corner is on the path it is on).
 *
 * Built at first use into the user's cache (codegen/native/__init__.py) and called through ctypes.
 */
#include <math.h>
#include <stdint.h>

#define REF_ARC 1
#define TWO_PI 6.283185307179586

struct path {
    const double *start, *end;  /* (S x 4) */
    const int64_t *kind;        /* (S) */
    const double *center;       /* (S x 2) */
    const double *radius;       /* (S) at `angle` */
    const double *angle;        /* (S) rad */
    const double *growth;       /* (S) mm per rad */
    const int64_t *plane;       /* (S x 2) */
    const int64_t *fine_row;    /* (S), -1: none */
    const double *fine;         /* (F x samples x 3) */
    int64_t samples;
};

/* Distance from p to the piece a-b, and the nearest point on it (when `nearest` is given). */
static double to_piece(const double *p, const double *a, const double *b, double *nearest)
{
    double ab[3], ap[3], dot = 0.0, len2 = 0.0;
    for (int i = 0; i < 3; i++) {
        ab[i] = b[i] - a[i];
        ap[i] = p[i] - a[i];
        dot += ap[i] * ab[i];
        len2 += ab[i] * ab[i];
    }
    double t = len2 > 0.0 ? dot / len2 : 0.0;
    t = t < 0.0 ? 0.0 : (t > 1.0 ? 1.0 : t);
    double d2 = 0.0;
    for (int i = 0; i < 3; i++) {
        const double q = a[i] + t * ab[i];
        if (nearest)
            nearest[i] = q;
        d2 += (p[i] - q) * (p[i] - q);
    }
    return sqrt(d2);
}

static double to_reference(const double *p, int64_t s, const struct path *path)
{
    double on_chord[3];
    double dist = to_piece(p, path->start + 4 * s, path->end + 4 * s, on_chord);
    const int64_t row = path->fine_row[s];
    if (row >= 0) {
        const double *f = path->fine + row * path->samples * 3;
        dist = INFINITY;
        for (int64_t k = 0; k + 1 < path->samples; k++) {
            const double d = to_piece(p, f + 3 * k, f + 3 * (k + 1), 0);
            if (d < dist)
                dist = d;
        }
    }
    if (path->kind[s] == REF_ARC) {
        const int64_t u = path->plane[2 * s], v = path->plane[2 * s + 1];
        const double pu = p[u] - path->center[2 * s], pv = p[v] - path->center[2 * s + 1];
        double radius = path->radius[s];
        if (path->growth[s] != 0.0) { /* a spiral */
            double turn = atan2(pv, pu) - path->angle[s];
            turn -= TWO_PI * nearbyint(turn / TWO_PI); /* within half a turn: the tool is near its chord */
            radius += path->growth[s] * turn;
        }
        const double radial = fabs(hypot(pu, pv) - radius);
        double off2 = 0.0;
        for (int64_t i = 0; i < 3; i++)
            if (i != u && i != v)
                off2 += (p[i] - on_chord[i]) * (p[i] - on_chord[i]);
        dist = hypot(radial, sqrt(off2));
    }
    return dist;
}

/* Distances (N) from points on segments seg (N) of a path of `segments` pieces. The points are either given
 * (N x 4), or (where `points` is null) motor positions in steps (N x M) less `origin` (M), times `to_axes`
 * (4 x M, axis mm per step; a row of zeros takes that axis from the segment's start). */
void path_errors(int64_t n, const double *points, const int64_t *steps, int64_t motors, const int64_t *origin,
                 const double *to_axes, const int64_t *seg, double near, int64_t segments, const double *start,
                 const double *end, const int64_t *kind, const double *center, const double *radius,
                 const double *angle, const double *growth, const int64_t *plane, const int64_t *fine_row,
                 const double *fine, int64_t samples, double *out)
{
    const struct path path = {start, end, kind, center, radius, angle, growth, plane, fine_row, fine, samples};
    int driven[4];
    for (int a = 0; a < 4; a++) {
        driven[a] = 0;
        for (int64_t m = 0; m < motors && !points; m++)
            driven[a] |= to_axes[a * motors + m] != 0.0;
    }
    for (int64_t i = 0; i < n; i++) {
        double mapped[4];
        const double *p = points + 4 * i;
        if (!points) {
            for (int a = 0; a < 4; a++) {
                double sum = 0.0;
                for (int64_t m = 0; m < motors; m++)
                    sum += to_axes[a * motors + m] * (double)(steps[i * motors + m] + origin[m]);
                mapped[a] = driven[a] ? sum : start[4 * seg[i] + a];
            }
            p = mapped;
        }
        double dist = to_reference(p, seg[i], &path);
        if (dist > near) {
            for (int64_t k = -1; k <= 1; k += 2) {
                int64_t s = seg[i] + k;
                s = s < 0 ? 0 : (s > segments - 1 ? segments - 1 : s);
                const double d = to_reference(p, s, &path);
                if (d < dist)
                    dist = d;
            }
        }
        out[i] = dist;
    }
}
