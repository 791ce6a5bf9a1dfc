"""Jog keys and feed hold keys in s51: the board's keys pressed and released at simulated times (codegen/sim/keys.py's
script for jog keys; (function, first clock, last clock) for the hold keys of codegen/verify/hold_runs.py's S51FlashRun).

The script keeps the pressed keys in a simulator variable, `kp` (bit i: codegen/motion/jog.py's KEYS[i]), set at every
entry of the firmware's key scan (`_jog_scan`, from firmware.map) from sim_ticks: a nested conditional over the
script's changes, so a change is seen at the first scan after its time (the firmware scans every 2 ms; it
could not see it earlier). Direct keys: at that entry each key's pin level goes on `pin<port>` (ucsim's levels
outside the chip; the firmware reads latch AND pin), low while pressed. A matrix: at every write to a port that
carries a row (bytes and bits), each column's pin reads low while a pressed key joins it to a row whose latch is
low; the scan drives its rows after its entry, so the columns follow. (One key per column at a time: ghost keys
through two pressed keys are not modelled.)

Each scan prints a record (TAG_SCAN, the index of the script's latest change in effect); at the end the firmware's
jog positions are read from internal RAM (TAG_JOG_POS + byte index, a byte each, little-endian int32 per motor).

Hold keys (codegen/firmware/mcs51/hold.py) likewise: the script keeps them in `hk` (bit i: HOLD_KEYS[i]), set at
every entry of the firmware's poll (`_hold_poll`), and a column reads low while a held key joins it to a row whose
latch is low (beside the jog keys' model of the same matrix, it only pulls columns low after that model's update).
Each poll prints a record (TAG_HOLD_POLL, the index of the latest change in effect): when the firmware first saw
each press.
"""

from __future__ import annotations

import numpy as np

from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig
from codegen.firmware.mcs51.board import SFR, board_data, parse_pin
from codegen.firmware.mcs51.hold import HOLD_KEYS
from codegen.firmware.mcs51.jog import taken_pins
from codegen.motion.jog import KEYS, board_keys
from codegen.sim.keys import KeyPress, key_events

TAG_SCAN, TAG_HOLD_POLL, TAG_JOG_POS = 20, 21, 32  # record tags (TAG_JOG_POS + byte index)
POSITION_BYTES = 4


def key_model(config: FirmwareConfig, script: list[KeyPress], symbols: dict[str, int], f_cpu: int) -> dict:
    """The s51 script's parts that play `script`: prelude, on_write (port -> expression), breaks [(spec, tag
    expression)], bits (bit addresses to break on), at_halt [tag expressions]."""
    board, _ = board_data(config.board)
    wiring = board_keys(config.board, board, config.jog.keys, parse_pin, taken_pins(board))
    scan = symbols.get("_jog_scan")
    if scan is None:
        raise BuildError("firmware.map lacks _jog_scan: the image has no jog mode")
    events = key_events(script, wiring.keys)
    if len(events) > 255:
        raise BuildError(f"a key script of {len(events)} changes: at most 255")
    mask = (lambda held: sum(1 << KEYS.index(k) for k in held))
    chain = "0"
    for t, held in events:  # the latest change wins: built from the first outwards
        chain = f"(sim_ticks>{int(round(t * f_cpu))})?{mask(held)}:{chain}"
    index = "0"
    for i, (t, _) in enumerate(events):
        index = f"(sim_ticks>{int(round(t * f_cpu))})?{i + 1}:{index}"
    on_write: dict[int, str] = {}
    effects = [f"kp={chain}"]
    if wiring.kind == "direct":
        ports = sorted({pin.port for pin in wiring.keys.values()})
        for port in ports:
            mine = {KEYS.index(k): pin for k, pin in wiring.keys.items() if pin.port == port}
            all_bits = sum(pin.mask for pin in mine.values())
            low = "|".join(f"(((kp>>{i})&1)?{pin.mask}:0)" for i, pin in mine.items())
            effects.append(f"pin{port}=(pin{port}&{0xFF & ~all_bits})|({all_bits}&~({low}))")
        bits: list[int] = []
    else:
        for port in sorted({pin.port for pin in wiring.cols}):
            cols = [c for c in wiring.cols if c.port == port]
            all_bits = sum(c.mask for c in cols)
            low = "|".join(f"((((kp>>{KEYS.index(k)})&1)&&!(P{wiring.rows[r].port}&{wiring.rows[r].mask}))?"
                           f"{wiring.cols[c].mask}:0)"
                           for k, (r, c) in wiring.keys.items() if wiring.cols[c].port == port) or "0"
            update = f"pin{port}=(pin{port}&{0xFF & ~all_bits})|({all_bits}&~({low}))"
            for row_port in sorted({r.port for r in wiring.rows}):
                on_write[row_port] = ",".join(filter(None, [on_write.get(row_port), update]))
        bits = sorted({SFR[r.port] + r.bit for r in wiring.rows})
    breaks = [(f"{scan:#x}", f"{','.join(effects)},{TAG_SCAN * 256}+({index})")]
    at_halt = []
    for k, m in enumerate(config.jog.motors):
        address = symbols.get(f"_jog_pos_m{m}")
        if address is None:
            raise BuildError(f"firmware.map lacks _jog_pos_m{m}")
        at_halt += [f"{TAG_JOG_POS * 256 + (POSITION_BYTES * k + b) * 256}+iram[{address + b:#x}]"
                    for b in range(POSITION_BYTES)]
    return {"prelude": ("var kp", "expression /X kp=0"), "on_write": on_write, "breaks": breaks, "bits": bits,
            "at_halt": at_halt, "events": events}


