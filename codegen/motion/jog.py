"""Jog keys, the host's half: the ramp table the firmware plays while a jog key is held, the motors each key
moves, and the board's key wiring (`jog_keys:` in targets/<board>.yaml).

Jog mode comes at power-up, before homing and the table: hold a direction key to move, release it to stop,
speed+ and speed- change the level (`machine.jog.speeds`, mm/min, slowest first; the firmware starts at the
slowest), start ends jog mode and the job begins. The job then starts where jogging left the tool: that point
is `program.start` (on a machine that homes, homing comes after jog mode and sets the coordinates anyway).

Eight directions in the x-y plane; every motor that moves steps at every jog event, at one step rate (a
diagonal moves x and y at that rate each on a cartesian machine; on a corexy x alone moves both belts, a
diagonal one belt). The step rate comes from a ramp table of intervals: from rest the k-th interval is
RAMP[k] (constant acceleration: step k at sqrt(2 k / A)), until an interval would be shorter than the
level's cruise interval; then the cruise interval. Stopping (release, another direction, a slower level)
goes down the same table, so deceleration mirrors acceleration, and a new direction starts from rest. The
firmware only looks entries up (integers, no division, no square root). Limits: the step rate stays within
RATE_HEADROOM of the jogged motors' smallest max_velocity x steps_per_mm, the acceleration within
ACCEL_HEADROOM of the smallest max_accel (or `jog.accel`, never above it).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from codegen.errors import BuildError
from codegen.kinematics.base import StepperLimits

# The keys' functions, in the order of their bits in the firmware's key mask.
DIRECTIONS = {"x+": (1, 0), "x-": (-1, 0), "y+": (0, 1), "y-": (0, -1),
              "x+y+": (1, 1), "x-y+": (-1, 1), "x-y-": (-1, -1), "x+y-": (1, -1)}
FUNCTIONS = ("speed+", "speed-", "start")
KEYS = tuple(DIRECTIONS) + FUNCTIONS
REQUIRED_KEYS = ("x+", "x-", "y+", "y-") + FUNCTIONS  # the diagonals may be x+ with y+ held together
# The jogged motors and each one's share of (x, y): its step sign is the sign of cx * dx + cy * dy.
JOGGED = {"cartesian": {"x": (1, 0), "y": (0, 1)}, "corexy": {"a": (1, 1), "b": (1, -1)}}
RATE_HEADROOM = 0.98  # of the motors' step rate limit: a pulse may come a cycle early
ACCEL_HEADROOM = 0.95  # of their acceleration limit: intervals are whole ticks
MAX_TICKS = 0xFFFF  # intervals are 16-bit
STILL = 4  # the direction code of no motion: (dx + 1) * 3 + (dy + 1) with dx = dy = 0


def direction_code(dx: int, dy: int) -> int:
    """The firmware's direction code 0..8 of a step direction (dx, dy), each -1, 0 or 1."""
    return (dx + 1) * 3 + (dy + 1)


@dataclass(frozen=True)
class JogPlan:
    """What the firmware's jog mode plays (timer ticks at `tick_hz`)."""

    motors: tuple[int, ...]  # indices of the jogged motors in the firmware's motor order
    signs: tuple[tuple[int, ...], ...]  # per direction code 0..8: each jogged motor's step sign (-1, 0, 1)
    speeds: tuple[int, ...]  # mm/min of each level (as the display shows them)
    cruise: tuple[int, ...]  # ticks between steps at each level's speed
    top: tuple[int, ...]  # per level: how many ramp entries it climbs before it cruises
    ramp: tuple[int, ...]  # ticks from step k to step k + 1 from rest
    tick_hz: int
    steps_per_mm: float
    max_rate: float  # steps/s each jogged motor may make (its limit, before the headroom)
    max_accel: float  # steps/s^2 (the jog's acceleration, before the headroom)
    keys: str | None  # matrix | direct: which of the board's `jog_keys` the firmware scans; None: the board's one


