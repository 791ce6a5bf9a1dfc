"""A second reading of the job's G-code, written apart from codegen/gcode, for verify to hold the tables against:
where each line leaves the tool, how fast it may go there, the circle of each arc, how long each dwell lasts.

It follows the contract (JOB-FORMAT.md, Marlin's and Grbl's documentation), not the front end's code: G0-G3 (IJ and
R arcs in the three planes), G4 (S s; P ms in Marlin, s in Grbl: `program.dialect`, else the first line that only
one of them writes), G17-G19, G20/G21, G90/G91, G92/G92.1, G93/G94, F, M220 S/B/R and M205 S/T (a move's speed is F
times the M220 factor, at least M205's least feeds), Grbl's coordinate systems (G54-G59, G10 L2/L20, G53,
G43.1/G49), M2/M30, Grbl's `$H` (`$` lines move nothing else). A line's axis words move in the modal motion whatever
else it holds (G40, G64, M3 ...), but beside an M code that takes its own letters (M201 X). Homing (G28, G30, $H)
leaves its axes unknown until an absolute coordinate gives each again (homing clears their G92 offsets, going to a
G28.1 / G30.1 position keeps them); nothing about an unknown axis is checked.
Lines are read one at a time (`Reading.upto`), so a print of any length is held a line at a time.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

WORD = re.compile(r"([A-Z])\s*([+-]?(?:\d+\.?\d*|\.\d+))?")
COMMENT = re.compile(r"\([^)]*\)")
INCH_MM = 25.4
UNKNOWN = math.nan
HOMES = {"G28", "G30"}
SYSTEMS = {f"G{n}": n - 54 for n in range(54, 60)}
FREE_TEXT = {"M117", "M118", "M23", "M28", "M32"}  # the rest of the line is text, not words
TOOL_CODES = {"M3", "M4", "M5", "M7", "M8", "M9"}  # Grbl's spindle and coolant: the axis words on their line move
DIALECT_LINES = 2000  # how far into the file the dialect's deciding line is looked for
GRBL_ONLY = re.compile(r"^\$|G0*38\.|G0*10L0*20?(?![\d.])")  # on the code, upper case, without spaces
MARLIN_ONLY = re.compile(r"(?<![A-Z])(M0*(104|109|140|190|82|83|106)|G0*29)(?![\d.])")
PLANES = {"G17": (0, 1), "G18": (2, 0), "G19": (1, 2)}
OFFSETS = {(0, 1): "IJ", (2, 0): "KI", (1, 2): "JK"}
TEXT_CHARS = 48  # of a line's text in a message
FULL_CIRCLE_RAD = 1e-9  # an arc that turns less than this from its start to its end turns all the way round


@dataclass(frozen=True)
class Move:
    """One line's motion in machine mm (x, y, z; nan where unknown)."""

    line: int
    text: str  # the line as written (its start), for messages
    start: tuple[float, float, float]
    end: tuple[float, float, float]
    speed: float | None  # mm/s the move may not beat (None: G0, inverse time, or no F yet)
    arc: tuple | None = None  # (centre (u, v), radius, plane (u, v) axes, clockwise, sweep rad, end radius)
    offsets: tuple[float, float, float] = (0.0, 0.0, 0.0)  # mm where coordinate 0 is (G92, G54-G59, G43.1)

    def length(self, tolerance: float = 0.0) -> float:
        """mm along the path (nan with an unknown axis); with a `tolerance`, the least an arc's chords may add up to
        when each strays from its circle by no more than that (Grbl's $12: the firmware runs each chord at F)."""
        if self.arc is None:
            return math.dist(self.start, self.end)
        _, radius, plane, _, sweep, end_radius = self.arc
        along = [self.end[i] - self.start[i] for i in range(3) if i not in plane]
        flat = (radius + end_radius) / 2 * abs(sweep)  # a spiral (its radius even in the angle) is no shorter
        return math.hypot(flat * _chord_share(min(radius, end_radius), sweep, tolerance), math.hypot(*along))


