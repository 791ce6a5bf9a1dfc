"""The printer codes of the interpreter: heaters and fan (Output), limits (Limits), M204 accelerations, M205
least feed rates, M220 feed rate factor, M221 flow, G4, M400, M900 / M572 pressure advance (a Limits item); M593 in
codegen/gcode/shaper_codes.py.

Each handler takes the interpreter, the block and the line's parameters ({letter: value}); it returns False
when the code is in error (the line then does nothing). Values follow Marlin: M201 mm/s^2, M203 mm/s,
M204 mm/s^2, M205 X/Y/Z/E mm/s and J mm, all in the current units (G20 scales them like lengths); heater
targets in degrees C; fan S over 0..255.
"""

from __future__ import annotations

from codegen.gcode.shaper_codes import input_shaping
from codegen.toolpath.items import Dwell, Limits, Output
from codegen.toolpath.limits import dwell_error
from codegen.toolpath.segments import WAIT_REST_S

FAN_FULL_SCALE = 255.0


def _number(it, block, params, letter: str, minimum: float = 0.0, strict: bool = True) -> float:
    """The value of `letter`; an error (the handler then returns False) when it is out of range."""
    value = params[letter]
    if value < minimum or (strict and value == minimum):
        relation = ">" if strict else ">="
        it.fail(block, letter, f"'{it.word(block, letter)}' must be {relation} {minimum:g}")
        raise _Bad
    return value


class _Bad(Exception):
    pass


def _guarded(handler):
    def run(it, block, params):
        try:
            return handler(it, block, params)
        except _Bad:
            return False

    run.__name__ = handler.__name__
    run.__doc__ = handler.__doc__
    return run


def _only_zero(it, block, params, letter: str, what: str) -> None:
    """A tool or fan index: only 0 exists here."""
    if letter in params and params[letter] != 0.0:
        it.fail(block, letter, f"'{it.word(block, letter)}': the machine has one {what} ({letter}0)")
        raise _Bad


def _heater(name: str, wait: bool, tool_letter: str | None):
    @_guarded
    def heater(it, block, params):
        if tool_letter is not None:
            _only_zero(it, block, params, tool_letter, "hot end")
        letter = "S" if "S" in params else ("R" if wait and "R" in params else None)
        if letter is not None:
            value = _number(it, block, params, letter, strict=False)
            it.items.append(Output(name, value, wait, it.source(block)))
        return None

    return heater


@_guarded
def fan(it, block, params):
    """M106 [S0..255]: the fan at S/255 (full without S)."""
    _only_zero(it, block, params, "P", "fan")
    value = _number(it, block, params, "S", strict=False) / FAN_FULL_SCALE if "S" in params else 1.0
    it.items.append(Output("fan", min(value, 1.0), False, it.source(block)))
    return None


@_guarded
def fan_off(it, block, params):
    """M107: the fan off."""
    _only_zero(it, block, params, "P", "fan")
    it.items.append(Output("fan", 0.0, False, it.source(block)))
    return None


def _per_axis(it, block, params, strict: bool = True) -> dict[str, float] | None:
    values = {letter.lower(): _number(it, block, params, letter, strict=strict) * it.unit
              for letter in "XYZE" if letter in params}
    return values or None


def _axis_limits(it, block, params, field: str):
    values = _per_axis(it, block, params)
    if values:
        it.items.append(Limits(it.source(block), **{field: values}))
    return None


@_guarded
def max_accel(it, block, params):
    """M201 X Y Z E: largest acceleration per axis (mm/s^2)."""
    return _axis_limits(it, block, params, "max_accel")


@_guarded
def max_velocity(it, block, params):
    """M203 X Y Z E: largest velocity per axis (mm/s, Marlin's unit)."""
    return _axis_limits(it, block, params, "max_velocity")


@_guarded
def accelerations(it, block, params):
    """M204 P (moves that extrude) T (travel) R (E-only) S (P and T): the moves' acceleration caps."""
    values = {letter: _number(it, block, params, letter) * it.unit for letter in "SPTR" if letter in params}
    if "S" in values:
        it.accel_print = it.accel_travel = values["S"]
    if "P" in values:
        it.accel_print = values["P"]
    if "T" in values:
        it.accel_travel = values["T"]
    if "R" in values:
        it.accel_retract = values["R"]
    return None


@_guarded
def jerk(it, block, params):
    """M205 X Y Z E (jerk, mm/s), J (junction deviation, mm), S and T (Marlin's least feed rate of the moves
    that extrude and of the others, mm/s: a slower move runs at it); B is skipped by the interpreter."""
    if "S" in params:
        it.min_feed = _number(it, block, params, "S", strict=False) * it.unit
    if "T" in params:
        it.min_travel_feed = _number(it, block, params, "T", strict=False) * it.unit
    values = _per_axis(it, block, params, strict=False)
    deviation = _number(it, block, params, "J") * it.unit if "J" in params else None
    if values or deviation is not None:
        it.items.append(Limits(it.source(block), jerk=values, junction_deviation=deviation))
    return None


