"""Validate a job file read by codegen/job/reading.py: `translate` turns pydantic's errors into diagnostics at
the file's positions, in plain words; `cross_check` adds the checks that span several keys.
`codegen.job.load_job` puts it together.
"""

from __future__ import annotations

from codegen.errors import Diagnostic, closest, suggest
from codegen.job.reading import Marks, YPath, dotted
from codegen.job.schema import (DEFAULT_MAX_TEMP_C, HEATERS, MOTORS, REQUIRED_MOTORS, SHAPED_AXES, SHAPES, AxisShaper,
                                BangBang, Control, CustomSensor, Delta, Heater, Homing, InputShaper, Job, Jog, Link,
                                Machine, PidGains, PlantOverrides, PressureAdvance, Program, Stepper)

# ---- validation: every problem of the file, as diagnostics ----

_CUSTOM = {"number", "text", "flag", "enum", "point", "sweep", "range", "rod", "length", "expr", "interval",
           "name", "shape", "sensor", "control"}
_PLAIN = {
    "model_type": "expected a mapping", "model_attributes_type": "expected a mapping",
    "dict_type": "expected a mapping", "list_type": "expected a list", "tuple_type": "expected a list",
    "string_type": "expected a string", "bool_type": "expected true or false",
    "bool_parsing": "expected true or false", "float_type": "expected a number",
    "float_parsing": "expected a number", "int_type": "expected a number", "finite_number": "expected a number",
}
_BOUNDS = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}


def _prefix(path: YPath) -> str:
    return f"{dotted(path)}: " if path else ""


def _yaml_path(loc: tuple) -> YPath:
    """A pydantic location as a YAML path (the list of a `points` shape is wrapped as {'points': [...]})."""
    if len(loc) >= 5 and loc[:2] == ("program", "shapes") and loc[3:5] == ("points", "points"):
        return loc[:4] + loc[5:]
    if len(loc) >= 5 and loc[:2] == ("machine", "heaters") and loc[3] == "sensor" and loc[4] in ("preset", "custom"):
        return loc[:4] + loc[5:]  # the sensor union's tag
    return tuple(loc)


def _message(err: dict, path: YPath) -> str:
    kind, ctx = err["type"], err.get("ctx") or {}
    if kind in _CUSTOM:
        return err["msg"]
    if kind in _PLAIN:
        return _PLAIN[kind]
    if kind in _BOUNDS:
        limit = next(iter(ctx.values()), "")
        return f"must be {_BOUNDS[kind]} {limit:g}" if isinstance(limit, (int, float)) else err["msg"]
    if kind == "too_short":
        n = ctx.get("min_length", 1)
        what = "points" if path and path[-1] == "points" else "items"
        return "must not be empty" if n == 1 else f"expected at least {n} {what}"
    msg = err["msg"]
    return msg[:1].lower() + msg[1:]


def translate(errors: list[dict], marks: Marks) -> list[Diagnostic]:
    """Pydantic's errors as diagnostics at the right key or value, in the house wording."""
    out = []
    located = [(err, _yaml_path(err["loc"]) + tuple((err.get("ctx") or {}).get("at", ()))) for err in errors]
    # A misspelt required key is one mistake: "unknown key 'max_acel' (did you mean 'max_accel'?)" says it all.
    misspelt = {path[:-1] + (closest(str(path[-1]), known_keys(path[:-1]) or ()),)
                for err, path in located if err["type"] == "extra_forbidden"}
    for err, path in located:
        kind, ctx = err["type"], err.get("ctx") or {}
        if kind == "missing":
            if path not in misspelt:
                out.append(Diagnostic(marks.mapping(path[:-1]), f"{_prefix(path[:-1])}missing key '{path[-1]}'"))
        elif kind == "extra_forbidden":
            keys = known_keys(path[:-1]) or ()
            hint = suggest(str(path[-1]), keys) or (f"; expected {', '.join(keys)}" if keys else "")
            out.append(Diagnostic(marks.key(path), f"{_prefix(path[:-1])}unknown key '{path[-1]}'{hint}"))
        elif kind == "expr":
            out.append(Diagnostic(marks.inside(path, int(ctx.get("offset", 0))), _prefix(path) + err["msg"]))
        else:
            if ctx.get("where") == "key":  # a problem with the key itself: reported against its mapping
                out.append(Diagnostic(marks.key(path), _prefix(path[:-1]) + _message(err, path)))
            else:
                out.append(Diagnostic(marks.value(path), _prefix(path) + _message(err, path)))
    return out