@dataclass(frozen=True)
class JogSettings:
    """`machine.jog` and the limits of the machine's steppers."""

    kinematics: str  # cartesian | corexy: which motors jog (JOGGED)
    speeds: tuple[float, ...]  # mm/min of each level, slowest first
    accel: float | None  # mm/s^2; None: the jogged motors' smallest max_accel
    keys: str | None  # matrix | direct; None: the kind the board has
    steppers: Mapping[str, StepperLimits]  # every stepper's, by name


def jog_plan(jog: JogSettings, motor_names: tuple[str, ...], tick_hz: int) -> JogPlan:
    """The ramp and cruise intervals of `machine.jog` for a firmware whose motors are `motor_names`;
    BuildError for a level the 16-bit intervals cannot hold."""
    shares = JOGGED[jog.kinematics]
    steppers = [jog.steppers[name] for name in shares]
    spm = steppers[0].steps_per_mm
    max_rate = min(s.max_velocity for s in steppers) * spm
    max_accel = min([s.max_accel for s in steppers] + ([jog.accel] if jog.accel else [])) * spm
    rates = np.minimum(np.array(jog.speeds) / 60.0 * spm, max_rate * RATE_HEADROOM)
    cruise = np.ceil(tick_hz / rates - 1e-9).astype(np.int64)
    if cruise.max() > MAX_TICKS:
        slow = jog.speeds[int(np.argmax(cruise))]
        raise BuildError(f"machine.jog: {slow:g} mm/min is too slow for the jog timer: {int(cruise.max())} ticks "
                         f"between steps, at most {MAX_TICKS} (the slowest speed is "
                         f"{60 * tick_hz / MAX_TICKS / spm:.3g} mm/min)")
    accel = max_accel * ACCEL_HEADROOM
    # Enough entries that the last one is at or below the fastest cruise interval: v^2 = 2 A k.
    need = int(math.ceil((tick_hz / cruise.min()) ** 2 / (2 * accel))) + 2
    t = np.sqrt(2.0 * np.arange(need + 1) / accel)
    ramp = np.ceil(np.diff(t) * tick_hz - 1e-9).astype(np.int64)
    top = np.array([int(np.count_nonzero(ramp > c)) for c in cruise])
    ramp = ramp[: int(top.max())]
    if len(ramp) and ramp[0] > MAX_TICKS:
        raise BuildError(f"machine.jog: an acceleration of {max_accel / spm:g} mm/s^2 is too low for the jog timer: "
                         f"the first step takes {int(ramp[0])} ticks, at most {MAX_TICKS}")
    jogged = tuple(motor_names.index(name) for name in shares)
    signs = []
    for code in range(9):
        dx, dy = code // 3 - 1, code % 3 - 1
        signs.append(tuple(int(np.sign(cx * dx + cy * dy)) for cx, cy in shares.values()))
    return JogPlan(motors=jogged, signs=tuple(signs), speeds=tuple(int(round(s)) for s in jog.speeds),
                   cruise=tuple(int(c) for c in cruise), top=tuple(int(k) for k in top),
                   ramp=tuple(int(r) for r in ramp), tick_hz=tick_hz, steps_per_mm=spm, max_rate=max_rate,
                   max_accel=max_accel, keys=jog.keys)


def check_jog_rate(plan: JogPlan, tick_hz: int, event_ticks: int, mcu: str) -> None:
    """BuildError when a jog speed needs steps closer than the MCU's jog loop makes them (`event_ticks`)."""
    fastest = min(plan.cruise)
    if fastest < event_ticks:
        top_speed = plan.speeds[plan.cruise.index(fastest)]
        most = math.floor(tick_hz / event_ticks * 60 / plan.steps_per_mm)
        raise BuildError(f"machine.jog: {top_speed} mm/min needs a step every {fastest} ticks; the {mcu}'s "
                         f"jog loop needs {event_ticks}: at most {most} mm/min")