@dataclass(frozen=True)
class Dwell:
    line: int
    text: str
    seconds: float


def gcode_lines(job) -> tuple[Iterator[str], int]:
    """The program's G-code lines (a file next to the job file, or the job's inline text) and the source line
    number of the first."""
    program = job.program
    path = Path(job.path).parent / program.gcode
    if "\n" not in program.gcode and path.is_file():
        return _file_lines(path), 1
    return iter(program.gcode.split("\n")), program.gcode_source.line


def grbl_dialect(job) -> bool:
    """Whether G4 P counts seconds: `program.dialect`, else the first of the first DIALECT_LINES lines that only Grbl
    (`$` lines, G38, G10 L2/L20, a comment naming Grbl) or Marlin (heaters, fan, M82/M83, G29, ;FLAVOR:Marlin)
    writes; neither: Marlin."""
    given = getattr(job.program, "dialect", None)
    if given is not None:
        return given == "grbl"
    lines, _ = gcode_lines(job)
    for _, text in zip(range(DIALECT_LINES), lines):
        code, _, comment = text.upper().partition(";")
        if "GRBL" in comment or ("FLAVOR" in comment and "MARLIN" in comment):
            return "GRBL" in comment
        code = COMMENT.sub(" ", code).replace(" ", "").replace("\t", "")
        if GRBL_ONLY.search(code) or MARLIN_ONLY.search(code):
            return GRBL_ONLY.search(code) is not None
    return False


def _file_lines(path: Path) -> Iterator[str]:
    with open(path, encoding="utf-8", errors="replace", newline="\n") as file:
        for text in file:
            yield text.rstrip("\r\n")


