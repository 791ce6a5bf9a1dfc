"""Feed hold keys in s51: the board's hold keys (codegen/firmware/mcs51_hold.py) pressed and released at simulated
clock counts, for codegen/hold_runs.py's S51FlashRun.

As the jog keys' model (codegen/sim/mcs51_keys.py): the script keeps the keys held in a simulator variable, `hk`
(bit i: HOLD_KEYS[i]), set at every entry of the firmware's poll (`_hold_poll`, from firmware.map) from sim_ticks, so
a change is seen at the first poll after it; at every write to a port that carries a row, each column's pin reads
low while a held key joins it to a row whose latch is low (beside the jog keys' model of the same matrix, it only
pulls columns low after that model's update). Each poll logs a record (TAG_HOLD_POLL, the index of the
latest change in effect), which tells when the firmware first saw each press.
"""

from __future__ import annotations

import numpy as np

from codegen.errors import BuildError
from codegen.firmware import FirmwareConfig
from codegen.firmware.mcs51 import SFR, board_data, parse_pin
from codegen.firmware.mcs51_hold import HOLD_KEYS

TAG_HOLD_POLL = 21  # record tag of a poll's entry


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