@_guarded
def flow(it, block, params):
    """M221 S (percent): the extruder's moves from here on are scaled by S/100, as Marlin and Klipper do
    (the program's E stays as written; the machine's E position moves on continuously)."""
    _only_zero(it, block, params, "T", "extruder")
    if "S" in params:
        new = _number(it, block, params, "S") / 100.0
        program_e = (it.pos[3] - it.e_shift) / it.flow
        it.flow, it.e_shift = new, it.pos[3] - new * program_e
    return None


@_guarded
def feed_factor(it, block, params):
    """M220 S (percent): every move's feed rate from here on times S/100, as Marlin and Klipper do; B saves
    the factor, R restores the saved one (Marlin, in that order, before S)."""
    if "B" in params:
        it.saved_speed_factor = it.speed_factor
    if "R" in params:
        it.speed_factor = it.saved_speed_factor
    if "S" in params:
        it.speed_factor = _number(it, block, params, "S") / 100.0
    return None


@_guarded
def dwell(it, block, params):
    """G4 P (ms in Marlin, s in Grbl: codegen/gcode/dialect.py) or S (s; S wins when both are given); no wait
    without either. G4 P0 waits no time but for the moves to finish, as Marlin, Grbl and Klipper do: the plan
    comes to rest there (a rest of WAIT_REST_S)."""
    if "S" in params:
        seconds = _number(it, block, params, "S", strict=False)
    elif "P" in params:
        seconds = _number(it, block, params, "P", strict=False) * it.dwell_p_seconds(block)
    else:
        return None
    if (message := dwell_error(seconds)) is not None:
        letter = "S" if "S" in params else "P"
        it.fail(block, letter, f"'{it.word(block, letter)}': {message}")
        return False
    it.items.append(Dwell(seconds if seconds > 0.0 else WAIT_REST_S, it.source(block)))
    return None


def _set_advance(it, block, params, letter: str):
    if letter in params:
        it.items.append(Limits(it.source(block), advance=_number(it, block, params, letter, strict=False)))
    return None


@_guarded
def linear_advance(it, block, params):
    """M900 K (Marlin's linear advance, here Klipper's smooth pressure advance: s, mm per mm/s): K from this line
    on (machine.pressure_advance has the smoothing time); without K nothing changes."""
    return _set_advance(it, block, params, "K")


@_guarded
def pressure_advance(it, block, params):
    """M572 D0 S (RepRapFirmware): K = S from this line on; D names the extruder (only 0 here; none: 0)."""
    _only_zero(it, block, params, "D", "extruder")
    return _set_advance(it, block, params, "S")


def advance_refused(it, block, name: str, params) -> tuple[int, str] | None:
    """Without machine.pressure_advance, M900 and M572 are harmless at K 0 (off) only: the problem (its word's
    index and message) of another K; None: none."""
    letter = {"M900": "K", "M572": "S"}.get(name)
    if letter is None or params.get(letter, 0.0) == 0.0:
        return None
    return it.word_index(block, letter), (f"'{name} {it.word(block, letter)}': pressure (linear) advance needs "
                                          f"machine.pressure_advance in the job; without it only {letter}0 (off)")


def finish_moves(it, block, params):
    """M400 (Marlin): waits for the moves to finish, so the plan comes to rest there (a rest of WAIT_REST_S)."""
    it.items.append(Dwell(WAIT_REST_S, it.source(block)))
    return None


def pause(it, block, params, name: str) -> None:
    """M0 / M1 (Grbl's and Marlin's program pause; M1 as M0: there is no optional stop switch): the plan comes to
    rest and the player waits for the resume key. With P (ms) or S (s), Marlin's timed form: a dwell."""
    if "S" in params or "P" in params:
        return dwell(it, block, params)
    if not it.pausable:
        it.fail(block, name, f"{name} waits for the resume key: the machine needs feed_hold (its hold keys or "
                             "the link's RESUME; the ATmega2560's images and the 8051's flash image have it)")
        return None
    it.items.append(Output("pause", 0.0, True, it.source(block)))
    return None


HANDLERS = {
    "M104": _heater("hotend", False, "T"),
    "M109": _heater("hotend", True, "T"),
    "M140": _heater("bed", False, None),
    "M190": _heater("bed", True, None),
    "M106": fan,
    "M107": fan_off,
    "M201": max_accel,
    "M203": max_velocity,
    "M204": accelerations,
    "M205": jerk,
    "M220": feed_factor,
    "M221": flow,
    "M400": finish_moves,
    "M593": input_shaping,
    "M900": linear_advance,
    "M572": pressure_advance,
}
