"""The ATmega2560 player's step interrupt (templates/avr/player_isr.S.j2): where its state lives, and the table.c
chunks of the compact stream (codegen/tables/format.py).

The interrupt is assembly and keeps its state in registers between events: main only sleeps while the table
plays (player_run never returns), so every register but r1 (zero) is the player's. Fixed roles: Z and RAMPZ the
table pointer, r24:r25 and r26:r27 the block and run countdowns (SBIW), r20-r23 the interval, r2-r5 the add, r6
the fractional tick, r7:r8 65536 - modulus, r18, r19 and r0 scratch. The rest (`POOL`) goes, in this order, to
the pending STEP masks (one per STEP port), the Bresenham state of each motor (steps and accumulator, 16 bits
each) in motor order, the masks of the block's masters (one per port) and a copy of the compare value; what does
not fit lives in SRAM (a motor there skips its Bresenham when it does not need it: a GPIOR0 bit per motor). A
one-motor image has no Bresenham: its motor steps at every event of a moving block (it is the master).
"""

from __future__ import annotations

import bisect

from codegen.errors import BuildError
from codegen.tables.format import CompactTable
from codegen.tables.schedule import RUNTIME_NAMES

CHUNK_BYTES = 32767  # avr-gcc objects stop at 32767 bytes
LINE_BYTES = 16  # table bytes per line of table.c
START_TICKS = 4  # tick 0, the interrupt that loads the first block, comes this many ticks after the timer start
FIXED_REGS = {"T0": "r18", "T1": "r19", "IV0": "r20", "IV1": "r21", "IV2": "r22", "IV3": "r23",
              "BLK_LO": "r24", "BLK_HI": "r25", "RUN_LO": "r26", "RUN_HI": "r27",
              "AD0": "r2", "AD1": "r3", "AD2": "r4", "AD3": "r5", "FRAC": "r6", "NMOD_LO": "r7", "NMOD_HI": "r8"}
POOL = ("r9", "r10", "r11", "r12", "r13", "r14", "r15", "r16", "r17", "r28", "r29")
NEED_BIT0 = 2  # GPIOR0 bit of motor 0's "Bresenham needed" flag (bit 0: PLAYER_DONE, bit 1: HOMING_FAILED)
PRESCALERS = {1: "_BV(CS10)", 8: "_BV(CS11)", 64: "_BV(CS11) | _BV(CS10)", 256: "_BV(CS12)",
              1024: "_BV(CS12) | _BV(CS10)"}
IO_PORTS = "ABCDEFG"  # PINx/PORTx in I/O space (IN/OUT, SBI/CBI); H..L are extended (LDS/STS)
_HEX = [f"0x{b:02X}" for b in range(256)]


def prescaler_bits(f_cpu: int, tick_hz: int) -> tuple[int, str]:
    """Timer1's prescaler for the player's tick, and its clock select bits (TCCR1B)."""
    scale = f_cpu // tick_hz
    if scale * tick_hz != f_cpu or scale not in PRESCALERS:
        raise BuildError(f"tick_hz {tick_hz} is not F_CPU {f_cpu} over a Timer1 prescaler ({sorted(PRESCALERS)})")
    return scale, PRESCALERS[scale]


def allocate(motors: list[dict], step_ports: list[dict]) -> dict:
    """Give the step ports and motors (template entries, updated in place) their registers or SRAM homes;
    returns {"cmp": (lo, hi) or None, "defines": [(name, reg, what)]}."""
    pool = list(POOL)
    defines = [(name, reg, "") for name, reg in FIXED_REGS.items()]

    def take(n: int) -> list[str] | None:
        if len(pool) < n:
            return None
        got = pool[:n]
        del pool[:n]
        return got

    for p in step_ports:
        p["pend"] = f"PEND_{p['port']}"
        defines.append((p["pend"], take(1)[0], f"STEP pins on port {p['port']} of the pending event"))
    bresenham = len(motors) > 1
    for m in motors:
        m["bresenham"] = bresenham
        m["regs"] = take(4) if bresenham else None
        m["need_bit"] = NEED_BIT0 + m["index"]
        if m["regs"]:
            names = [f"{m['id']}_{part}" for part in ("ST_LO", "ST_HI", "B_LO", "B_HI")]
            what = (f"{m['name']}: steps in the block (0 for a master)", "", f"{m['name']}: 65535 - Bresenham "
                    "accumulator", "")
            defines += list(zip(names, m["regs"], what))
            m["st_lo"], m["st_hi"], m["b_lo"], m["b_hi"] = names
        else:
            m["st_lo"], m["st_hi"], m["b_lo"], m["b_hi"] = (f"pl_{m['var']}_{part}" for part in
                                                            ("st_lo", "st_hi", "b_lo", "b_hi"))
    for p in step_ports:
        reg = take(1)
        p["always_reg"] = bool(reg)
        p["always"] = f"ALWAYS_{p['port']}" if reg else f"pl_always_{p['var']}"
        if reg:
            defines.append((p["always"], reg[0], f"STEP pins on port {p['port']} of the block's masters"))
    cmp = take(2)
    if cmp:
        defines += [("CMP_LO", cmp[0], "OCR1A: the compare value of the event just played"), ("CMP_HI", cmp[1], "")]
    return {"cmp": bool(cmp), "defines": defines}


def isr_context(motors: list[dict], step_ports: list[dict], dir_ports: list[dict], invert_mask: int,
                f_cpu: int, tick_hz: int, pulse_cycles: int) -> dict:
    """Everything player_isr.S.j2 needs besides the pins: registers, the prescaler, the STEP pulse."""
    if len(motors) > 4:
        raise BuildError(f"the compact table stream holds at most 4 motors, not {len(motors)}")
    scale, clock = prescaler_bits(f_cpu, tick_hz)
    for p in step_ports:
        p["io"] = p["port"] in IO_PORTS
        p["single"] = len(p["motors"]) == 1
    for p in dir_ports:
        p["io"] = p["port"] in IO_PORTS
    return {**allocate(motors, step_ports), "prescale": scale, "timer_clock": clock, "start_ticks": START_TICKS,
            "invert_mask": invert_mask, "pulse_cycles": pulse_cycles}


def table_chunks(table: CompactTable) -> list[dict]:
    """table.c's chunks of at most CHUNK_BYTES as lines of at most LINE_BYTES, with a comment line where each
    block record and each runtime record starts (and at the end marker)."""
    data = table.data
    marks = {int(o): f"block {b}: flags 0x{data[o]:02X}{' (long)' if table.block_long[b] else ''}"
             for b, o in enumerate(table.block_offsets)}
    for o in table.runtime_offsets:
        marks[int(o)] = f"runtime: {RUNTIME_NAMES[data[o + 1]]} {data[o + 2] | data[o + 3] << 8}"
    marks[len(data) - 2] = "end marker"
    offsets = sorted(marks)
    chunks = []
    for base in range(0, len(data), CHUNK_BYTES):
        end = min(base + CHUNK_BYTES, len(data))
        cuts = [base] + offsets[bisect.bisect_right(offsets, base):bisect.bisect_left(offsets, end)] + [end]
        lines = []
        for a, b in zip(cuts, cuts[1:]):
            for i in range(a, b, LINE_BYTES):
                comment = f"0x{a:06X}: {marks[a]}" if i == a and a in marks else ""
                lines.append({"comment": comment, "text": ", ".join(_HEX[x] for x in data[i:min(i + LINE_BYTES, b)])})
        chunks.append({"size": end - base, "lines": lines})
    return chunks
