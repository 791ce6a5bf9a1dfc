/* The G-code interpreter's short way in C: stretches of plain G0/G1 lines (words X Y Z E F S, each at most once)
 * and comment lines, read and run as codegen/gcode/reader.py and Interpreter.line (codegen/gcode/interpreter.py)
 * do, which stay the reference (tests/native/test_frontend.py compares them). Any other line, and a plain line
 * that would be an error, is left to Python: the run stops before it. The arithmetic is Python's, operation
 * by operation (no FMA: -std=c99 contracts nothing); numbers are read by strtod, correctly rounded as float().
 *
 * Built at first use into the user's cache (codegen/native/__init__.py) and called through ctypes.
 */
#include <locale.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* The interpreter's state (codegen/gcode/fast.py packs it): reals, and flags. */
enum { POS = 0, OFF = 4, UNIT = 8, FLOW, E_SHIFT, FEED, DRAW_FEED, RAPID, SPEED_FACTOR, MIN_FEED, MIN_TRAVEL_FEED,
       ACCEL_PRINT, ACCEL_TRAVEL, ACCEL_RETRACT, S_FULL, POWER,
       REACH /* x 4: how far each axis may go */, LONGEST_MOVE /* s: codegen/toolpath/limits.py */ };
enum { RELATIVE, E_RELATIVE, HAS_FEED, SPINDLE, FIXED /* bit i: axis i has no motor */, MODE /* 0: G0, 1: G1 */,
       S_WATCHED /* lines with S are Python's (its note or warning about S comes first) */ };
enum { X, Y, Z, E, F, S, WORDS };

#define NUMBER_CHARS 64 /* longer numbers are left to Python */
static const char LETTERS[] = "XYZEFS"; /* in the order of the enum above */

static int regex_space(char c) /* \s of Python's re.ASCII */
{
    return c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\f' || c == '\v';
}

static int str_space(char c) /* str.isspace() of an ASCII character */
{
    return regex_space(c) || (c >= 0x1c && c <= 0x1f);
}

/* The number at text[k] ([+-]?(\d+\.?\d*|\.\d+)) into *value; returns the position after it, or -1. */
static int64_t number(const char *text, int64_t k, int64_t end, double *value)
{
    const int64_t first = k;
    if (k < end && (text[k] == '+' || text[k] == '-'))
        k++;
    int64_t digits = 0;
    while (k < end && text[k] >= '0' && text[k] <= '9')
        k++, digits++;
    if (k < end && text[k] == '.') {
        k++;
        while (k < end && text[k] >= '0' && text[k] <= '9')
            k++, digits++;
    }
    if (digits == 0 || k - first >= NUMBER_CHARS)
        return -1;
    char copy[NUMBER_CHARS];
    memcpy(copy, text + first, (size_t)(k - first));
    copy[k - first] = '\0';
    *value = strtod(copy, NULL);
    return k;
}

enum { SKIP, PLAIN, OTHER };

/* One line text[0..n): SKIP (blank or comment: not a block), PLAIN (a G0/G1 line of plain words: its mode,
 * which words it has and their values, its indent) or OTHER (for Python). */
static int classify(const char *text, int64_t n, int *mode, int *has, double *value, int64_t *indent)
{
    if (n == 0 || text[0] == ';')
        return SKIP;
    if (text[n - 1] == '\r')
        n--;
    if (memchr(text, '(', (size_t)n) || memchr(text, ')', (size_t)n))
        return OTHER;
    const char *semicolon = memchr(text, ';', (size_t)n);
    const int64_t end = semicolon ? semicolon - text : n;
    if (memchr(text, '*', (size_t)end))
        return OTHER;
    if (end == 0)
        return SKIP;
    *indent = 0;
    if (text[0] == ' ' || text[0] == '\t') {
        int64_t k = 0;
        while (k < end && str_space(text[k]))
            k++;
        if (k == end)
            return SKIP;
        *indent = k;
    }
    int64_t k = 0, words = 0;
    *has = 0;
    while (k < end && regex_space(text[k]))
        k++;
    while (k < end) {
        char letter = text[k];
        if (letter >= 'a' && letter <= 'z')
            letter = (char)(letter - 'a' + 'A');
        k++;
        while (k < end && regex_space(text[k]))
            k++;
        const int64_t digits = k;
        double v;
        k = number(text, k, end, &v);
        if (k < 0)
            return OTHER;
        if (words == 0) {  /* G0, G1, G00, G01 as written */
            const int64_t len = k - digits;
            const char *d = text + digits;
            if (letter != 'G' || !((len == 1 && (d[0] == '0' || d[0] == '1')) ||
                                   (len == 2 && d[0] == '0' && (d[1] == '0' || d[1] == '1'))))
                return OTHER;
            *mode = d[len - 1] - '0';
        } else {
            const char *at = memchr(LETTERS, letter, WORDS);
            if (at == NULL || (*has & (1 << (at - LETTERS))))
                return OTHER;
            const int w = (int)(at - LETTERS);
            *has |= 1 << w;
            value[w] = v;
        }
        words++;
        while (k < end && regex_space(text[k]))
            k++;
    }
    return words ? PLAIN : OTHER;
}

