"""Blocks -> Toolpath: a modal interpreter (Grbl's modal groups and order of execution, Marlin's printer codes).

State: the machine position (mm, [x, y, z, e]), the G92 offsets (machine = program + offset), units (G20/G21),
distance mode (G90/G91; E follows the last of G90, G91, M82, M83, as in Marlin 2), motion mode (G0 at the
start, as Grbl), arc plane, feed (mm/s), tool (M3/M4 on, M5 off) and power, and the M204 accelerations.
Within a line: units first, then F, S, the M-codes, G4, plane and distance modes, G28/G92, the motion, and
M2/M30 (after which nothing is read). A line with an error does nothing; up to MAX_ERRORS are collected.

Moves are kept as point indices while reading; at the end every point becomes a row of one read-only array
and each Arc/Home holds views of its rows (a move's start is the previous move's end), the lines one after
another one Lines item. Stretches of plain G0/G1 lines are read and run in C (codegen/gcode/fast.py) as `line`
runs them.
"""

from __future__ import annotations

import math

import codegen.gcode.mcodes as mcodes
import codegen.toolpath.limits as limits
from codegen.errors import Diagnostic
from codegen.gcode.codes import (ADVANCE_CODES, AXIS_LETTERS, AXIS_TAKERS, BARE_LETTERS, HARMLESS_PARAMS, MOTION,
                                 PARAMS, PLANES, PROBES, SUPPORTED, code_name, group_of, harmless_reason)
from codegen.gcode.diagnostics import Diagnostics, Stop
from codegen.gcode.dialect import Dialect, DialectState
from codegen.gcode.grbl import PROBE_REASON, SYSTEMS, GrblState, system_command
from codegen.gcode.moves import LINE, Moves
from codegen.gcode.reader import Block, Origin
from codegen.gcode.shaper_codes import ShaperState

_ORDER = ("G93", "G94", "M3", "M4", "M5", "M7", "M8", "M9", *mcodes.HANDLERS, "G4", *PLANES, *SYSTEMS, "G43.1",
          "G49", "G90", "G91", "M82", "M83", "G10", "G28.1", "G30.1", "G28", "G30", "G92", "G92.1")
_MOTION_CODES = {("G", n): "G" + n.lstrip("0") if n.strip("0") else "G0"
                 for n in ("0", "1", "2", "3", "00", "01", "02", "03")}
_LINEAR = {key: name for key, name in _MOTION_CODES.items() if name in ("G0", "G1")}
_ARC_CODES = {key: name for key, name in _MOTION_CODES.items() if name in ("G2", "G3")}
_ARC_LETTERS = frozenset("XYZEFSIJKR")
_FAST_INDEX = {letter: i for i, letter in enumerate("XYZEFS")}


