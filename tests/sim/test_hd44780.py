"""The LCD1602 status display of the 8051 target: the board's `lcd:` section, the text the firmware shows, the
HD44780 decoder of simulated port writes (unit tests on hand-made writes), and the driver (templates/mcs51/lcd.c.j2)
built with SDCC, run in s51 and decoded, end to end.
"""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

from codegen.errors import BuildError
from codegen.firmware.mcs51.board import SFR, board_data, memories
from codegen.firmware.mcs51.lcd import Lcd, board_lcd, parse_lcd, pin_uses, render_lcd
from codegen.firmware.mcs51.sdcc import read_map
from codegen.sim.hd44780 import DisplayDecoder, decode
from codegen.sim.mcs51 import _records

CLOCKS_PER_US = 12
FOUR_BIT = {"mode": "4bit", "rs": "P2.1", "e": "P2.2", "data": ["P2.4", "P2.5", "P2.6", "P2.7"]}
# Any pins on any ports: D0-D3 on P1.4-P1.7, D4-D7 on P3.0-P3.3, RS, E and RW on P2.
EIGHT_BIT = {"mode": "8bit", "rs": "P2.0", "e": "P2.7", "rw": "P2.6",
             "data": ["P1.4", "P1.5", "P1.6", "P1.7", "P3.0", "P3.1", "P3.2", "P3.3"]}


def wiring(section):
    return parse_lcd(section, "at89c52", {})


class Writer:
    """Drives the display's pins one bit write at a time, 1 us apart unless told, as (clock, port, latch) records
    at 12 MHz; `falls` are the clocks at which E fell."""

    def __init__(self, w):
        self.w, self.clock, self.rows, self.falls = w, 0, [], []
        self.latch = dict.fromkeys(range(4), 0xFF)

    def pin(self, pin, level, us=1.0):
        self.clock += round(us * CLOCKS_PER_US)
        self.latch[pin.port] = self.latch[pin.port] & ~(1 << pin.bit) | level << pin.bit
        self.rows.append((self.clock, pin.port, self.latch[pin.port]))

    def wait(self, us):
        self.clock += round(us * CLOCKS_PER_US)

    def put(self, rs, bus, high_us=1.0):
        self.pin(self.w.rs, rs)
        for i, p in enumerate(self.w.data):
            self.pin(p, bus >> (self.w.first_data_line + i) & 1)
        self.pin(self.w.e, 1)
        self.pin(self.w.e, 0, high_us)
        self.falls.append(self.clock)

    def byte(self, rs, value, wait_us=50.0):
        self.put(rs, value)
        if self.w.mode == 4:
            self.put(rs, value << 4 & 0xFF)
        self.wait(wait_us)

    def init(self):
        self.pin(self.w.e, 0)
        if self.w.rw:
            self.pin(self.w.rw, 0)
        self.wait(20_000)
        for wait_us in (5000, 200, 50):
            self.put(0, 0x30)
            self.wait(wait_us)
        if self.w.mode == 4:
            self.put(0, 0x20)
            self.wait(50)
        for instruction, wait_us in ((0x28 if self.w.mode == 4 else 0x38, 50), (0x08, 50), (0x01, 2000),
                                     (0x06, 50), (0x0C, 50)):
            self.byte(0, instruction, wait_us)
        return self

    def text(self, chars, address=None):
        if address is not None:
            self.byte(0, 0x80 | address)
        for c in chars:
            self.byte(1, ord(c))
        return self

    def decode(self):
        return decode(np.array(self.rows, dtype=np.int64), self.w)


def messages(display):
    return [str(p) for p in display.problems]


@pytest.mark.parametrize("section", [FOUR_BIT, EIGHT_BIT], ids=["4bit", "8bit"])
def test_decodes_init_and_two_lines(section):
    out = Writer(wiring(section)).init().text("Hello").text("World!", 0x40).decode()
    assert out.problems == []
    assert out.lines == ("Hello" + " " * 11, "World!" + " " * 10)
    assert out.states[0][1] == (" " * 16, " " * 16) and out.states[-1][1] == out.lines
    assert len(out.states) == 1 + 11  # display on (blank), then one state per character


def test_address_jumps_and_the_wrap_between_lines():
    out = (Writer(wiring(FOUR_BIT)).init().text("AB", 0x45).text("XYZ", 0x0E)  # Z goes to 0x10, off screen
           .text("PQ", 0x27).decode())  # P at the end of line 1's 40 cells, Q at 0x40
    assert out.problems == []
    assert out.lines == (" " * 14 + "XY", "Q    AB" + " " * 9)