# A problem found by a cross-key check, with paths relative to the checked mapping:
# (path the message is about, message, path to point at, 'key' | 'value' | 'mapping' (a key missing there)).
Issue = tuple[tuple, str, tuple, str]


def machine_issues(m: dict) -> list[Issue]:
    """Motors against the kinematics; heater names; `delta:` exactly when the kinematics is delta."""
    kin = m.get("kinematics")
    if not isinstance(kin, str) or kin not in MOTORS:  # a wrong value or type: the schema reports it
        return []
    issues: list[Issue] = []
    steppers = m.get("steppers")
    if isinstance(steppers, dict):
        allowed = MOTORS[kin]
        for name in steppers:
            if name not in allowed:
                hint = suggest(str(name), allowed) or f"; {kin} motors are {', '.join(allowed)}"
                message = f"unknown motor '{name}' for {kin} kinematics{hint}"
                issues.append((("steppers",), message, ("steppers", name), "key"))
        for name in REQUIRED_MOTORS[kin]:
            if name not in steppers:
                message = f"missing motor '{name}' (required for {kin} kinematics)"
                issues.append((("steppers",), message, ("steppers",), "key"))
    heaters = m.get("heaters")
    if isinstance(heaters, dict):
        for name in heaters:
            if name not in HEATERS:
                hint = suggest(str(name), HEATERS) or f"; heaters are {', '.join(HEATERS)}"
                issues.append((("heaters",), f"unknown heater '{name}'{hint}", ("heaters", name), "key"))
            elif isinstance(heaters[name], dict):
                issues += _temperature_order(name, heaters[name])
    if kin == "delta" and "delta" not in m:
        issues.append(((), "missing key 'delta' (required for delta kinematics)", (), "mapping"))
    elif kin == "delta" and m["delta"] is None:
        issues.append((("delta",), "expected a mapping (required for delta kinematics)", ("delta",), "value"))
    elif kin != "delta" and m.get("delta") is not None:
        issues.append((("delta",), "only allowed with kinematics: delta", ("delta",), "key"))
    if isinstance(m.get("jog"), dict) and isinstance(steppers, dict):
        issues += _jog_issues(kin, steppers, m["jog"])
    if m.get("pressure_advance") is not None and isinstance(steppers, dict) and "e" not in steppers:
        issues.append((("pressure_advance",), "pressure advance needs an extruder (motor 'e')", ("pressure_advance",),
                       "key"))
    return issues


def _jog_issues(kin: str, steppers: dict, jog: dict) -> list[Issue]:
    """Jog keys move x and y (cartesian x, y; corexy a, b), every moving motor at one step rate: their
    steps_per_mm agree, and no jog speed is above a jogged motor's max_velocity."""
    if kin == "delta":
        return [(("jog",), "jog keys need cartesian or corexy kinematics", ("jog",), "key")]
    jogged = [steppers.get(name) for name in REQUIRED_MOTORS[kin]]
    if not all(isinstance(s, dict) for s in jogged):
        return []
    numbers = (lambda *v: all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v))
    spm = [s.get("steps_per_mm") for s in jogged]
    issues: list[Issue] = []
    if numbers(*spm) and spm[0] != spm[1]:
        a, b = REQUIRED_MOTORS[kin]
        issues.append((("jog",), f"jog keys step {a} and {b} at one rate: their steps_per_mm must agree "
                       f"({spm[0]:g}, {spm[1]:g})", ("jog",), "key"))
    amax, accel = [s.get("max_accel") for s in jogged], jog.get("accel")
    if numbers(accel, *amax) and accel > min(amax):
        issues.append((("jog", "accel"), f"{accel:g} mm/s^2 is above the jogged motors' max_accel ({min(amax):g})",
                       ("jog", "accel"), "value"))
    vmax = [s.get("max_velocity") for s in jogged]
    speeds = jog.get("speeds")
    if numbers(*vmax) and isinstance(speeds, list):
        for i, speed in enumerate(speeds):
            if numbers(speed) and speed > 60 * min(vmax):
                issues.append((("jog", "speeds", i), f"{speed:g} mm/min is above the jogged motors' max_velocity "
                               f"({min(vmax):g} mm/s = {60 * min(vmax):g} mm/min)", ("jog", "speeds", i), "value"))
    return issues