class Interpreter(Moves, GrblState, Diagnostics, DialectState):
    def __init__(self, job, origin: Origin, strict: bool = False, dialect: Dialect = Dialect("marlin", None, "")):
        machine, program = job.machine, job.program
        self.motors = tuple(machine.motor_names)
        self.kinematics = getattr(machine, "kinematics", "cartesian")
        has_z = "z" in self.motors or self.kinematics == "delta"
        self.movable = (True, True, has_z, "e" in self.motors)
        self.fixed = tuple(i for i in range(4) if not self.movable[i])
        self.home_point = list(machine.home_point)  # x, y, z (mm) where G28 leaves the tool
        self.reach = limits.axis_reach(machine)  # mm, per axis: where a move may go
        start = [0.0] * 4
        start[: len(program.start)] = [float(v) for v in program.start]
        self.pos = start
        self.off = [0.0] * 4
        self.flow = 1.0  # M221: machine E = flow * (program E + offset) + e_shift
        self.e_shift = 0.0
        self.speed_factor = self.saved_speed_factor = 1.0  # M220
        self.min_feed = self.min_travel_feed = 0.0  # M205 S, T (mm/s)
        self.unit = 1.0
        self.relative = self.e_relative = False
        self.mode = "G0"
        self.plane = (0, 1)
        self.feed: float | None = None  # mm/s; None: no F so far
        self.draw_feed = float(program.feed) / 60.0
        travel = getattr(program, "travel_feed", None)
        self.rapid = math.inf if travel is None else float(travel) / 60.0
        self.spindle = False
        self.dynamic = False  # M4 (Grbl's laser mode: power follows the speed), else M3's constant power
        self.power = 1.0
        self.pausable = getattr(machine, "feed_hold", None) is not None  # a resume key for M0/M1
        self.advances = getattr(machine, "pressure_advance", None) is not None  # M900 and M572 set its K
        self.accel_print = self.accel_travel = self.accel_retract = math.inf
        self.shapers = ShaperState(machine)  # M593
        self.origin, self.strict = origin, strict
        self.flat = list(start)
        self.count, self.cur, self.base = 1, 0, 0
        self.items: list = []
        self.native = None  # the C's moves (codegen/gcode/fast.py), where it reads the plain lines
        self.errors: list[Diagnostic] = []
        self.warned: dict[str, list] = {}
        self.notes: list[Diagnostic] = []
        self.grbl_init()
        self.dialect_init(machine, program, dialect)

    # ---- results ----

    def run(self, block: Block | Diagnostic) -> bool:
        """Interpret a block (or report a line the reader refused); False once the program has ended or there
        are too many errors to go on."""
        try:
            if type(block) is Block:
                self.line(block)
            else:
                self._error(block.where, block.message)
        except Stop:
            return False
        return True

    # ---- one line ----

    def line(self, block: Block) -> None:
        """One line. The G0/G1 lines that make up most files take this short way; others go through
        `_common` (any single motion code) and `_general` (everything)."""
        words = block.words
        mode = _LINEAR.get(words[0])
        if mode is None or self.inverse_time:
            return self._common(block)
        values = [None] * 6  # X Y Z E F S
        index = _FAST_INDEX.get
        try:
            for letter, number in words[1:]:
                i = index(letter)
                if i is None:
                    return self._common(block)
                if values[i] is not None:
                    return self._general(block)  # a letter twice
                values[i] = float(number)
        except ValueError:  # a letter without a number
            return self._general(block)
        x, y, z, e, feed, power = values
        pos, unit, off = self.pos, self.unit, self.off
        tgt = pos[:]
        if self.relative:
            if x is not None:
                tgt[0] = pos[0] + x * unit
            if y is not None:
                tgt[1] = pos[1] + y * unit
            if z is not None:
                tgt[2] = pos[2] + z * unit
        else:
            if x is not None:
                tgt[0] = x * unit + off[0]
            if y is not None:
                tgt[1] = y * unit + off[1]
            if z is not None:
                tgt[2] = z * unit + off[2]
        if e is not None:  # scaled by the flow (M221)
            if self.e_relative:
                tgt[3] = pos[3] + e * unit * self.flow
            else:
                tgt[3] = (e * unit + off[3]) * self.flow + self.e_shift
        if feed is not None:
            if feed <= 0.0:
                return self.fail(block, "F", f"feed rate '{self.word(block, 'F')}' must be > 0")
            self.feed = feed * unit / 60.0
        if power is not None and self.set_power(block, {"S": power}) is False:
            return
        self.mode = mode
        if tgt == pos or (self.fixed and self.axis_missing(block, tgt)):
            return
        if mode == "G0":
            feed, tool = self.rapid, False
        else:
            feed, tool = self.draw_feed if self.feed is None else self.feed, self.spindle
        feed = self.speed(feed, tgt[3] != pos[3])
        if self.beyond_limits(block, tgt, feed):
            return
        if tgt[3] == pos[3]:
            accel = self.accel_travel
        elif tgt[0] == pos[0] and tgt[1] == pos[1] and tgt[2] == pos[2]:
            accel = self.accel_retract
        else:
            accel = self.accel_print
        self.flat.extend(tgt)
        start, self.cur = self.cur, self.count
        self.count += 1
        self.pos = tgt
        self.items.append((LINE, start, self.cur, feed, tool, self.origin.at(block.index, block.indent), mode,
                           accel, self.power, self.dynamic))

    def _common(self, block: Block) -> None:
        """A G2/G3 line of plain words (most of an arc file); anything else goes to `_general`."""
        words = block.words
        motion = _ARC_CODES.get(words[0])
        if motion is None or self.inverse_time:
            return self._general(block)
        params: dict[str, float] = {}
        for letter, number in words[1:]:
            if letter in params or letter not in _ARC_LETTERS or not number:
                return self._general(block)
            params[letter] = float(number)
        if "F" in params and self._feed(block, params) is False:
            return
        if "S" in params and self.set_power(block, params) is False:
            return
        self.mode = motion
        self.arc_move(block, motion, params)

    def _feed(self, block: Block, params) -> bool | None:
        value = params["F"]
        if value <= 0.0:
            self.fail(block, "F", f"feed rate '{self.word(block, 'F')}' must be > 0")
            return False
        self.feed = value * self.unit / 60.0
        return None

    def _general(self, block: Block) -> None:
        """Any line: codes by name and group, parameters by owner, every problem reported, then the codes."""
        words = block.words
        if words[0][0] == "$":
            return system_command(self, block)
        codes: list[tuple[str, int]] = []
        params: dict[str, float] = {}
        problems: list[tuple[int, str]] = []
        tool, bare = None, []
        for k, (letter, number) in enumerate(words):
            if not number:
                if letter in params or letter in bare:
                    problems.append((k, f"'{letter}' appears twice on this line"))
                else:
                    bare.append(letter)
                    params[letter] = 0.0
                continue
            if letter == "G" or letter == "M":
                name = code_name(letter, number)
                if name is None:
                    problems.append((k, f"'{letter}{number}' is not a code"))
                else:
                    codes.append((name, k))
            elif letter == "N":
                continue
            elif letter in params:
                problems.append((k, f"'{letter}' appears twice on this line"))
            else:
                params[letter] = float(number)
                if letter == "T":
                    tool = k
        if tool is not None and not any(name == "M6" or "T" in PARAMS.get(name, "") for name, _ in codes):  # M6's T
            del params["T"]
            name = code_name("T", words[tool][1])
            if name is None:
                problems.append((tool, f"'T{words[tool][1]}' is not a tool number"))
            else:
                codes.append((name, tool))
        for letter in bare:
            if not any(letter in BARE_LETTERS.get(name, "") for name, _ in codes):
                problems.append((self.word_index(block, letter), f"expected a number after '{letter}'"))
                del params[letter]
        motion, names = self._classify(block, codes, params, problems)
        for k, message in problems:
            self.fail(block, k, message)
        if problems or names is None:
            return
        if any(name == "G80" for name, _ in codes):
            self.mode = None  # until a G0..G3: axis words alone are an error meanwhile (Grbl's error 31)
        if "G20" in names:
            self.unit = 25.4
        elif "G21" in names:
            self.unit = 1.0
        inverse = ("G93" in names or self.inverse_time) and "G94" not in names
        if "G94" in names and self.inverse_time:
            self.feed = None  # back from G93 the feed rate is undefined until an F, as in Grbl: the job's feed
        if ("F" in params and not inverse and not any("F" in PARAMS[n] for n in names)
                and self._feed(block, params) is False):  # M593's F is a frequency
            return
        if "S" in params and not any("S" in PARAMS[n] for n in names) and self.set_power(block, params) is False:
            return
        if "G53" in names and motion not in ("G0", "G1"):
            return self.fail(block, "G53", "G53 (machine coordinates) moves only with G0 or G1")
        for name in _ORDER:
            if name in names and self._code(block, name, params) is False:
                return
        if motion is not None:
            self.mode = motion
            if motion != "G0" and self.inverse_time and self.inverse_time_feed(block, params) is False:
                return
            self._move(block, motion, params, machine="G53" in names)
            self.inverse_feed = None
        for name in ("M0", "M1"):  # the stopping group comes after the line's motion
            if name in names:
                mcodes.pause(self, block, params, name)
        if "M2" in names or "M30" in names:
            raise Stop

    def _move(self, block: Block, motion: str, params, machine: bool) -> None:
        """The line's motion; with G53 in absolute machine coordinates (X, Y, Z) for this move alone."""
        saved = self.off, self.relative
        if machine:
            self.off, self.relative = [0.0, 0.0, 0.0, self.off[3]], False
        try:
            if motion == "G0" or motion == "G1":
                self.line_move(block, motion, params)
            else:
                self.arc_move(block, motion, params)
        finally:
            if machine:
                self.off, self.relative = saved

    def _classify(self, block: Block, codes, params, problems):
        """Modal groups, supported and harmless codes, and which code takes each parameter. Returns the motion
        (explicit or modal) and the supported codes by name (None: the line does nothing more)."""
        names: dict[str, int] = {}
        groups: dict[str, str] = {}
        motion, taker, harmless, takes = None, None, [], []
        for name, k in codes:
            group = group_of(name)
            if group in groups:
                first = groups[group]
                problems.append((k, f"'{name}' twice on one line" if first == name else
                                 f"'{name}' and '{first}' on one line: both are in the {group} group"))
                continue
            groups[group] = name
            if name in PROBES:
                problems.append((k, f"'{name}' {PROBE_REASON}"))
            elif name in SUPPORTED and (name not in ADVANCE_CODES or self.advances):
                names[name] = k
                if name in MOTION:
                    motion = name
                elif name in AXIS_TAKERS:
                    taker = name
            elif (reason := harmless_reason(name)) is not None:
                harmless.append((name, k, reason))
            else:
                problems.append((k, f"unsupported G-code '{name}'"))
        if motion is not None and taker is not None:
            problems.append((max(names[motion], names[taker]),
                             f"'{motion}' and '{taker}' on one line: both take the axis words"))
        if harmless:
            for name, k, _ in harmless:  # pressure advance moves the extruder off the plan: only "off" is harmless
                if (problem := mcodes.advance_refused(self, block, name, params)) is not None:
                    problems.append(problem)
            if problems:
                return None, None
            takes = [self.harmless_takes(block, name, k) for name, k, _ in harmless]
            if None in takes:  # they take every word of the line
                allowed = all([self.skip(block, k, name, reason) for name, k, reason in harmless])
                return (motion, names) if allowed and names else (None, None)
        if motion is None and taker is None:
            taken = {letter for name in names for letter in PARAMS[name]}  # M220's R is not an arc's radius
            if any(a in params for a in AXIS_LETTERS) or (self.mode in ("G2", "G3") and
                                                          any(a in params and a not in taken for a in "IJKR")):
                motion = self.mode
                if any(name == "G80" for name, _, _ in harmless):
                    k = min(self.word_index(block, a) for a in (*AXIS_LETTERS, *"IJKR") if a in params)
                    problems.append((k, f"'{block.words[k][0]}{block.words[k][1]}': G80 on this line cancels the "
                                     "motion mode; axis words need G0, G1, G2 or G3"))
        used = set("FS").union(*takes)  # the rest of the line keeps its meaning: G64 X5 moves in the modal motion
        for name in names:
            used.update(PARAMS[name])
        if motion is not None:
            used.update(PARAMS[motion])
        for letter in params:
            if letter not in used:
                k = self.word_index(block, letter)
                word = self.word(block, letter)
                problems.append((k, f"'{word}' is not a parameter of {' or '.join(names)}" if names else
                                 f"'{word}': G80 cancelled the motion mode; axis words need G0, G1, G2 or G3"
                                 if self.mode is None and letter in AXIS_LETTERS else
                                 f"'{word}' needs a code that takes it"))
        if problems or not all([self.skip(block, k, name, reason) for name, k, reason in harmless]):
            return None, None
        for (code, letter), reason in HARMLESS_PARAMS.items():
            if code in names and letter in params:
                if not self.skip(block, self.word_index(block, letter), f"{code} {letter}", reason):
                    return None, None
        return motion, names

    def _code(self, block: Block, name: str, params) -> bool | None:
        """Run one non-motion code; False when it failed (the rest of the line is dropped)."""
        if name == "M3" or name == "M4":
            self.spindle, self.dynamic = True, name == "M4"
        elif name == "M5":
            self.spindle = False
        elif name == "M82":
            self.e_relative = False
        elif name == "M83":
            self.e_relative = True
        elif name == "G90":
            self.relative = self.e_relative = False
        elif name == "G91":
            self.relative = self.e_relative = True
        elif name in PLANES:
            self.plane = PLANES[name]
        elif name == "G92":
            return self.set_position(block, params)
        elif name == "G28" and self.stored["G28"] is None:
            return self.home(block, params)
        elif name in ("G28", "G30"):
            return self.go_stored(block, name, params)
        elif name in ("G28.1", "G30.1"):
            self.store(name[:3])
        elif name in SYSTEMS:
            self.select_system(name)
        elif name == "G10":
            return self.set_system(block, params)
        elif name == "G92.1":
            self.clear_g92()
        elif name in ("G43.1", "G49"):
            return self.set_tool_length(block, params, name)
        elif name in ("G93", "G94"):
            self.inverse_time = name == "G93"
        elif name in ("M7", "M8", "M9"):
            self.coolant(block, name)
        elif name == "G4":
            return mcodes.dwell(self, block, params)
        else:
            return mcodes.HANDLERS[name](self, block, params)
        return None