def test_entry_mode_decrement_display_shift_and_display_off():
    w = Writer(wiring(EIGHT_BIT)).init()
    w.byte(0, 0x04)  # entry mode: decrement
    w.text("ab", 0x05)
    assert w.decode().lines[0] == "    ba" + " " * 10
    w.byte(0, 0x18)  # shift the display left
    assert w.decode().lines[0] == "   ba" + " " * 11
    w.byte(0, 0x02, wait_us=2000)  # return home: no shift
    assert w.decode().lines[0] == "    ba" + " " * 10
    w.byte(0, 0x08)  # display off
    out = w.decode()
    assert out.lines == (" " * 16, " " * 16) and out.problems == []


def test_a_write_before_the_previous_instruction_finished():
    w = Writer(wiring(FOUR_BIT)).init()
    w.byte(0, 0x01, wait_us=500)  # clear display takes 1.52 ms
    w.text("A")
    w.byte(1, ord("B"), wait_us=20)  # a character takes 37 us
    w.text("C")
    clear_done, b_done = w.falls[-7], w.falls[-3]  # the second nibbles of the clear and of B
    out = w.decode()
    assert [p.clock for p in out.problems] == [w.falls[-6], w.falls[-2]]  # the first nibbles of A and C
    assert "still busy with instruction 0x01" in messages(out)[0]
    assert "still busy with character 0x42" in messages(out)[1]
    assert out.problems[0].clock - clear_done < 1.52e-3 * 12e6 and out.problems[1].clock - b_done < 37 * 12
    assert out.lines[0].startswith("ABC")  # decoded all the same


def test_reset_sequence_waits_and_power_up():
    w = Writer(wiring(EIGHT_BIT))
    w.pin(w.w.e, 0)
    w.pin(w.w.rw, 0)  # high from reset: a read
    w.wait(10_000)  # 10 ms: too early for the first instruction
    w.put(0, 0x30)
    w.wait(3000)  # 3 ms: the datasheet asks 4.1
    w.put(0, 0x30)
    w.wait(200)
    w.put(0, 0x30)
    out = w.decode()
    assert [p.clock for p in out.problems] == w.falls[:2]
    assert "power-up" in messages(out)[0] and "instruction 0x30" in messages(out)[1]


def test_the_reset_level_of_e_is_ignored_until_power_up_ends():
    w = Writer(wiring(FOUR_BIT))
    w.pin(w.w.rs, 0)
    w.pin(w.w.e, 0)  # E high from reset: the display is still resetting
    assert w.decode().problems == []
    late = Writer(wiring(FOUR_BIT))
    late.wait(16_000)
    late.pin(late.w.e, 0)  # the same fall after 16 ms is a write (RS high, all ones: character 0xFF)
    assert late.decode().problems == [] and late.decode().states[0][0] == late.clock


def test_short_e_pulse_setup_times_and_reads():
    w = Writer(wiring(EIGHT_BIT)).init()
    w.put(1, ord("A"), high_us=5 / 12)  # 417 ns high
    short = w.clock
    w.wait(50)
    w.pin(w.w.rs, 1)
    w.pin(w.w.e, 1)
    w.pin(w.w.data[0], 0, us=0)  # D0 changes with... (same clock)
    w.pin(w.w.e, 0, us=1 / 12)  # ...and E falls 83 ns later
    setup = w.clock
    w.wait(50)
    w.pin(w.w.rw, 1)
    w.pin(w.w.e, 1)
    w.pin(w.w.e, 0)
    read = w.clock
    out = w.decode()
    problems = {(p.clock, p.message.split(" ")[0]) for p in out.problems}
    assert problems == {(short, "E"), (setup, "E"), (setup, "a"), (read, "a")}
    assert "E high for 417 ns, less than 450 ns" in messages(out)[0]
    assert any("83 ns before E falls" in m for m in messages(out)) and "a read" in messages(out)[-1]