class Reading:
    """The program's moves and dwells in order of their lines, read as far as asked (`upto`)."""

    def __init__(self, job, start_mm):
        self.lines, self.number = gcode_lines(job)
        self.number -= 1  # the number of the line last read
        self.pos = [float(v) for v in start_mm[:3]]
        self.systems = [[0.0, 0.0, 0.0] for _ in SYSTEMS]  # G54 .. G59's origins
        self.system = 0
        self.g92 = [0.0, 0.0, 0.0]
        self.tool_length = 0.0  # G43.1's, on z
        self.unit, self.relative, self.inverse_time = 1.0, False, False
        self.plane = (0, 1)
        self.motion = "G0"
        self.feed = float(job.program.feed) / 60.0  # mm/s
        self.grbl = grbl_dialect(job)
        self.p_seconds = 1.0 if self.grbl else 0.001  # G4 P's unit
        self.factor, self.saved_factor, self.least = 1.0, 1.0, 0.0  # M220's; the larger of M205 S and T
        self.delimited, self.ended = False, False
        self.text = ""  # the line being read
        self.stored: set[str] = set()  # G28 / G30 whose position G28.1 / G30.1 stored (Grbl's)
        self.delta = job.machine.kinematics == "delta"  # which homes all three axes at once

    def upto(self, last_line: int) -> Iterator[Move | Dwell]:
        """The moves and dwells of the lines not read yet, up to `last_line`."""
        while not self.ended and self.number < last_line:
            text = next(self.lines, None)
            self.number += 1
            if text is None:
                self.ended = True
                break
            yield from self._line(text)

    def _line(self, text: str) -> Iterator[Move | Dwell]:
        self.text = text.split(";", 1)[0].strip()[:TEXT_CHARS]
        code = text.split(";", 1)[0]
        code = COMMENT.sub(lambda m: " " * len(m.group()), code).split("*", 1)[0].strip().upper()
        if code == "%":
            self.ended, self.delimited = self.delimited, True
            return
        if not code or code.startswith("/"):
            return
        if code.startswith("$"):  # Grbl's system commands: only $H (with the axes it names, or all) moves
            if code.startswith("$H"):
                for i in [i for i, letter in enumerate("XYZ") if letter in code[2:]] or [0, 1, 2]:
                    self.pos[i], self.g92[i] = UNKNOWN, 0.0
            return
        words = [(letter, number) for letter, number in WORD.findall(code)]
        if words and f"{words[0][0]}{_number(words[0][1])}" in FREE_TEXT:
            return
        codes = [f"{letter}{_number(number)}" for letter, number in words if letter in "GM"]
        params = {letter: float(number) for letter, number in words if letter not in "GMNT" and number}
        yield from self._run(codes, params, {letter for letter, _ in words})

    def _run(self, codes: list[str], params: dict[str, float], letters: set[str]) -> Iterator[Move | Dwell]:
        for code in codes:  # the modes first, as RS274 orders a line
            if code in ("G20", "G21"):
                self.unit = INCH_MM if code == "G20" else 1.0
            elif code in ("G90", "G91"):
                self.relative = code == "G91"
            elif code in ("G93", "G94"):
                self.inverse_time = code == "G93"
            elif code in PLANES:
                self.plane = PLANES[code]
            elif code in ("G0", "G1", "G2", "G3", "G80"):
                self.motion = code
        if "F" in params and not self.inverse_time and "M593" not in codes:  # M593's F is a frequency
            self.feed = params["F"] * self.unit / 60.0
        if "M220" in codes:  # B saves the factor, R restores it
            self.saved_factor = self.factor if "B" in letters else self.saved_factor
            self.factor = self.saved_factor if "R" in letters else params.get("S", 100 * self.factor) / 100.0
        if "M205" in codes:
            self.least = max(self.least, *(params.get(k, 0.0) * self.unit for k in "ST"))
        if "M2" in codes or "M30" in codes:
            self.ended = True
            return
        if "G4" in codes:
            seconds = params["S"] if "S" in params else params.get("P", 0.0) * self.p_seconds
            if seconds > 0:
                yield Dwell(self.number, self.text, seconds)
            return
        if self._offsets(codes, params, letters):
            return
        tool_change = "T" in letters or "M6" in codes  # Grbl runs the rest of the block; Marlin skips it
        if (any(c.startswith("M") and c not in TOOL_CODES and c != "M6" for c in codes) or
                not any(k in params for k in "XYZ") or (tool_change and not self.grbl)):
            return  # an M code's letters are its own; a move of E alone leaves x, y, z
        yield self._move(params, "G53" in codes)

    def _offsets(self, codes: list[str], params: dict[str, float], letters: set[str]) -> bool:
        """The codes that set where coordinates are, or home; True when one took the line's axis words."""
        given = [(i, params[letter] * self.unit) for i, letter in enumerate("XYZ") if letter in params]
        for code in codes:
            if code in SYSTEMS:
                self.system = SYSTEMS[code]
            elif code == "G43.1":
                self.tool_length = params.get("Z", 0.0) * self.unit
            elif code == "G49":
                self.tool_length = 0.0
            elif code == "G92.1":
                self.g92 = [0.0, 0.0, 0.0]
            elif code in ("G28.1", "G30.1"):
                self.stored.add(code[:3])
        if "G92" in codes:
            for i, value in given:
                self.g92[i] = self.pos[i] - value - self._base(i)
        elif "G10" in codes and params.get("L") in (2.0, 20.0):
            number = int(params.get("P", 0)) - 1
            origin = self.systems[self.system if number < 0 else number]
            for i, value in given:  # L2: the origin itself; L20: the origin that puts the tool at the value
                origin[i] = value if params["L"] == 2.0 else self.pos[i] - value - self.g92[i] - self._tool(i)
        elif HOMES.intersection(codes):
            # Homing (G28 with no stored position) clears the offsets of its axes, as Marlin; going to a stored
            # position (G28 after G28.1, G30) keeps them, as Grbl. Either way the axes are not followed from there.
            homes = "G28" in codes and "G28" not in self.stored
            named = [i for i, letter in enumerate("XYZ") if letter in letters]
            for i in [0, 1, 2] if not named or (homes and self.delta) else named:
                self.pos[i] = UNKNOWN
                self.g92[i] = 0.0 if homes else self.g92[i]
        else:
            return "G43.1" in codes or "G10" in codes
        return True

    def _tool(self, i: int) -> float:
        return self.tool_length if i == 2 else 0.0

    def _base(self, i: int) -> float:
        """Where coordinate 0 of axis i is before G92: the coordinate system's origin and the tool length."""
        return self.systems[self.system][i] + self._tool(i)

    def _move(self, params: dict[str, float], machine: bool) -> Move:
        """A G0-G3 (`machine`: G53, in machine coordinates for this line)."""
        start = tuple(self.pos)
        end = list(start)
        for i, letter in enumerate("XYZ"):
            if letter in params:
                value = params[letter] * self.unit
                offset = 0.0 if machine else self._base(i) + self.g92[i]
                end[i] = start[i] + value if self.relative and not machine else value + offset
        speed = None if self.motion == "G0" or self.inverse_time else max(self.feed * self.factor, self.least)
        arc = _arc(self.motion, self.plane, start, end, params, self.unit) if self.motion in ("G2", "G3") else None
        self.pos = end
        offsets = tuple(self._base(i) + self.g92[i] for i in range(3))
        return Move(self.number, self.text, start, tuple(end), speed, arc, offsets)