/* The speed (mm/s) of a move as Interpreter.line takes it: its F (`feed` < 0: none on the line), M220, M205. */
static double move_speed(const double *state, int mode, double feed, int64_t has_feed, int extrudes)
{
    double speed = mode == 0 ? state[RAPID] : (feed >= 0.0 ? feed : (has_feed ? state[FEED] : state[DRAW_FEED]));
    speed = speed * state[SPEED_FACTOR];
    const double least = extrudes ? state[MIN_FEED] : state[MIN_TRAVEL_FEED];
    return least > speed ? least : speed;
}

/* Whether a move goes out of reach or lasts longer than a move may (Moves.beyond_limits reports it). */
static int beyond(const double *state, const double *pos, const double *tgt, int mode, double feed,
                  int64_t has_feed)
{
    for (int i = 0; i < 4; i++)
        if (tgt[i] != pos[i] && !(fabs(tgt[i]) <= state[REACH + i]))
            return 1;
    const double dx = tgt[0] - pos[0], dy = tgt[1] - pos[1], dz = tgt[2] - pos[2];
    double length = sqrt(dx * dx + dy * dy + dz * dz);
    if (length == 0.0)
        length = fabs(tgt[3] - pos[3]);
    return !(length / move_speed(state, mode, feed, has_feed, tgt[3] != pos[3]) <= state[LONGEST_MOVE]);
}

/* Runs lines from *at (line k is text[starts[k] .. starts[k + 1] - 1)) while they are plain or comments and the
 * batch has room (*blocks: in, the blocks it may still take; out, the blocks taken). Each move goes to row
 * `made` on of end (x 4), feed, accel, power, rapid, line, indent (at most `capacity` rows). Returns the moves
 * made; *at is the first line not taken. */
int64_t run_lines(const char *text, const int64_t *starts, int64_t lines, int64_t *at, int64_t *blocks,
                  double *state, int64_t *flags, int64_t made, int64_t capacity, double *end, double *feed,
                  double *accel, double *power, int64_t *rapid, int64_t *line, int64_t *indent)
{
    const int64_t budget = *blocks, first_made = made;
    int64_t taken = 0, k = *at;
    const char *point = localeconv()->decimal_point;
    if (point[0] != '.' || point[1] != '\0') {  /* a locale whose numbers strtod reads otherwise: Python reads */
        *blocks = 0;
        return 0;
    }
    double *pos = state + POS;
    const double *off = state + OFF, unit = state[UNIT];
    for (; k < lines; k++) {
        int mode = 0, has = 0;
        double value[WORDS];
        int64_t margin = 0;
        const int kind = classify(text + starts[k], starts[k + 1] - 1 - starts[k], &mode, &has, value, &margin);
        if (kind == SKIP)
            continue;
        if (kind == OTHER || taken == budget || made == capacity)
            break;
        double tgt[4] = {pos[0], pos[1], pos[2], pos[3]};
        for (int i = 0; i < 3; i++)
            if (has & (1 << i))
                tgt[i] = flags[RELATIVE] ? pos[i] + value[i] * unit : value[i] * unit + off[i];
        if (has & (1 << E))  /* scaled by the flow (M221) */
            tgt[3] = flags[E_RELATIVE] ? pos[3] + value[E] * unit * state[FLOW]
                                       : (value[E] * unit + off[3]) * state[FLOW] + state[E_SHIFT];
        if ((has & (1 << F)) && value[F] <= 0.0)
            break;  /* an error: Python's */
        if ((has & (1 << S)) && (value[S] < 0.0 || flags[S_WATCHED]))
            break;
        const int moves = tgt[0] != pos[0] || tgt[1] != pos[1] || tgt[2] != pos[2] || tgt[3] != pos[3];
        int fixed_moves = 0;
        for (int i = 0; i < 4; i++)
            if ((flags[FIXED] & (1 << i)) && tgt[i] != pos[i])
                fixed_moves = 1;
        if (moves && fixed_moves)
            break;
        if (moves && beyond(state, pos, tgt, mode, (has & (1 << F)) ? value[F] * unit / 60.0 : -1.0, flags[HAS_FEED]))
            break;  /* an error: Python's */
        /* the line is ours */
        taken++;
        if (has & (1 << F)) {
            state[FEED] = value[F] * unit / 60.0;
            flags[HAS_FEED] = 1;
        }
        if (has & (1 << S)) {
            const double p = value[S] / state[S_FULL];
            state[POWER] = 1.0 < p ? 1.0 : p;
        }
        flags[MODE] = mode;
        if (!moves)
            continue;
        const int extrudes = tgt[3] != pos[3];
        const double speed = move_speed(state, mode, -1.0, flags[HAS_FEED], extrudes);
        double a = state[ACCEL_PRINT];
        if (!extrudes)
            a = state[ACCEL_TRAVEL];
        else if (tgt[0] == pos[0] && tgt[1] == pos[1] && tgt[2] == pos[2])
            a = state[ACCEL_RETRACT];
        for (int i = 0; i < 4; i++)
            end[made * 4 + i] = pos[i] = tgt[i];
        feed[made] = speed;
        accel[made] = a;
        power[made] = state[POWER];
        rapid[made] = mode == 0;
        line[made] = k;
        indent[made] = margin;
        made++;
    }
    *at = k;
    *blocks = taken;
    return made - first_made;
}