@pytest.mark.parametrize("piece", [1, 5, 64])
def test_records_fed_a_piece_at_a_time_decode_as_the_whole(piece):
    """A stream's display is decoded as s51's records come (codegen/sim/mcs51_edges.py): a piece may end between
    a latch write and the next, mid-nibble or with E high."""
    w = Writer(wiring(FOUR_BIT)).init().text("Hello").text("World!", 0x40)
    w.put(1, ord("A"), high_us=5 / 12)  # 417 ns high: a problem carried from its piece to the display's end
    rows = np.array(w.rows, dtype=np.int64)
    decoder = DisplayDecoder(w.w)
    for start in range(0, len(rows), piece):
        decoder.feed(rows[start:start + piece])
    whole, pieces = decode(rows, w.w), decoder.display()
    assert pieces.lines == whole.lines == ("Hello" + " " * 11, "World!" + " " * 10)  # "A": half a byte
    assert pieces.states == whole.states and len(whole.states) == 1 + 11
    assert messages(pieces) == messages(whole) and len(whole.problems) == 1


def test_an_address_beyond_the_ddram_is_reported():
    w = Writer(wiring(FOUR_BIT)).init().text("A", 0x30)
    out = w.decode()
    assert [p.clock for p in out.problems] == [w.falls[-3]] and "0x30 does not exist" in messages(out)[0]
    assert out.lines[0].startswith("A")  # written where the address counter was: 0x00


def test_expected_text_layout():
    lcd = Lcd(wiring(FOUR_BIT), ("A", "B", "C"))
    assert lcd.expected_text([0, -12345, 32767]) == ("A     0 B-12345 ", "C 32767         ")
    assert lcd.expected_text([-32768, 7, -1]) == ("A-32768 B     7 ", "C    -1         ")
    four = Lcd.for_motors(wiring(FOUR_BIT), ["x", "y", "z", "e"])
    assert four.expected_text([1, 22, -333, 4444]) == ("X     1 Y    22 ", "Z  -333 E  4444 ")
    assert Lcd.for_motors(wiring(FOUR_BIT), ["x"]).expected_text([-5]) == ("X    -5         ", " " * 16)
    with pytest.raises(ValueError, match="not a signed 16-bit"):
        lcd.expected_text([0, 32768, 0])
    with pytest.raises(ValueError, match="2 positions for 3 motors"):
        lcd.expected_text([0, 0])
    with pytest.raises(BuildError, match="1 to 4 motors, not 5"):
        Lcd.for_motors(wiring(FOUR_BIT), "abcde")


def test_board_sections():
    seed = board_lcd("seed-51", ["a", "b", "c"])
    assert seed.wiring.mode == 4 and seed.wiring.rw is None and seed.labels == ("A", "B", "C")
    assert [p.name for p in (seed.wiring.rs, seed.wiring.e, *seed.wiring.data)] == [
        "P2.1", "P2.2", "P2.4", "P2.5", "P2.6", "P2.7"]
    assert board_lcd("at89c52", ["x", "y"]) is None and board_lcd("stc89c52rc", ["x", "y"]) is None


@pytest.mark.parametrize("change, message", [
    ({"rs": "P1.0"}, "P1.0 (rs) is already steppers.X.step"),
    ({"e": "P0.3"}, "P0.3 (e) is already the external RAM bus (AD0-AD7)"),
    ({"rs": "P2.0"}, "P2.0 (rs) is already the external RAM bus (A8)"),
    ({"e": "P3.4"}, "P3.4 (e) is already tool.pin"),
    ({"rw": "P2.1"}, "P2.1 is both rs and rw"),
    ({"data": ["P2.4", "P2.5", "P2.6"]}, "a 4bit display takes a list of 4 pins, D4 to D7"),
    ({"mode": "6bit"}, "`6bit` is not one of 4bit, 8bit"),
    ({"enable": "P2.3"}, "unknown key(s) enable"),
    ({"e": "P4.1"}, "lcd.e: `P4.1` is not an 8051 pin"),
])
def test_bad_sections_are_named(change, message):
    board, _ = board_data("seed-51")
    with pytest.raises(BuildError, match="board seed-51: lcd") as err:
        parse_lcd({**FOUR_BIT, **change}, "seed-51", pin_uses(board, int(memories("seed-51")["xram"])))
    assert message in str(err.value)


# End to end: the driver compiled with SDCC, a small main, s51 logging every write to the display's ports.

MAIN_C = """#include <8052.h>
#include "lcd.h"

void halt(void) __naked
{
    __asm
    clr EA
00001$:
    sjmp 00001$
    __endasm;
}

void main(void)
{
    lcd_init();
%s
    halt();
}
"""
TAG_HALT = 16


