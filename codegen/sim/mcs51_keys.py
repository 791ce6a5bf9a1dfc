"""Jog keys in s51: the board's keys pressed and released at simulated times (codegen/sim/keys.py's script).

The script keeps the pressed keys in a simulator variable, `kp` (bit i: codegen/jog.py's KEYS[i]), set at every
entry of the firmware's key scan (`_jog_scan`, from firmware.map) from sim_ticks: a nested conditional over the
script's changes, so a change is seen at the first scan after its time (the firmware scans every 2 ms; it
could not see it earlier). Direct keys: at that entry each key's pin level goes on `pin<port>` (ucsim's levels
outside the chip; the firmware reads latch AND pin), low while pressed. A matrix: at every write to a port that
carries a row (bytes and bits), each column's pin reads low while a pressed key joins it to a row whose latch is
low; the scan drives its rows after its entry, so the columns follow. (One key per column at a time: ghost keys
through two pressed keys are not modelled.)

Each scan prints a record (TAG_SCAN, the index of the script's latest change in effect); at the end the firmware's
jog positions are read from internal RAM (TAG_JOG_POS + byte index, a byte each, little-endian int32 per motor).
"""

from __future__ import annotations

from codegen.errors import BuildError
from codegen.firmware import FirmwareConfig
from codegen.firmware.mcs51 import SFR, board_data, parse_pin
from codegen.firmware.mcs51_jog import taken_pins
from codegen.jog import KEYS, board_keys
from codegen.sim.keys import KeyPress, key_events

TAG_SCAN, TAG_JOG_POS = 20, 32  # record tags (TAG_JOG_POS + byte index)
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
