"""Grbl 1.1's codes beyond the common ones: work coordinate systems, machine coordinates, stored positions,
tool length offset, inverse-time feed and coolant.

Offsets: machine = program + offset, with offset = the selected work system (G54-G59, set by G10 L2/L20) +
the G92 offset + the tool length offset (G43.1, on Z). The interpreter keeps the sum in `off`; the handlers
here change it by what they change, so G92 (codegen/gcode/moves.py) keeps its meaning.

G28 and G30 go to stored positions as Grbl does once a program stores one (G28.1, G30.1): by way of the
point its axis words give (program coordinates), then to the stored position in machine coordinates, only
the named axes when there are any. Without a stored G28 position, G28 homes (Marlin's meaning, and Grbl's
machine origin after homing); G30 without G30.1 goes to the home position.

The `$` system commands, a line each: `$H` homes (as G28 without a stored position: every axis the machine has,
or the axes named, `$HX`); `$X` (alarm unlock), the settings (`$110=5000`, `$RST=`, `$N0=`) and the report
queries (`$$`, `$#`, `$G`, `$I`, `$N`, `$`) are skipped with a warning (errors with --strict), a setting naming
the job file key that gives it; `$C` (check mode), `$SLP` (sleep) and `$J=` (a sender's jog) are errors.
"""

from __future__ import annotations

import re

from codegen.toolpath.items import Output

SYSTEMS = ("G54", "G55", "G56", "G57", "G58", "G59")
PROBE_REASON = ("probes: the move stops where a contact closes, a measurement taken while the machine runs, "
                "which a plan computed beforehand cannot know")


class GrblState:
    """Mixed into the Interpreter: the state and handlers of the codes above."""

    def grbl_init(self) -> None:
        self.systems = {name: [0.0] * 4 for name in SYSTEMS}
        self.system = "G54"
        self.tool_length = 0.0
        self.stored = {"G28": None, "G30": None}
        self.inverse_time = False
        self.inverse_feed: float | None = None  # this block's F in G93 (1/min)

    def select_system(self, name: str) -> None:
        old, new = self.systems[self.system], self.systems[name]
        self.off = [o + n - p for o, n, p in zip(self.off, new, old)]
        self.system = name

    def set_system(self, block, params) -> bool | None:
        """G10 L2 P<n> (the system's offset) or L20 (so that the tool is at the given program coordinates)."""
        mode = params.get("L")
        if mode not in (2.0, 20.0):
            self.fail(block, "L" if "L" in params else "G10", "G10 needs L2 or L20 (work coordinate offsets)")
            return False
        number = params.get("P", 0.0)
        if number not in (0, 1, 2, 3, 4, 5, 6):
            self.fail(block, "P" if "P" in params else "G10", "G10 needs P0 (the current system) to P6 (G59)")
            return False
        if not any(letter in params for letter in "XYZ"):  # as Grbl: error 26, no axis words
            self.fail(block, "G10", "G10 needs the axis words to set (X, Y, Z)")
            return False
        name = self.system if number == 0 else SYSTEMS[int(number) - 1]
        values = list(self.systems[name])
        for i, letter in enumerate("XYZ"):
            if letter in params:
                value = params[letter] * self.unit
                # L20: offset such that the current position reads `value` (the G92 and tool offsets stay)
                others = self.off[i] - self.systems[self.system][i]
                values[i] = self.pos[i] - value - others if mode == 20.0 else value
        if name == self.system:
            self.off = [o + n - p for o, n, p in zip(self.off, values, self.systems[name])]
        self.systems[name] = values
        return None

    def clear_g92(self) -> None:
        """G92.1: the G92 offsets go; the work system and tool length offset stay."""
        system = self.systems[self.system]
        self.off = [system[0], system[1], system[2] + self.tool_length, self.off[3]]  # E's stays, as its shift

    def set_tool_length(self, block, params, name: str) -> bool | None:
        """G43.1 Z<offset> (dynamic tool length offset) or G49 (none)."""
        if name == "G43.1" and "Z" not in params:
            self.fail(block, "G43.1", "G43.1 needs Z, the tool length offset")
            return False
        new = params["Z"] * self.unit if name == "G43.1" else 0.0
        self.off[2] += new - self.tool_length
        self.tool_length = new
        return None

    def store(self, name: str) -> None:
        """G28.1 / G30.1: the current machine position becomes G28's / G30's."""
        self.stored[name] = self.pos[:3]

    def go_stored(self, block, name: str, params) -> bool | None:
        """G28 (with a stored position) and G30: rapid by the given point, then to the stored position."""
        stored = self.stored[name] or self.home_point
        named = [i for i, letter in enumerate("XYZ") if letter in params]
        if named:
            self.line_move(block, "G0", {letter: params[letter] for letter in "XYZ" if letter in params})
        final = self.pos[:]
        for i in named or [i for i in range(3) if self.movable[i]]:
            final[i] = stored[i]
        if final != self.pos:
            if self.fixed and self.axis_missing(block, final):
                return False
            start = self.add_point(final)
            self.items.append(self.line_item(block, start, self.speed(self.rapid, False), False, "G0",
                                             self.accel_travel))
        return None

    def coolant(self, block, name: str) -> None:
        """M7 (mist) / M8 (flood) on, M9 both off: recorded, as the fan is."""
        if name == "M9":
            self.items += [Output("mist", 0.0, False, self.source(block)),
                           Output("flood", 0.0, False, self.source(block))]
        else:
            self.items.append(Output("mist" if name == "M7" else "flood", 1.0, False, self.source(block)))

    def inverse_time_feed(self, block, params) -> bool | None:
        """G93: each G1/G2/G3 carries F, the inverse of its duration in minutes."""
        if "F" not in params:
            self.fail(block, None, "in inverse time mode (G93) every G1, G2 and G3 needs F (1/minutes)")
            return False
        if params["F"] <= 0.0:
            self.fail(block, "F", f"feed rate '{self.word(block, 'F')}' must be > 0")
            return False
        self.inverse_feed = params["F"]
        return None


