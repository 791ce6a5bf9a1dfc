"""Feed hold, resume, feed override and M0/M1 in the ATmega2560's flash image and streaming firmware
(codegen/tables/hold.py has the arithmetic): the keys (and a stream's link requests) main polls after every interrupt,
and the step interrupt's dilated path (templates/avr/player_isr.S.j2).

Keys to ground on the board's `hold_keys:` pins (internal pull-ups, pressed reads low): `hold` sets the target
factor to 0, `resume` to the override, `feed-` and `feed+` step the override by 10 % (10 % to
machine.feed_hold.max_override) on each press; above 100 % the ceiling records cap the factor
(codegen/tables/headroom.py). The step interrupt takes the dilated path while a GPIOR0 bit says so (main sets it at a key;
the interrupt clears it once the factor and its target are both 100 %)."""

from __future__ import annotations

import re

from codegen.errors import BuildError
from codegen.firmware.avr.player import NEED_BIT0
from codegen.firmware.config import FirmwareConfig, board_pin_uses, load_target
from codegen.tables.hold import CLAMP, F_ONE, RESUME_TICKS, override_target
from codegen.tables.schedule import RT_PAUSE

HOLD_KEYS = ("hold", "resume", "feed-", "feed+")  # in the order of their bits (the link's requests' too)
HOLD_VARIABLES = 21  # bytes of SRAM: D (2), F.frac16 (3), target, ceiling, parked, paused, override step, keys,
# the last look's TCNT1 (2), the debounce's quiet (2), spill (6)
DEBOUNCE_MS = 20  # a feed key's contacts bounce for a few ms: presses closer than this count once
HOLD_STREAM_VARIABLES = 2  # the streaming firmware's: the link's requests, the catch-up's far flag
PIN = re.compile(r"P[A-L][0-7]")
LINK_BITS = (6, 7)  # GPIOR0 bits the streaming firmware's link keeps (link.h: RX_STORE_BIT, RX_KEEP_BIT)


def dilate_bit(motors: list[dict], stream: bool) -> int:
    """A GPIOR0 bit no motor's "Bresenham needed" flag takes (only motors kept in SRAM use theirs), nor the link."""
    used = {m["need_bit"] for m in motors if m["bresenham"] and not m["regs"]} | (set(LINK_BITS) if stream else set())
    free = [b for b in range(NEED_BIT0, 8) if b not in used]
    if not free:
        raise BuildError("machine.feed_hold: the player has no GPIOR0 bit left for the hold's flag")
    return free[0]


def hold_context(config: FirmwareConfig, motors: list[dict], stream: bool, tick_hz: int) -> dict:
    """The templates' `hold` (None without feed_hold). Call after the player's registers are allocated."""
    plan = config.hold
    if plan is None:
        return {"hold": None}
    taken = board_pin_uses(load_target(config.board), PIN, {"name", "target", "mcu", "hold_keys"})
    keys = []
    for function in HOLD_KEYS:
        pin = plan.keys.get(function)
        if pin is None or not PIN.fullmatch(pin):
            raise BuildError(f"board {config.board}: hold_keys needs {function}: a pin such as PL2 (has {pin!r})")
        if pin in taken:
            raise BuildError(f"board {config.board}: hold_keys {function} is {pin}, which is its {taken[pin]} too")
        keys.append({"function": function, "port": pin[1], "bit": int(pin[2])})
    start = config.hold_override // 10
    return {"hold": {
        "bit": dilate_bit(motors, stream), "key_list": keys,
        "ramp_k": plan.ramp_k, "f_one": F_ONE, "f_free": plan.gate_above, "gated": plan.gated,
        "ceilings": plan.top > F_ONE,
        "resume_ticks": RESUME_TICKS,
        "clamp_bytes": [CLAMP >> 8 * k & 0xFF for k in range(3)],
        "debounce_ms": DEBOUNCE_MS, "debounce_ticks": DEBOUNCE_MS * tick_hz // 1000,
        "override_steps": plan.max_step, "start_step": start, "start_target": override_target(start),
        "table": plan.table, "rt_pause": RT_PAUSE}}