def _temperature_order(name: str, heater: dict) -> list[Issue]:
    """min_temp_c below max_temp_c, either of them given or the heater's default."""
    low = heater.get("min_temp_c", Heater.model_fields["min_temp_c"].default)
    high = heater.get("max_temp_c", DEFAULT_MAX_TEMP_C[name])
    numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (low, high))
    if not numbers or low < high:
        return []
    at = ("heaters", name, "min_temp_c" if "min_temp_c" in heater else "max_temp_c")
    return [(at, f"min_temp_c ({low:g}) must be below max_temp_c ({high:g})", at, "value")]


def program_issues(p: dict) -> list[Issue]:
    """Exactly one of `shapes` and `gcode`."""
    given = [k for k in ("shapes", "gcode") if k in p]
    empty = {"shapes": "expected a list of shapes", "gcode": "expected a file name or G-code"}
    issues: list[Issue] = [((k,), empty[k], (k,), "value") for k in given if p[k] is None]
    if len(given) == 2:
        issues.append(((), "give either 'shapes' or 'gcode', not both", ("gcode",), "key"))
    elif not given:
        issues.append(((), "missing key 'shapes' or 'gcode'", (), "mapping"))
    return issues


def known_keys(path: tuple) -> tuple[str, ...] | None:
    """The keys allowed in the mapping at a YAML path (for "did you mean"); None when not a model."""
    model = {
        (): Job, ("machine",): Machine, ("machine", "delta"): Delta, ("machine", "link"): Link,
        ("machine", "homing"): Homing, ("machine", "jog"): Jog, ("program",): Program,
        ("machine", "input_shaper"): InputShaper, ("machine", "pressure_advance"): PressureAdvance,
    }.get(tuple(path))
    if model is None and len(path) == 3 and path[:2] == ("machine", "input_shaper") and path[2] in SHAPED_AXES:
        model = AxisShaper
    if model is None and len(path) == 3 and path[:2] == ("machine", "steppers"):
        model = Stepper
    if model is None and len(path) >= 3 and path[:2] == ("machine", "heaters"):
        model = {(): Heater, ("sensor",): CustomSensor, ("control",): Control, ("control", "pid"): PidGains,
                 ("control", "bang_bang"): BangBang, ("plant",): PlantOverrides}.get(tuple(path[3:]))
    if model is None and len(path) == 4 and path[:2] == ("program", "shapes") and path[3] in SHAPES:
        model = SHAPES[path[3]]
    if model is None:
        return None
    return tuple(f.alias or name for name, f in model.model_fields.items())


def cross_check(data: dict, marks: Marks) -> list[Diagnostic]:
    """The checks that span several keys, over the YAML data (they run even when other values are wrong)."""
    out = []
    for key, check in (("machine", machine_issues), ("program", program_issues)):
        if isinstance(data.get(key), dict):
            for about, message, at, where in check(data[key]):
                locate = {"mapping": marks.mapping, "key": marks.key, "value": marks.value}[where]
                out.append(Diagnostic(locate((key,) + at), _prefix((key,) + about) + message))
    return out