# ---- `$` lines ----

QUERIES = ("$", "$$", "$#", "$G", "$I", "$N")
AXES = "XYZ"
_SETTING = re.compile(r"\$(\d+)\s*=\s*(\S*)")
_STEPPER = {10: ("steps_per_mm", ""), 11: ("max_velocity", " (mm/s; Grbl's is mm/min)"), 12: ("max_accel", ""),
            13: ("range", " ([min, max])")}  # $100-$102, $110-$112, $120-$122, $130-$132 by their tens
_KEYS = {11: "machine.junction_deviation", 12: "machine.tolerance", 30: "program.s_max", 32: "machine.laser",
         20: "machine.steppers.<motor>.range (soft limits)"}
ERRORS = {
    "$C": "'$C' switches Grbl's check mode (it then reads the program without moving): not modelled; remove it",
    "$SLP": "'$SLP' puts Grbl to sleep (motors off until a reset): not modelled; remove it",
}
JOG = ("'$J=' is a jog, a move a sender makes at the operator's request, not part of a program: write it as G1 "
       "(G91 for a relative jog) with its F")


def setting_key(it, number: int) -> str | None:
    """The job file key that gives Grbl's setting $number, with a hint; None: no key (it changes nothing here)."""
    tens, axis = divmod(number, 10)
    if tens in _STEPPER and axis < 3:
        motors = it.motors if it.kinematics == "cartesian" else ("x", "y", "z")
        field, hint = _STEPPER[tens]
        return f"machine.steppers.{motors[axis] if axis < len(motors) else AXES[axis].lower()}.{field}{hint}"
    return _KEYS.get(number)


def system_command(it, block) -> None:
    """A `$` line (block.words: [("$", the rest of the line, upper case)])."""
    command = "$" + block.words[0][1].replace(" ", "")
    k = None  # the `$`: the line's first column
    if command.startswith("$H") and all(letter in AXES for letter in command[2:]):
        it.home(block, {letter: 0.0 for letter in command[2:]})
    elif command == "$X":
        it.skip(block, k, command, "alarm unlock; there is no alarm state here")
    elif command in QUERIES:
        it.skip(block, k, command, "a report query")
    elif command.startswith("$J="):
        it.fail(block, k, JOG)
    elif command in ERRORS:
        it.fail(block, k, ERRORS[command])
    elif command.startswith("$RST="):
        it.skip(block, k, command, "restores Grbl's settings; the job file describes the machine")
    elif command.startswith("$N") and "=" in command:
        it.skip(block, k, command[:command.index("=")], "a startup block, which Grbl runs at its reset, not here")
    elif (setting := _SETTING.fullmatch(command)) is not None:
        key = setting_key(it, int(setting.group(1)))
        name = f"${int(setting.group(1))}"
        it.skip(block, k, name, f"a Grbl setting; the job file gives it: {key}" if key else
                "a Grbl setting that changes nothing this toolchain models")
    else:
        it.fail(block, k, f"unknown Grbl command '{command}'")
