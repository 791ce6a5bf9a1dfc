"""What an HD44780 character display (LCD1602: 2 lines of 16) shows, decoded from the simulated port writes that
drive it, with the datasheet's timing checked.

Input: the records of port latch writes, (clock, port, latch value) rows in time order (codegen.sim.mcs51's
`_records`; rows of other tags are ignored), and the wiring (`rs`, `e`, optional `rw`, `data` = D4-D7 or D0-D7
pins with `.port` and `.bit`, as codegen.firmware.mcs51.lcd.LcdWiring). Ports come out of reset at 0xFF.

The model (HD44780U datasheet): the display takes RS and the data lines on each falling edge of E. It powers up
with an 8-bit interface (4-bit wiring: D3-D0 unconnected, read as 0) until a function set with DL = 0; then two
writes make a byte, high nibble first. Decoded: function set, clear display, return home, entry mode (increment or
decrement, display shift), display on/off, cursor or display shift, DDRAM address (line 2 at 0x40), CGRAM address
(the characters written there are not shown), data. Problems, each with its clock:
- a byte (its first write, on a 4-bit interface) before the previous instruction has finished: execution times for
  the oscillator at 270 kHz (clear and return home 1.52 ms, the rest 37 us), 15 ms from power-up to the first one,
  4.1 ms after the first function set of the reset sequence and 100 us after the second;
- E high for less than 450 ns, E falling less than 1000 ns after its previous fall, RS or RW changing less than
  60 ns before E rises (or while E is high), a data line changing less than 195 ns before E falls, RS or a data line
  changing less than 10 ns after it falls (the 2.7-4.5 V figures);
- reads (RW high), which the decoder does not answer, and addresses outside the DDRAM.
The fall of E from its reset level (high) during the power-up wait is ignored, as the display ignores it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from codegen.firmware.mcs51.board import Pin
    from codegen.firmware.mcs51.lcd import LcdWiring

COLUMNS = 16
OSC_HZ = 270_000  # the display's oscillator, for which the datasheet gives its execution times
EXECUTE_S = 37e-6  # every instruction and data write but clear and return home
HOME_S = 1.52e-3  # clear display, return home
POWER_UP_S = 15e-3  # from VCC at 4.5 V to the first instruction
RESET_WAITS_S = (4.1e-3, 100e-6)  # after the first and the second function set of the reset sequence
E_HIGH_NS, E_CYCLE_NS, SETUP_RS_NS, SETUP_DATA_NS, HOLD_NS = 450, 1000, 60, 195, 10
SPACE = 0x20


@dataclass(frozen=True)
class Problem:
    clock: int
    message: str

    def __str__(self) -> str:
        return f"clock {self.clock}: {self.message}"


@dataclass
class Display:
    """The visible text at the end, every change of it as (clock, (line 1, line 2)), and the problems found."""

    lines: tuple[str, str]
    states: list[tuple[int, tuple[str, str]]] = field(default_factory=list)
    problems: list[Problem] = field(default_factory=list)


def _char(code: int) -> str:
    """The character of a code in the display's ROM A00 for the codes that are ASCII (0x5C is a yen sign)."""
    return "\u00a5" if code == 0x5C else chr(code) if 0x20 <= code <= 0x7D else "\ufffd"