def jog_positions(rec, n_motors: int) -> list[int] | None:
    """The firmware's jog position counts (steps from power-up) from the records read at the end, or None."""
    values = {}
    for tag, value in zip(rec[:, 1].tolist(), rec[:, 2].tolist()):
        if TAG_JOG_POS <= tag < TAG_JOG_POS + POSITION_BYTES * n_motors:
            values[tag - TAG_JOG_POS] = value
    if len(values) != POSITION_BYTES * n_motors:
        return None
    out = []
    for k in range(n_motors):
        raw = sum(values[POSITION_BYTES * k + b] << (8 * b) for b in range(POSITION_BYTES))
        out.append(raw - (1 << 32) if raw >= 1 << 31 else raw)
    return out


def hold_key_model(config: FirmwareConfig, presses: list[tuple[str, int, int]], symbols: dict[str, int]) -> dict:
    """The s51 script's parts that press `presses` ((function, first clock, last clock)): prelude, on_write (port ->
    expression), breaks [(spec, tag expression)], bits (bit addresses to break on), changes (clock of each change
    of the held keys, in order: a poll's record gives the index + 1 of the latest one it saw)."""
    poll = symbols.get("_hold_poll")
    if poll is None:
        raise BuildError("firmware.map lacks _hold_poll: the image has no feed hold keys")
    matrix = (board_data(config.board)[0].get("jog_keys") or {})["matrix"]
    rows, cols = [parse_pin(p) for p in matrix["rows"]], [parse_pin(p) for p in matrix["cols"]]
    times = sorted({t for _, a, b in presses for t in (a, b)})
    if len(times) > 255:
        raise BuildError(f"{len(times)} hold key changes: at most 255")
    chain, index = "0", "0"
    for i, t in enumerate(times):  # the latest change wins: built from the first outwards
        held = sum(1 << HOLD_KEYS.index(f) for f, a, b in presses if a <= t < b)
        chain = f"(sim_ticks>{t})?{held}:{chain}"
        index = f"(sim_ticks>{t})?{i + 1}:{index}"
    on_write: dict[int, str] = {}
    for port in sorted({c.port for c in cols}):
        mine = [(HOLD_KEYS.index(f), rows[r], cols[c]) for f, (r, c) in config.hold.keys.items()
                if cols[c].port == port]
        all_bits = sum(c.mask for c in cols if c.port == port)
        low = "|".join(f"((((hk>>{bit})&1)&&!(P{row.port}&{row.mask}))?{col.mask}:0)" for bit, row, col in mine) or "0"
        # after the jog keys' own update (which sets every column from its keys) only pull more columns low
        update = (f"pin{port}=pin{port}&~({low})" if config.jog is not None
                  else f"pin{port}=(pin{port}&{0xFF & ~all_bits})|({all_bits}&~({low}))")
        for row_port in sorted({r.port for r in rows}):
            on_write[row_port] = ",".join(filter(None, [on_write.get(row_port), update]))
    return {"prelude": ("var hk", "expression /X hk=0"), "on_write": on_write,
            "breaks": [(f"{poll:#x}", f"hk={chain},{TAG_HOLD_POLL * 256}+({index})")],
            "bits": sorted({SFR[r.port] + r.bit for r in rows}), "changes": times}


def seen_at(polls: np.ndarray, changes: list[int], press: int) -> int:
    """The clock of the first poll that saw the change at clock `press` (-1: none did); `polls` (clock, index)."""
    j = changes.index(press) + 1
    later = np.flatnonzero(polls[:, 1] >= j)
    return int(polls[later[0], 0]) if len(later) else -1
