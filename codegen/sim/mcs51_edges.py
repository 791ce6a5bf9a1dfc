"""An 8051 streaming run's records (codegen/sim/mcs51_link.py: s51's port writes) kept whole (KeptRecords), or
written as they come into an edges file in the simavr harness's format (EdgeRecords; codegen/sim/avr_edges.py), for
verify to read a chapter at a time in another process (codegen/verify/run_reader.py), so that neither process holds
the run.

The file's pins (edge_pins): STEP and DIR of each motor, the tool, then the slow pins (codegen/sim/mcs51.py
slow_pins), each record a change of the pin's level (8051 pins are high after reset), and a START_PIN record at each
start of the player's timer (the fetch of its SETB TR0, as codegen/sim/mcs51.py logs it). A STEP pin's fall from its
reset level before its first rise ends no pulse, and is left out. The board's display is decoded as its records come
(codegen/sim/hd44780.py DisplayDecoder).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from codegen.firmware.config import FirmwareConfig
from codegen.firmware.mcs51.board import board_pins, memories
from codegen.firmware.mcs51.lcd import board_lcd
from codegen.firmware.mcs51.sdcc import START_TICKS
from codegen.sim.avr_edges import EDGE_RECORD, START_PIN, RunPins
from codegen.sim.hd44780 import DisplayDecoder
from codegen.sim.mcs51 import TAG_FAULT, TAG_TIMER, slow_pins


def edge_pins(pins: dict) -> list[tuple[str, object]]:
    """The edges file's pins by name, in the file's order."""
    named = [(f"{m['name']}.{role}", m[role]) for m in pins["motors"] for role in ("step", "dir")]
    return named + [("tool", pins["tool"])] + slow_pins(pins)


def mcs51_run_pins(config: FirmwareConfig) -> RunPins:
    """The layout of the edges file EdgeRecords writes for `config`'s board."""
    pins, mem = board_pins(config), memories(config.board)
    f_cpu = int(mem["f_cpu"])
    clocks_per_tick = f_cpu // int(mem["tick_hz"])
    return RunPins(f_cpu, clocks_per_tick, clocks_per_tick * (1 + START_TICKS),
                   tuple(bool(m["invert"]) for m in pins["motors"]), tuple(name for name, _ in edge_pins(pins)),
                   1 if pins["tool_active_high"] else 0, 1)


class KeptRecords:
    """Every record, (clock, tag, value) rows: the whole run (codegen/sim/mcs51.py trace_of decodes it)."""

    def __init__(self):
        self._parts: list[np.ndarray] = []

    def add(self, rec: np.ndarray) -> None:
        self._parts.append(rec)

    def array(self) -> np.ndarray:
        return np.concatenate(self._parts) if self._parts else np.zeros((0, 3), dtype=np.int64)

    def close(self) -> None:
        pass


class EdgeRecords:
    """The records as pin changes in the edges file at `path`, the display decoded, the timer starts and homing's
    fault records kept (a few a run)."""

    def __init__(self, path: Path, config: FirmwareConfig):
        pins = board_pins(config)
        self.pins = [(pin.port, pin.bit) for _, pin in edge_pins(pins)]
        self.steps = {2 * m for m in range(len(pins["motors"]))}  # the pins' indices of the STEP pins
        self.level = [1] * len(self.pins)  # each pin's level as last written: high after reset
        self.risen = [False] * len(self.pins)
        lcd = board_lcd(config.board, [m.name for m in config.motors])
        self.display = None if lcd is None else DisplayDecoder(lcd.wiring, f_osc=int(memories(config.board)["f_cpu"]))
        self.kept: list[np.ndarray] = []  # the timer starts' and the faults' records
        self._file = open(path, "ab")

    def add(self, rec: np.ndarray) -> None:
        cycles, pin_ids, levels = [], [], []
        for index, (port, bit) in enumerate(self.pins):
            mine = rec[rec[:, 1] == port]
            level = (mine[:, 2] >> bit) & 1
            changed = np.diff(np.concatenate([[self.level[index]], level])) != 0
            clock, level = mine[changed, 0], level[changed]
            if len(level):
                self.level[index] = int(level[-1])
            if index in self.steps and not self.risen[index]:  # its fall from the reset level ends no pulse
                rises = np.flatnonzero(level == 1)
                self.risen[index] = bool(len(rises))
                clock, level = (clock[rises[0]:], level[rises[0]:]) if len(rises) else (clock[:0], level[:0])
            cycles.append(clock)
            pin_ids.append(np.full(len(clock), index))
            levels.append(level)
        starts = rec[rec[:, 1] == TAG_TIMER, 0]
        cycles.append(starts)
        pin_ids.append(np.full(len(starts), START_PIN))
        levels.append(np.zeros(len(starts), dtype=np.int64))
        out = np.zeros(sum(len(c) for c in cycles), EDGE_RECORD)
        out["cycle"], out["pin"], out["level"] = (np.concatenate(a) for a in (cycles, pin_ids, levels))
        self._file.write(out[np.argsort(out["cycle"], kind="stable")].tobytes())
        self._file.flush()  # whole records for the reader as each batch ends
        kept = rec[np.isin(rec[:, 1], (TAG_TIMER, TAG_FAULT))]
        if len(kept):
            self.kept.append(kept)
        if self.display is not None:
            self.display.feed(rec)

    def array(self) -> np.ndarray:
        """The records kept: the timer starts and the faults."""
        return np.concatenate(self.kept) if self.kept else np.zeros((0, 3), dtype=np.int64)

    def close(self) -> None:
        self._file.close()