def _number(text: str) -> str:
    """A code's number as its name writes it: G01 -> 1, G92.1 -> 92.1."""
    if not text:
        return ""
    value = float(text)
    return str(int(value)) if value == int(value) else f"{value:g}"


def _chord_share(radius: float, sweep: float, tolerance: float) -> float:
    """The least share of an arc's length its chords may have: a chord turning 2a on the circle, its middle
    within `tolerance` of it (cos a >= 1 - tolerance / radius), is sin(a) / a of its arc, less the more it turns."""
    half = min(math.acos(max(1.0 - tolerance / radius, 0.0)) if radius > 0 else math.pi / 2, abs(sweep) / 2)
    return math.sin(half) / half if half > 0 else 1.0


def _arc(motion: str, plane: tuple[int, int], start, end, params: dict[str, float], unit: float) -> tuple | None:
    """(centre, radius, plane, clockwise, sweep, end radius) of a G2/G3 in `plane`; None with an unknown end in the
    plane. The radii are the start's and the end's distances from the centre: an end off the start's circle (as
    Grbl lets an I/J arc's be, by up to 0.1 % of the radius) is reached along a spiral, as LinuxCNC draws it; an
    R a little short of half the chord is the half circle on it."""
    u, v = plane
    (su, sv), (eu, ev) = (start[u], start[v]), (end[u], end[v])
    if any(math.isnan(c) for c in (su, sv, eu, ev)):
        return None
    clockwise = motion == "G2"
    if "R" in params:
        radius = params["R"] * unit
        du, dv = eu - su, ev - sv
        chord = math.hypot(du, dv) or math.inf  # the front end refuses an R arc that ends where it starts
        rise = math.sqrt(max(radius * radius - chord * chord / 4.0, 0.0)) / chord
        side = 1.0 if clockwise else -1.0  # clockwise: the centre right of the chord; R < 0: the longer arc
        side = -side if radius < 0 else side
        centre = (su + du / 2 + side * rise * dv, sv + dv / 2 - side * rise * du)
    else:
        letters = OFFSETS[plane]
        centre = (su + params.get(letters[0], 0.0) * unit, sv + params.get(letters[1], 0.0) * unit)
    a0 = math.atan2(sv - centre[1], su - centre[0])
    a1 = math.atan2(ev - centre[1], eu - centre[0])
    turn = ((a0 - a1) if clockwise else (a1 - a0)) % (2 * math.pi)
    if turn < FULL_CIRCLE_RAD:  # the same start and end: a whole circle
        turn = 2 * math.pi
    radii = math.hypot(su - centre[0], sv - centre[1]), math.hypot(eu - centre[0], ev - centre[1])
    return centre, radii[0], plane, clockwise, -turn if clockwise else turn, radii[1]