def _c_int(value):
    return "-32767 - 1" if value == -32768 else str(value)


def run_driver(lcd, board, shows, tmp_path):
    """Build lcd.c with a main showing every position list of `shows` in turn, run it to halt() in s51, decode."""
    sources = render_lcd(lcd, {"board": board, "mcu": "at89c52", "job_file": "tests/sim/test_hd44780.py",
                               "target": "mcs51"})
    calls = "\n".join(f"    lcd_show_position({m}, {_c_int(p)});" for show in shows for m, p in enumerate(show))
    sources["main.c"] = MAIN_C % calls
    for name, text in sources.items():
        (tmp_path / name).write_text(text, encoding="utf-8")
    mem = memories(board)
    flags = ["-mmcs51", "--Werror", f"--model-{mem['model']}", "--iram-size", str(mem["iram"]),
             "--xram-size", str(mem["xram"]), "--code-size", str(mem["flash"])]
    for name in ("main.c", "lcd.c"):
        subprocess.run(["sdcc", *flags, "-c", name], cwd=tmp_path, check=True, capture_output=True)
    subprocess.run(["sdcc", *flags, "-o", "main.ihx", "main.rel", "lcd.rel"], cwd=tmp_path, check=True,
                   capture_output=True)
    _, symbols = read_map(tmp_path / "main.map")
    w = lcd.wiring
    pins = [p for p in (w.rs, w.e, w.rw, *w.data) if p is not None]
    script = [f'file "{tmp_path / "main.ihx"}"']
    watches = [f"sfr w {SFR[port]:#x}" for port in sorted({p.port for p in pins})]
    watches += [f"bits w {SFR[p.port] + p.bit:#x}" for p in pins]
    for n, spec in enumerate(watches, 1):
        port = int(spec.split()[-1], 16) & 0xF0
        script += [f"break {spec}", f"commands {n} expression /u sim_ticks ; "
                                    f"expression /u {(port - 0x80) // 16 * 256}+P{(port - 0x80) // 16} ; run"]
    script += [f"break {symbols['_halt']:#x}",
               f"commands {len(watches) + 1} expression /u sim_ticks ; expression /u {TAG_HALT * 256}",
               "run", "quit", ""]
    (tmp_path / "run.cmd").write_text("\n".join(script), encoding="utf-8")
    done = subprocess.run(["timeout", "60", "s51", "-X", "12M", "-C", "run.cmd"], cwd=tmp_path,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True)
    records = _records(done.stdout)
    assert records[-1, 1] == TAG_HALT, done.stdout[-2000:]
    return decode(records, w), symbols, (tmp_path / "lcd.rel").read_text(), (tmp_path / "lcd.asm").read_text()


@pytest.mark.skipif(shutil.which("sdcc") is None or shutil.which("s51") is None, reason="needs sdcc and s51")
@pytest.mark.parametrize("board, section, motors, shows", [
    ("seed-51", None, "abc", [[0, -12345, 32767], [-32768, 7, -1]]),
    ("at89c52", {"mode": "8bit", "rs": "P2.4", "e": "P2.5", "rw": "P2.6", "data": [f"P0.{b}" for b in range(8)]},
     "xyze", [[1, -10, 100, -1000], [10000, -9, 9999, 0]]),
], ids=["seed-51-4bit-large", "at89c52-8bit-small"])
def test_driver_in_s51(board, section, motors, shows, tmp_path):
    if section is None:
        lcd = board_lcd(board, motors)
    else:
        lcd = Lcd.for_motors(parse_lcd(section, board, pin_uses(board_data(board)[0], 0)), motors)
    display, symbols, rel, asm = run_driver(lcd, board, shows, tmp_path)
    assert display.problems == []
    shown = [lines for _, lines in display.states]
    assert lcd.expected_text(shows[0]) in shown
    assert display.lines == lcd.expected_text(shows[-1])
    # Integer only: no multiplication or division, neither SDCC's routines nor the 4-cycle MUL and DIV (they would
    # delay the step interrupt); and a small driver.
    assert not [s for s in symbols if s.startswith(("__div", "__mod", "__mul"))]
    assert not re.search(r"^\s+(mul|div)\s", asm, re.M)
    code = sum(int(size, 16) for area, size in
               (line.split()[1:4:2] for line in rel.splitlines() if line.startswith("A "))
               if area in ("CSEG", "CONST"))
    assert code < 600
