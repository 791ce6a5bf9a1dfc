"""The optional HD44780 status display (LCD1602: 2 lines of 16 characters) of an 8051 board: its wiring from the
board's `lcd:` section, the context of templates/mcs51/lcd.c.j2 and lcd.h.j2, and the text the firmware shows.

Board schema (targets/<board>.yaml; pins as P<port>.<bit>, on any ports):
    lcd: {mode: 4bit, rs: P2.1, e: P2.2, data: [P2.4, P2.5, P2.6, P2.7]}   # data: D4-D7 (4bit) or D0-D7 (8bit)
    optional `rw: P2.3`: the driver holds it low (it never reads the busy flag); without it RW is tied to GND.
A board without `lcd:` has no display. P0's pins are open drain: display lines there need pull-up resistors.

Layout: each motor (at most 4, in the firmware's motor order) owns half a line of 8 columns, motor 0 and 1 on
line 1, motor 2 and 3 on line 2: a one-character label (the motor's name in capitals), its position as a signed
decimal right-aligned in 6 columns (-32768 to 32767 steps; the minus sign just before the digits), a blank:
    `A     0 B-12345 `
    `C 32767         `
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

from codegen.errors import BuildError
from codegen.firmware.config import board_pin_uses
from codegen.firmware.mcs51.board import Pin, board_data, memories, parse_pin
from codegen.firmware.render import render

MODES = {"4bit": 4, "8bit": 8}
KEYS = ("mode", "rs", "e", "rw", "data")
COLUMNS = 16
LINE_ADDRESS = (0x00, 0x40)  # DDRAM address of the first column of each line (2-line mode)
FIELD_COLUMNS = 8  # label, 6-column number, blank
NUMBER_COLUMNS = 6
MAX_MOTORS = 4
POSITION_MIN, POSITION_MAX = -32768, 32767  # the firmware's signed 16-bit step counters
WAIT_UNIT = 10  # machine cycles per unit of the driver's busy wait (lcd_wait)
# While the job plays, main refreshes the positions at most this often: 20 a second is more than an eye reads, and
# a refresh (seven writes a motor) keeps main from its other work (keys, the link's answers) for milliseconds.
REFRESH_MS = 50
TH1_TICKS = 256  # machine cycles per count of Timer1's high byte, the refresh's clock
# The driver's waits: name -> (microseconds, why). The HD44780U's execution times are for its oscillator at
# 270 kHz; it may run as slow as 190 kHz (times x 1.42), hence the margins.
WAITS = {
    "POWER_UP": (20000, "> 15 ms from VCC at 4.5 V to the first instruction"),
    "RESET_1": (5000, "> 4.1 ms after the first function set of the reset sequence"),
    "RESET_2": (200, "> 100 us after the second"),
    "EXECUTE": (60, "an instruction or a character: 37 us at 270 kHz, 53 us at 190 kHz"),
    "CLEAR": (2500, "clear display: 1.52 ms at 270 kHz, 2.16 ms at 190 kHz"),
}
_PIN = re.compile(r"P[0-3]\.[0-7]")
_BOOKKEEPING = {"name", "target", "mcu", "lcd"}


@dataclass(frozen=True)
class LcdWiring:
    """The display's pins: `data` is D4-D7 (mode 4) or D0-D7 (mode 8), in bus order."""

    board: str
    mode: int  # 4 or 8 data lines
    rs: Pin
    e: Pin
    rw: Pin | None  # None: RW tied to GND
    data: tuple[Pin, ...]

    @property
    def first_data_line(self) -> int:
        """The bus line of data[0]: D4 on a 4-bit interface, D0 on an 8-bit one."""
        return 8 - self.mode


def pin_uses(board: dict, xram: int) -> dict[str, str]:
    """Every pin the board gives to something other than the display (pin name -> what), the external RAM's bus
    included: P0 (address/data), the P2 lines that carry address bits above A7, P3.6/P3.7 (WR/RD)."""
    uses = board_pin_uses(board, _PIN, _BOOKKEEPING)
    if xram:
        uses.update({f"P0.{b}": "the external RAM bus (AD0-AD7)" for b in range(8)})
        high = (xram - 1) >> 8  # the largest DPH a MOVX @DPTR puts on P2
        uses.update({f"P2.{b}": f"the external RAM bus (A{8 + b})" for b in range(high.bit_length())})
        uses.update({"P3.6": "the external RAM bus (WR)", "P3.7": "the external RAM bus (RD)"})
    return uses


def parse_lcd(section: object, board: str, taken: dict[str, str]) -> LcdWiring:
    """Check a board's `lcd:` section against the pins `taken` by the rest of the board (pin_uses)."""
    where = f"board {board}: lcd"
    if not isinstance(section, dict):
        raise BuildError(f"{where}: expected a mapping with {', '.join(KEYS)}")
    unknown = sorted(set(section) - set(KEYS))
    if unknown:
        raise BuildError(f"{where}: unknown key(s) {', '.join(map(str, unknown))} (allowed: {', '.join(KEYS)})")
    missing = [k for k in ("mode", "rs", "e", "data") if k not in section]
    if missing:
        raise BuildError(f"{where}: missing {', '.join(missing)}")
    mode = MODES.get(str(section["mode"]))
    if mode is None:
        raise BuildError(f"{where}.mode: `{section['mode']}` is not one of {', '.join(MODES)}")
    data = section["data"]
    if not isinstance(data, list) or len(data) != mode:
        first = 8 - mode
        raise BuildError(f"{where}.data: a {section['mode']} display takes a list of {mode} pins, "
                         f"D{first} to D7 in order")
    roles = [("rs", section["rs"]), ("e", section["e"])] + ([("rw", section["rw"])] if "rw" in section else [])
    roles += [(f"data D{8 - mode + i}", pin) for i, pin in enumerate(data)]
    pins = {}
    for role, text in roles:
        try:
            pins[role] = parse_pin(text)
        except BuildError:
            raise BuildError(f"{where}.{role.split()[0]}: `{text}` is not an 8051 pin (expected e.g. P2.4)") from None
    seen: dict[str, str] = {}
    clashes = []
    for role, pin in pins.items():
        if pin.name in seen:
            clashes.append(f"{pin.name} is both {seen[pin.name]} and {role}")
        elif pin.name in taken:
            clashes.append(f"{pin.name} ({role}) is already {taken[pin.name]}")
        seen.setdefault(pin.name, role)
    if clashes:
        raise BuildError(f"{where}: pins used twice: " + "; ".join(clashes))
    return LcdWiring(board=board, mode=mode, rs=pins["rs"], e=pins["e"], rw=pins.get("rw"),
                     data=tuple(pins[f"data D{8 - mode + i}"] for i in range(mode)))