class _Controller:
    """The display's instruction decoder, DDRAM and busy time, fed one byte or nibble per falling edge of E."""

    def __init__(self, f_osc: float, osc_hz: float, power_on: int) -> None:
        self.clocks_per_s, self.scale = f_osc, OSC_HZ / osc_hz
        self.eight_bit, self.two_lines, self.display_on = True, False, False
        self.increment, self.shift_on_write, self.cgram = True, False, False
        self.address, self.shift = 0, 0
        self.ddram = bytearray([SPACE] * 0x80)
        self.first_nibble: tuple[int, int] | None = None  # (RS, high nibble) of a byte half received
        self.busy_until = power_on + round(POWER_UP_S * f_osc)
        self.previous = "power-up"
        self.instructions = 0
        self.problems: list[Problem] = []
        self.states: list[tuple[int, tuple[str, str]]] = []

    def lines(self) -> tuple[str, str]:
        if not self.display_on:
            return " " * COLUMNS, " " * COLUMNS
        if not self.two_lines:
            line = "".join(_char(self.ddram[(self.shift + c) % 80]) for c in range(COLUMNS))
            return line, " " * COLUMNS
        return tuple("".join(_char(self.ddram[base + (self.shift + c) % 40]) for c in range(COLUMNS))
                     for base in (0x00, 0x40))

    def receive(self, clock: int, rs: int, bus: int) -> None:
        if self.eight_bit:
            self._check_busy(clock)
            self._execute(clock, rs, bus)
        elif self.first_nibble is None:
            self._check_busy(clock)
            self.first_nibble = (rs, bus >> 4)
        else:
            first_rs, high = self.first_nibble
            self.first_nibble = None
            if first_rs != rs:
                self.problems.append(Problem(clock, "RS differs between the two nibbles of a byte"))
            self._execute(clock, rs, high << 4 | bus >> 4)

    def _check_busy(self, clock: int) -> None:
        if clock < self.busy_until:
            early = (self.busy_until - clock) / self.clocks_per_s * 1e6
            self.problems.append(Problem(clock, f"a write {early:.1f} us before the display is ready "
                                                f"(still busy with {self.previous})"))

    def _execute(self, clock: int, rs: int, byte: int) -> None:
        seconds, name = EXECUTE_S * self.scale, f"instruction 0x{byte:02X}"
        if rs:
            name = f"character 0x{byte:02X}"
            if not self.cgram:
                self.ddram[self.address] = byte
                self._advance(1 if self.increment else -1)
                self.shift += (1 if self.increment else -1) if self.shift_on_write else 0
        elif byte & 0x80:
            address = byte & 0x7F
            if (address < 0x28 or 0x40 <= address < 0x68) if self.two_lines else address < 0x50:
                self.cgram, self.address = False, address
            else:
                self.problems.append(Problem(clock, f"DDRAM address 0x{address:02X} does not exist (ignored)"))
        elif byte & 0x40:
            self.cgram = True
        elif byte & 0x20:
            self.eight_bit, self.two_lines = bool(byte & 0x10), bool(byte & 0x08)
            if self.instructions < len(RESET_WAITS_S):
                seconds = max(seconds, RESET_WAITS_S[self.instructions])
        elif byte & 0x10:
            step = -1 if byte & 0x04 else 1
            if byte & 0x08:
                self.shift += step
            else:
                self._advance(-step)
        elif byte & 0x08:
            self.display_on = bool(byte & 0x04)
        elif byte & 0x04:
            self.increment, self.shift_on_write = bool(byte & 0x02), bool(byte & 0x01)
        elif byte & 0x03:  # return home (0x02, 0x03); clear display (0x01) also blanks DDRAM and sets increment
            self.address, self.shift, self.cgram, seconds = 0, 0, False, HOME_S * self.scale
            if byte == 0x01:
                self.ddram[:] = bytes([SPACE] * len(self.ddram))
                self.increment = True
        else:
            self.problems.append(Problem(clock, "instruction 0x00 (none)"))
        self.instructions += 1
        self.busy_until, self.previous = clock + round(seconds * self.clocks_per_s), name
        shown = self.lines()
        if not self.states or self.states[-1][1] != shown:
            self.states.append((clock, shown))

    def _advance(self, step: int) -> None:
        """Address counter to the next (step +1) or previous (-1) DDRAM cell."""
        if self.two_lines:
            line, offset = divmod(self.address, 0x40)
            offset += step
            if not 0 <= offset < 40:
                line, offset = 1 - line, offset % 40
            self.address = 0x40 * line + offset
        else:
            self.address = (self.address + step) % 80


def _display_writes(records: np.ndarray, masks: dict[int, int], seen: dict[int, int]) -> np.ndarray:
    """The records of the display's ports that change one of its pins (masks: port -> the display's pins; seen:
    port -> its pins' bits as last written, updated here: the latch is 0xFF after reset)."""
    rec = np.asarray(records, dtype=np.int64).reshape(-1, 3)
    rec = rec[np.isin(rec[:, 1], list(masks))]
    keep = np.zeros(len(rec), dtype=bool)
    for port, mask in masks.items():
        rows = np.flatnonzero(rec[:, 1] == port)
        bits = rec[rows, 2] & mask
        keep[rows] = bits != np.concatenate([[seen[port]], bits[:-1]])
        if len(bits):
            seen[port] = int(bits[-1])
    return rec[keep]