@dataclass(frozen=True)
class KeyWiring:
    """The board's jog keys: each function's key, a key to ground read through a pull-up (pressed reads low).
    A matrix drives one row low at a time and reads the columns; direct keys are read each on its pin."""

    kind: str  # matrix | direct
    keys: dict  # function -> (row, col) in a matrix, or its pin (direct)
    rows: tuple = ()  # a matrix's row pins (driven low one at a time) ...
    cols: tuple = ()  # ... and its column pins (read)

    def pins(self) -> tuple:
        return self.rows + self.cols if self.kind == "matrix" else tuple(self.keys.values())


def board_keys(board_name: str, board: dict, kind: str | None, parse_pin: Callable, taken: dict[str, str]
               ) -> KeyWiring:
    """The board file's `jog_keys:` of `kind` (None: the one kind the board has); BuildError naming every problem.
    `parse_pin` reads the target's pin names, `taken` gives the pins the board uses otherwise (name -> what)."""
    section = board.get("jog_keys")
    where = f"board {board_name}: jog_keys"
    if not isinstance(section, dict) or not section:
        raise BuildError(f"board {board_name} has no jog keys (a `jog_keys:` entry with `matrix:` or `direct:`): "
                         f"jog mode needs them")
    unknown = sorted(set(section) - {"matrix", "direct"})
    if unknown:
        raise BuildError(f"{where}: unknown kind(s) {', '.join(map(str, unknown))} (matrix, direct)")
    if kind is None:
        if len(section) > 1:
            raise BuildError(f"{where}: the board has matrix and direct keys: say which in machine.jog.keys")
        kind = next(iter(section))
    if kind not in section:
        raise BuildError(f"{where}: the board has no {kind} keys (has {', '.join(section)})")
    spec = section[kind] if isinstance(section[kind], dict) else {}
    problems: list[str] = []
    if kind == "matrix":
        rows = tuple(parse_pin(p) for p in spec.get("rows") or [])
        cols = tuple(parse_pin(p) for p in spec.get("cols") or [])
        if not 1 <= len(rows) <= 8 or not 1 <= len(cols) <= 8:
            problems.append("a matrix needs `rows:` and `cols:`, 1 to 8 pins each")
        table = spec.get("keys") or {}
        keys = {}
        for name, at in table.items():
            ok = isinstance(at, list) and len(at) == 2 and all(isinstance(v, int) for v in at)
            if not ok or not (0 <= at[0] < len(rows) and 0 <= at[1] < len(cols)):
                problems.append(f"key {name}: expected [row, col] within the {len(rows)} x {len(cols)} matrix")
                continue
            keys[str(name)] = tuple(at)
        places = list(keys.values())
        problems += [f"keys {', '.join(n for n, a in keys.items() if a == p)} share the key {list(p)}"
                     for p in sorted(set(places)) if places.count(p) > 1]
        wiring = KeyWiring("matrix", keys, rows, cols)
    else:
        wiring = KeyWiring("direct", {str(name): parse_pin(pin) for name, pin in spec.items()})
    stray = [n for n in wiring.keys if n not in KEYS]
    problems += [f"unknown key function {n!r} (functions: {', '.join(KEYS)})" for n in stray]
    missing = [n for n in REQUIRED_KEYS if n not in wiring.keys]
    if missing:
        problems.append(f"missing key(s) {', '.join(missing)}")
    seen: dict[str, int] = {}
    for pin in wiring.pins():
        seen[pin.name] = seen.get(pin.name, 0) + 1
    problems += [f"{name} is used twice" for name, n in seen.items() if n > 1]
    problems += [f"{name} is already {taken[name]}" for name in seen if name in taken]
    if problems:
        raise BuildError(f"{where}.{kind}: " + "; ".join(problems))
    return wiring