@dataclass(frozen=True)
class Lcd:
    """A wired display showing the positions of the firmware's motors, one label character each."""

    wiring: LcdWiring
    labels: tuple[str, ...]

    def __post_init__(self) -> None:
        if not 1 <= len(self.labels) <= MAX_MOTORS:
            raise BuildError(f"board {self.wiring.board}: the LCD shows 1 to {MAX_MOTORS} motors, "
                             f"not {len(self.labels)}")
        bad = [s for s in self.labels if len(s) != 1 or not (s.isascii() and s.isalnum())]
        if bad:
            raise BuildError(f"LCD labels must be single letters or digits, got {bad}")

    @classmethod
    def for_motors(cls, wiring: LcdWiring, motor_names: Sequence[str]) -> Lcd:
        """Each motor labelled by the first letter of its name, in capitals (x -> X, a -> A)."""
        return cls(wiring, tuple(name[:1].upper() for name in motor_names))

    def field_address(self, motor: int) -> int:
        """DDRAM address of the motor's label; its number follows."""
        return LINE_ADDRESS[motor // 2] + FIELD_COLUMNS * (motor % 2)

    def expected_text(self, positions: Sequence[int]) -> tuple[str, str]:
        """The two 16-column lines the firmware shows after lcd_show_position(m, positions[m]) for every motor."""
        if len(positions) != len(self.labels):
            raise ValueError(f"{len(positions)} positions for {len(self.labels)} motors")
        lines = [[" "] * COLUMNS for _ in LINE_ADDRESS]
        for motor, (label, steps) in enumerate(zip(self.labels, positions)):
            if not POSITION_MIN <= steps <= POSITION_MAX:
                raise ValueError(f"position {steps} of motor {motor} is not a signed 16-bit number")
            column = FIELD_COLUMNS * (motor % 2)
            lines[motor // 2][column:column + 1 + NUMBER_COLUMNS] = f"{label}{steps:>{NUMBER_COLUMNS}d}"
        return "".join(lines[0]), "".join(lines[1])

    def context(self) -> dict:
        """The `lcd` key of the templates' context (they also use board, mcu, job_file and target)."""
        w = self.wiring
        tick_hz = int(memories(w.board)["tick_hz"])  # machine cycles per second: the busy waits count them
        waits = [{"name": name, "us": us, "why": why, "units": math.ceil(us * tick_hz / 1e6 / WAIT_UNIT - 1e-9)}
                 for name, (us, why) in WAITS.items()]
        return {"lcd": {
            "mode": w.mode, "rs": _pin(w.rs), "e": _pin(w.e), "rw": _pin(w.rw) if w.rw else None,
            "data": [{**_pin(p), "line": w.first_data_line + i} for i, p in enumerate(w.data)],
            "fields": [{"motor": m, "label": label, "char": f"'{label}'", "address": self.field_address(m)}
                       for m, label in enumerate(self.labels)],
            "number_columns": NUMBER_COLUMNS, "wait_unit": WAIT_UNIT, "waits": waits,
            "init_ms": sum(us for name, (us, _) in WAITS.items() if name != "EXECUTE") // 1000,
            "show_us": (1 + NUMBER_COLUMNS) * WAITS["EXECUTE"][0],
            "refresh_ms": REFRESH_MS, "refresh_units": refresh_units(tick_hz),
        }}


def refresh_units(tick_hz: int) -> int:
    """REFRESH_MS in counts of Timer1's high byte at `tick_hz` machine cycles a second (a byte: at most 255)."""
    units = -(-REFRESH_MS * tick_hz // (1000 * TH1_TICKS))
    if units > 255:
        raise BuildError(f"a display refresh every {REFRESH_MS} ms takes {units} counts of Timer1's high byte at "
                         f"{tick_hz} machine cycles a second: more than a byte holds")
    return units


def board_lcd(board: str, motor_names: Sequence[str]) -> Lcd | None:
    """The display of targets/<board>.yaml showing the positions of `motor_names` (the firmware's motors, in
    order), or None when the board has no `lcd:` section."""
    data, _ = board_data(board)
    if "lcd" not in data:
        return None
    wiring = parse_lcd(data["lcd"], board, pin_uses(data, int(memories(board)["xram"])))
    return Lcd.for_motors(wiring, motor_names)


def render_lcd(lcd: Lcd, context: dict) -> dict[str, str]:
    """lcd.c and lcd.h (file name -> text); `context` gives board, mcu, job_file and target (the player's)."""
    return {name: render(f"mcs51/{name}.j2", **{**context, **lcd.context()}) for name in ("lcd.c", "lcd.h")}


def _pin(pin: Pin) -> dict:
    return {"name": pin.name, "sbit": f"P{pin.port}_{pin.bit}"}