def _fall_problems(ns: float, clock: int, rise: int | None, fall: int | None, control_at: int,
                   data_at: int) -> list[str]:
    """The write timing at a falling edge of E (clocks of the last rise and fall before it, and of the last
    changes of RS/RW and of the data lines); ns: nanoseconds per clock."""
    out = []
    if rise is not None and (clock - rise) * ns < E_HIGH_NS:
        out.append(f"E high for {(clock - rise) * ns:.0f} ns, less than {E_HIGH_NS} ns")
    if fall is not None and (clock - fall) * ns < E_CYCLE_NS:
        out.append(f"E falls {(clock - fall) * ns:.0f} ns after its previous fall, less than {E_CYCLE_NS} ns")
    if rise is not None and (rise - control_at) * ns < SETUP_RS_NS:
        out.append(f"RS or RW changes less than {SETUP_RS_NS} ns before E rises, or while E is high")
    if (clock - data_at) * ns < SETUP_DATA_NS:
        out.append(f"a data line changes {(clock - data_at) * ns:.0f} ns before E falls, less than {SETUP_DATA_NS} ns")
    return out


class DisplayDecoder:
    """The display driven by records fed in time order, a piece at a time (`feed`), and what it shows (`display`);
    f_osc: the records' clocks per second; osc_hz: the display's oscillator (execution times scale with 270 kHz /
    osc_hz); power_on: the clock of power-up."""

    def __init__(self, wiring: LcdWiring, f_osc: float = 12_000_000, osc_hz: float = OSC_HZ, power_on: int = 0):
        used = [p for p in (wiring.rs, wiring.e, wiring.rw, *wiring.data) if p is not None]
        self.wiring = wiring
        self.masks = {port: sum(1 << p.bit for p in used if p.port == port) for port in sorted({p.port for p in used})}
        self.latch = dict.fromkeys(self.masks, 0xFF)
        self.seen = dict(self.masks)
        self.ns = 1e9 / f_osc
        self.lcd = _Controller(f_osc, osc_hz, power_on)
        self.e, self.control, self.data = 1, (self._level(wiring.rs), self._level(wiring.rw)), self._bus()
        self.rise = self.fall = None  # clocks of the last edges of E (E is high from reset, with no rise seen)
        self.control_at = self.data_at = -(1 << 62)  # clocks of the last changes of RS/RW and of the data lines

    def _level(self, pin: Pin | None) -> int:
        return 0 if pin is None else self.latch[pin.port] >> pin.bit & 1

    def _bus(self) -> int:
        return sum(self._level(p) << (self.wiring.first_data_line + i) for i, p in enumerate(self.wiring.data))

    def feed(self, records: np.ndarray) -> None:
        wiring, lcd, ns = self.wiring, self.lcd, self.ns
        for clock, port, value in _display_writes(records, self.masks, self.seen).tolist():
            self.latch[port] = value
            held = self.fall is not None and (clock - self.fall) * ns < HOLD_NS
            if (self._level(wiring.rs), self._level(wiring.rw)) != self.control:
                self.control, self.control_at = (self._level(wiring.rs), self._level(wiring.rw)), clock
                if held:
                    lcd.problems.append(Problem(clock, f"RS or RW changes within {HOLD_NS} ns after E falls"))
            if self._bus() != self.data:
                self.data, self.data_at = self._bus(), clock
                if held:
                    lcd.problems.append(Problem(clock, f"a data line changes within {HOLD_NS} ns after E falls"))
            if self._level(wiring.e) == self.e:
                continue
            self.e = self._level(wiring.e)
            if self.e:
                self.rise = clock
                continue
            if self.rise is None and clock < lcd.busy_until:
                self.fall = clock  # E leaving its reset level during the power-up wait: ignored
                continue
            lcd.problems += [Problem(clock, text) for text in _fall_problems(ns, clock, self.rise, self.fall,
                                                                             self.control_at, self.data_at)]
            self.fall = clock
            if self.control[1]:
                lcd.problems.append(Problem(clock, "a read (RW high): the decoder models writes only"))
            else:
                lcd.receive(clock, self.control[0], self.data)

    def display(self) -> Display:
        lcd = self.lcd
        return Display(lines=lcd.lines(), states=lcd.states, problems=sorted(lcd.problems, key=lambda p: p.clock))


def decode(records: np.ndarray, wiring: LcdWiring, f_osc: float = 12_000_000, osc_hz: float = OSC_HZ,
           power_on: int = 0) -> Display:
    """The display driven by `records` (see the module's doc; DisplayDecoder)."""
    decoder = DisplayDecoder(wiring, f_osc, osc_hz, power_on)
    decoder.feed(records)
    return decoder.display()
