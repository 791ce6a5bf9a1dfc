"""What the G-code front end knows about codes: names, modal groups, parameters, and the harmless ones.

A code's name is its letter and number without leading zeros: `G01` is `G1`, `G38.2` stays `G38.2`,
`M862.3` stays `M862.3`. Modal groups follow Grbl (NIST RS274NGC); the 3D-printer M-codes (M104, M201, ...)
share one group, "M command", so at most one of them stands on a line (their parameters would clash).
"""

from __future__ import annotations

MOTION = ("G0", "G1", "G2", "G3")
PLANES = {"G17": (0, 1), "G18": (2, 0), "G19": (1, 2)}  # (u, v) axes of the arc plane: XY, ZX, YZ
PLANE_NAMES = {(0, 1): "XY", (2, 0): "ZX", (1, 2): "YZ"}
AXIS_LETTERS = "XYZE"

GROUPS = {
    **{c: "motion" for c in (*MOTION, "G38.2", "G38.3", "G38.4", "G38.5", "G80", "G81", "G82", "G83")},
    **{c: "non-modal" for c in ("G4", "G10", "G28", "G28.1", "G30", "G30.1", "G53", "G92", "G92.1")},
    **{c: "plane" for c in PLANES},
    "G90": "distance", "G91": "distance",
    "G90.1": "arc distance", "G91.1": "arc distance",
    "G93": "feed rate mode", "G94": "feed rate mode",
    "G20": "units", "G21": "units",
    "G40": "cutter compensation",
    "G43.1": "tool length offset", "G49": "tool length offset",
    **{c: "coordinate system" for c in ("G54", "G55", "G56", "G57", "G58", "G59")},
    "G61": "path control", "G64": "path control",
    "M0": "stopping", "M1": "stopping", "M2": "stopping", "M30": "stopping",
    "M3": "spindle", "M4": "spindle", "M5": "spindle",
    "M7": "coolant", "M8": "coolant", "M9": "coolant",
}


def group_of(name: str) -> str:
    group = GROUPS.get(name)
    if group is not None:
        return group
    return {"M": "M command", "T": "tool"}.get(name[0], name)


# The parameter letters each supported code takes (F and S are everybody's: the modal feed and the tool
# power, unless the line's code takes S itself; N is a line number).
PARAMS = {
    "G0": "XYZE", "G1": "XYZE", "G2": "XYZEIJKR", "G3": "XYZEIJKR",
    "G4": "PS",
    "G17": "", "G18": "", "G19": "", "G20": "", "G21": "", "G90": "", "G91": "", "G94": "",
    "G28": "XYZ", "G92": "XYZE",
    "M0": "PS", "M1": "PS", "M2": "", "M30": "", "M3": "", "M4": "", "M5": "", "M82": "", "M83": "",
    "M104": "ST", "M109": "SRT", "M140": "S", "M190": "SR",
    "M106": "SP", "M107": "P",
    "M201": "XYZE", "M203": "XYZE", "M204": "PRST", "M205": "XYZEJSTB", "M220": "SBR", "M221": "ST", "M400": "",
    "M593": "XYFD",
    "M900": "K", "M572": "DS",  # with machine.pressure_advance only (else harmless at K0/S0)
    # Grbl (codegen/gcode/grbl.py)
    "G10": "LPXYZ", "G53": "", "G28.1": "", "G30": "XYZ", "G30.1": "", "G92.1": "", "G93": "",
    "G43.1": "Z", "G49": "", "M7": "", "M8": "", "M9": "",
    **{f"G5{n}": "" for n in range(4, 10)},
}
SUPPORTED = frozenset(PARAMS)
# The letters a code takes without a number: G28's axes (`G28 X Y`, as Marlin), M593's, M220's B (save) and R.
BARE_LETTERS = {"G28": "XYZ", "M593": "XY", "M220": "BR"}
ADVANCE_CODES = frozenset({"M900", "M572"})  # pressure advance: supported where the job has machine.pressure_advance
AXIS_TAKERS = frozenset(c for c, p in PARAMS.items() if any(a in p for a in AXIS_LETTERS))

# Codes that change nothing this toolchain models: skipped with one warning each (errors with --strict).
HARMLESS = {
    "M73": "print progress",
    "M117": "display message",
    "M118": "host message",
    "M900": "linear advance off (K0), as without it",
    "M572": "pressure advance off (S0), as without it",
    "G29": "bed levelling; there is no probe",
    "M420": "bed levelling state",
    "T": "tool select; the machine has one tool",
    "M6": "tool change; the machine has one tool",
    "G64": "path blending; corners always blend by the junction deviation",
    "M84": "motors off",
    "M18": "motors off",
    "M17": "motors on",
    "G80": "cancel canned cycle; there are none",
    "G40": "cutter compensation off, the only mode",
    "G61": "exact path mode, the only one",
    "M105": "temperature report",
    "M114": "position report",
    "M115": "firmware info",
    "M500": "save settings",
    "M501": "restore settings",
    "M503": "report settings",
    "M862": "printer check",  # M862.1 nozzle, M862.3 model, M862.5 G-code level, ...
}
# The harmless codes that take no words but their own (G64's P and Q tolerances): the line's other words keep their
# meaning, as in Grbl and LinuxCNC (`G64 X5` moves in the modal motion). The others take every word of their line.
HARMLESS_TAKES = {"G40": "", "G61": "", "G64": "PQ", "G80": ""}
# Parameters of supported codes that are skipped the same way: (code, letter) -> why.
HARMLESS_PARAMS = {
    ("M205", "B"): "minimum segment time; Marlin applies it only while its move queue runs low",
}
# Codes whose argument is free text (the rest of the line), not words.
TEXT_CODES = frozenset({"M23", "M28", "M32", "M117", "M118", "M862"})


def family(name: str) -> str:
    """M862.3 -> M862: the codes listed by family in HARMLESS and TEXT_CODES."""
    dot = name.find(".")
    return name if dot < 0 else name[:dot]


def harmless_reason(name: str) -> str | None:
    if name[0] == "T":  # any tool number: Marlin skips a tool change on a one-tool machine
        return HARMLESS["T"]
    return HARMLESS.get(name) or (HARMLESS.get(family(name)) if name.startswith("M862.") else None)


PROBES = frozenset({"G38.2", "G38.3", "G38.4", "G38.5"})


_names: dict[tuple[str, str], str | None] = {}


LARGEST_CODE = 1e6  # a code number beyond names no code


def code_name(letter: str, number: str) -> str | None:
    """`G`, `01` -> `G1`; `G`, `38.2` -> `G38.2`; None for a number that names no code (`G1.25`, `G-1`)."""
    key = (letter, number)
    try:
        return _names[key]
    except KeyError:
        pass
    value = float(number)
    if not abs(value) < LARGEST_CODE:  # nan and inf too: G followed by 400 nines, G-999...
        return None
    tenths = round(value * 10.0)
    name = None
    if value >= 0.0 and abs(value * 10.0 - tenths) < 1e-6:
        name = f"{letter}{tenths // 10}" + (f".{tenths % 10}" if tenths % 10 else "")
    if len(_names) < 10_000:
        _names[key] = name
    return name
