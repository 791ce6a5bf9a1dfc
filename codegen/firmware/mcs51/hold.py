"""Feed hold, resume and feed override in the 8051's flash image and streaming firmware (codegen/tables/hold.py has the
arithmetic): the keys main scans between step interrupts, or the link's HOLD, RESUME, FEED_DOWN and FEED_UP frames
(hold.c: one hold_poll for both), and the step interrupt's dilated path (templates/mcs51/player.c.j2).

The keys sit on the board's key matrix (`hold_keys:` gives each one's (row, column) in `jog_keys:`' matrix): `hold`
sets the target factor to 0, `resume` to the override (and re-arms a parked player), `feed-` and `feed+` step the
override by 10 % (10 % to 100 %: the 8051's player has no ceiling records) once per press, a press counting only
after DEBOUNCE_MS of quiet, timed by Timer1 (free once homing is done). The interrupt takes the dilated path while
the bit pl_dilating says so (main sets it at a key; the interrupt clears it once the factor and its target are both
100 %). An M0/M1 pause is a runtime record before its block (the only one an 8051 image has): the interrupt sets F 0
there, parks, and resume goes on at F_ONE.

The streaming firmware has no hold keys (seed-51's matrix is on P0, the bus to the external RAM of its ring): the
serial interrupt sets a bit of hold_requests per request frame (the keys' bits), and hold_poll takes each as one
press, with no bounce to time."""

from __future__ import annotations

from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig
from codegen.tables.format import RUNTIME_BYTES, RUNTIME_FLAGS
from codegen.tables.hold import CLAMP, F_ONE, LONG, RESUME_TICKS, override_target
from codegen.tables.schedule import FRAC_BITS

HOLD_KEYS = ("hold", "resume", "feed-", "feed+")  # in the order of their bits in hold.c
DEBOUNCE_MS = 20  # as the AVR's (codegen/firmware/avr/hold.py): presses closer than this count once
TH1_TICKS = 256  # Timer1's high byte counts this many machine cycles
POLL_MS = 2  # main looks at the keys this often (each look drives the matrix rows: no faster than a person needs)


def hold_context(config: FirmwareConfig, board: dict, parse_pin, stop_ticks: int, tick_hz: int,
                 stream: bool = False) -> dict:
    """The templates' `hold` (None without feed_hold): the keys' rows and columns (`stream`: the link's requests
    instead), the ramp and the dilation table."""
    plan = config.hold
    if plan is None:
        return {"hold": None}
    scans = [] if stream else _scans(config, board, parse_pin, plan)
    if CLAMP & 0xFFFF != 0xFFFF or LONG & 0xFF:
        raise BuildError("codegen/tables/hold.py's CLAMP and LONG no longer suit the 8051's dilated path")
    long_iv = (LONG >> FRAC_BITS) - stop_ticks  # the kept interval's upper 16 bits from which a delta is LONG
    start = config.hold_override // 10
    return {"hold": {
        "scans": scans, "requests": stream, "ramp_k": plan.ramp_k, "f_one": F_ONE, "resume_ticks": RESUME_TICKS,
        "long_iv": long_iv, "long_add": 0x10000 - long_iv, "clamp_top": CLAMP >> 16,
        "table_lo": [d & 0xFF for d in plan.table], "table_hi": [d >> 8 for d in plan.table],
        "targets": [override_target(s) for s in range(plan.max_step + 1)],
        "runtime_flags": RUNTIME_FLAGS, "runtime_bytes": RUNTIME_BYTES, "override_steps": plan.max_step,
        "start_step": start, "start_target": override_target(start),
        "debounce_ms": DEBOUNCE_MS, "debounce_units": -(-DEBOUNCE_MS * tick_hz // (1000 * TH1_TICKS)),
        "poll_ms": POLL_MS, "poll_units": -(-POLL_MS * tick_hz // (1000 * TH1_TICKS))}}


def _scans(config: FirmwareConfig, board: dict, parse_pin, plan) -> list[dict]:
    """The hold keys by the matrix row that reads them: the row's pin, and each key's column and bit."""
    matrix = (board.get("jog_keys") or {}).get("matrix") or {}
    rows = [parse_pin(p) for p in matrix.get("rows") or []]
    cols = [parse_pin(p) for p in matrix.get("cols") or []]
    jog_places = {tuple(v) for v in (matrix.get("keys") or {}).values()}
    by_row: dict[int, list[dict]] = {}
    for bit, function in enumerate(HOLD_KEYS):
        place = plan.keys.get(function)
        if not (isinstance(place, tuple) and len(place) == 2 and 0 <= place[0] < len(rows)
                and 0 <= place[1] < len(cols)):
            raise BuildError(f"board {config.board}: hold_keys needs {function}: [row, column] of the jog_keys "
                             f"matrix ({len(rows)} x {len(cols)}; has {place!r})")
        if place in jog_places:
            raise BuildError(f"board {config.board}: hold_keys {function} is at {list(place)}, a jog key's place")
        col = cols[place[1]]
        by_row.setdefault(place[0], []).append({"function": function, "bit": 1 << bit, "sfr": col.sfr,
                                                "mask": col.mask, "pin": col.name})
    scans = []
    for r, keys in sorted(by_row.items()):
        row = rows[r]
        scans.append({"sfr": row.sfr, "pin": row.name, "low": 0xFF & ~row.mask, "keys": keys})
    return scans
