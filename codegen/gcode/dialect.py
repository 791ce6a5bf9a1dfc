"""Marlin's or Grbl's G-code (`program.dialect`, JOB-FORMAT.md), where their codes mean different things: G4 P is
milliseconds in Marlin and seconds in Grbl; S's full scale (without `program.s_max`) is 255 in Marlin and 1000 in
Grbl ($30). Without the key, the first line that only one of them writes decides (`guess`, over at most the first
GUESS_LINES lines, GUESS_CHARS characters), else Marlin; a note says which and why where it first matters.

An S on a machine without `machine.laser` sets nothing (the tool pin is on or off): one warning at the first.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from codegen.errors import Diagnostic
from codegen.gcode.codes import HARMLESS_TAKES

GUESS_LINES = 2000
GUESS_CHARS = 1 << 18
GUESS_LINE_CHARS = 256  # a deciding code stands near a line's start
S_FULL_SCALE = {"marlin": 255.0, "grbl": 1000.0}
_GRBL_CODE = re.compile(r"^\s*\$|G\s*0*38\s*\.|G\s*0*10\s*L\s*0*20?(?![\d.])", re.IGNORECASE)
_MARLIN_CODE = re.compile(r"(?<![A-Z])(?:M\s*0*(?:104|109|140|190|82|83|106)|G\s*0*29)(?![\d.])", re.IGNORECASE)
NO_LASER = ("the machine has no `laser:`, so M3/M4 switch the tool pin on and off only; "
            "`machine.laser: {pwm_hz: 1000}` (a PWM laser) gives power control over S")


@dataclass(frozen=True)
class Dialect:
    name: str  # marlin | grbl
    line: int | None  # the 0-based index of the line that decided the guess; None: the default or the job's key
    why: str  # what decided it; "": the job file's program.dialect

    def reason(self, first_line: int) -> str:
        """Why this dialect, for a note (`first_line`: the source line number of index 0)."""
        if self.line is None:
            return f"the default: none of the first {GUESS_LINES} lines is Grbl's or Marlin's alone"
        return f"guessed from line {first_line + self.line} ({self.why})"


def guess(text: str) -> Dialect:
    """The dialect of the G-code whose start is `text`: the first deciding line's, else Marlin."""
    for index, whole in enumerate(text.split("\n")[:GUESS_LINES]):
        line = whole[:GUESS_LINE_CHARS]  # a line of 176 KB (CR-only ends) made the searches below quadratic
        cut = line.find(";")
        comment = "" if cut < 0 else line[cut:].upper()
        if "GRBL" in comment:
            return Dialect("grbl", index, "a comment names Grbl")
        if "FLAVOR" in comment and "MARLIN" in comment:
            return Dialect("marlin", index, "the slicer's flavor is Marlin")
        code = re.sub(r"\([^()]*\)", " ", line if cut < 0 else line[:cut])
        if (found := _GRBL_CODE.search(code)) is not None:
            return Dialect("grbl", index, f"'{found.group().strip()}' is Grbl's")
        if (found := _MARLIN_CODE.search(code)) is not None:
            return Dialect("marlin", index, f"'{found.group()}' is Marlin's")
    return Dialect("marlin", None, "")


def dialect_of(job, source: str | Path) -> Dialect:
    """The job's `program.dialect`, or the guess from the start of its G-code (inline text or a file)."""
    given = getattr(job.program, "dialect", None)
    if given is not None:
        return Dialect(given, None, "")
    if isinstance(source, str):
        return guess(source[:GUESS_CHARS])
    try:
        with open(source, encoding="utf-8", errors="surrogateescape", newline="\n") as file:
            return guess(file.read(GUESS_CHARS))
    except OSError:  # reported where the program is read
        return Dialect("marlin", None, "")


class DialectState:
    """Mixed into the Interpreter: G4 P's unit, S's scale and the tool power, and their note and warning.
    `s_watched`: Python reads every S (the C's plain lines leave them) until the note or warning is given."""

    def dialect_init(self, machine, program, dialect: Dialect) -> None:
        self.dialect, self.dialect_given = dialect, getattr(program, "dialect", None) is not None
        self.noted: set[str] = set()  # the meanings the note has been given for
        self.has_laser = getattr(machine, "laser", None) is not None
        scale = getattr(program, "s_max", None)
        self.s_full = float(scale) if scale else S_FULL_SCALE[dialect.name]
        self.s_guessed = self.has_laser and not scale and not self.dialect_given
        self.s_watched = not self.has_laser or self.s_guessed

    def note(self, block, k: int | None, meaning: str, setting: str) -> None:
        """Once per meaning, where it first matters: what the dialect made of a word, and why that dialect."""
        if meaning in self.noted or self.dialect_given:
            return
        self.noted.add(meaning)
        self.notes.append(Diagnostic(self.where(block, k), f"{meaning}: G-code dialect {self.dialect.name}, "
                                     f"{self.dialect.reason(self.origin.line)}; {setting}", "note"))

    def harmless_takes(self, block, name: str, k: int) -> str | None:
        """The letters a skipped code takes from its line (None: every word). T and M6 take their own alone in
        Grbl, which runs the rest of the block (`T1 X5` moves); Marlin runs one command a line and skips the
        rest."""
        if name[0] != "T" and name != "M6":
            return HARMLESS_TAKES.get(name)
        grbl = self.dialect.name == "grbl"
        if any(letter not in "NTGM" for letter, _ in block.words):  # parameters beside it
            self.note(block, k, f"words beside {name[0] if name[0] == 'T' else name} "
                      f"{'kept' if grbl else 'skipped'}", "program.dialect sets it")
        return ("T" if name == "M6" else "") if grbl else None  # M6's tool number beside it

    def dwell_p_seconds(self, block) -> float:
        """Seconds per unit of G4's P."""
        grbl = self.dialect.name == "grbl"
        self.note(block, self.word_index(block, "P"), f"G4 P in {'seconds' if grbl else 'milliseconds'}",
                  "program.dialect sets it")
        return 1.0 if grbl else 0.001

    def s_heeded(self, block) -> bool:
        """Before an S sets the tool power: its note or warning; False when --strict refuses an unheeded S."""
        k = self.word_index(block, "S")
        if self.has_laser:
            if self.s_guessed:
                self.note(block, k, f"S of full power {self.s_full:g}", "program.s_max sets it")
            self.s_watched = False
            return True
        self.s_watched = False
        return self.skip(block, k, "S", NO_LASER)

    def set_power(self, block, params) -> bool | None:
        """S: the tool power from here on (over the full scale); False when it is in error."""
        value = params["S"]
        if value < 0.0:
            self.fail(block, "S", f"power '{self.word(block, 'S')}' must be >= 0")
            return False
        if self.s_watched and not self.s_heeded(block):
            return False
        self.power = min(value / self.s_full, 1.0)
        return None
