"""How long main's loop in the streaming ATmega2560 firmware holds interrupts off, read from the generated assembly.

A step interrupt whose compare match comes while main has interrupts off waits until they are back on; with the
link's interrupt in the way too, that is its pulse's worst latency, which the plan's rate budget counts on
(codegen/targets.py: pulse_jitter_s, the target file's main_cli_cycles). This walks every path of main's idle loop
(player_run from its first SLEEP: templates/avr/player_isr/run.S.j2, and what it calls: link_status, link_window,
hold_poll), following branches, skips, jumps, calls and returns, and adds up each instruction's cycles on the
ATmega2560 (22-bit PC: RCALL 4, CALL 5, RET 5) from every CLI to where interrupts are back: an SEI and the
instruction after it (which runs before any interrupt); a SLEEP with interrupts off halts (the job is done). A loop with interrupts off is an error, as is an instruction
it does not know. Two calls are not walked into: heaters_hook (its own figure, heater_check_cycles: it runs a heater
stage only when the next step event is far enough away) and heaters_hold_hook (a WAIT record has stopped the timer:
no pulse is due while it runs); a jump to heaters_after_table ends the walk (the job is done).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig
from codegen.targets import target_info

ONE = {"add", "adc", "sub", "subi", "sbc", "sbci", "and", "andi", "or", "ori", "eor", "com", "neg", "sbr", "cbr", "inc",
       "dec", "tst", "clr", "ser", "cp", "cpc", "cpi", "mov", "movw", "ldi", "in", "out", "bst", "bld", "lsl", "lsr",
       "rol", "ror", "asr", "swap", "nop", "sec", "clc", "set", "clt", "sei", "cli", "sleep", "wdr"}
TWO = {"lds", "sts", "ld", "st", "ldd", "std", "push", "pop", "sbi", "cbi", "rjmp", "adiw", "sbiw", "mul", "muls",
       "mulsu"}
CALLS = {"rcall": 4, "call": 5}
SKIPS = {"sbrc", "sbrs", "sbic", "sbis", "cpse"}
TWO_WORDS = {"lds", "sts", "call", "jmp"}  # a skip over one of these takes 3 cycles
RETURN = 5
OPAQUE = {"heaters_hook"}  # not walked into: called with interrupts on, its own figure
ENDS = {"heaters_hold_hook"}  # the timer stands while it runs
DONE = {"heaters_after_table"}  # the job is done: the heaters' own loop (heaters.c)
LINE = re.compile(r"^\s*(?:(?P<label>[.\w]+):)?\s*(?P<op>[a-z]+)?\s*(?P<args>[^;]*?)\s*(?:;.*)?$")


@dataclass(frozen=True)
class Instruction:
    op: str
    args: str
    where: str  # file:line, for messages


@dataclass(frozen=True)
class Stretch:
    cycles: int
    where: str  # the CLI that starts it


def parse(sources: dict[str, str]) -> tuple[list[Instruction], dict[str, int], list[tuple[str, int]]]:
    """The instructions of the sources in order, their labels (name -> index) and the numeric local labels."""
    code: list[Instruction] = []
    labels: dict[str, int] = {}
    local: list[tuple[str, int]] = []
    for name, text in sources.items():
        text = re.sub(r"/\*.*?\*/", lambda m: "\n" * m[0].count("\n"), text, flags=re.S)  # lines kept
        for number, line in enumerate(text.splitlines(), 1):
            if line.lstrip().startswith(("#", ".")) and ":" not in line.split(";")[0]:
                continue  # preprocessor lines and directives
            match = LINE.match(line)
            if match is None:
                continue
            label, op = match["label"], match["op"]
            if label:
                (local.append((label, len(code))) if label.isdigit() else labels.__setitem__(label, len(code)))
            if op:
                code.append(Instruction(op, match["args"], f"{name}:{number}"))
    return code, labels, local


def longest_stretch(sources: dict[str, str]) -> Stretch:
    """The longest interrupts-off stretch of main's idle loop in an image's sources (file name -> text:
    player_isr.S, and a streaming image's link_tx.S)."""
    code, labels, local = parse({name: sources[name] for name in ("player_isr.S", "link_tx.S") if name in sources})

    def target(arg: str, at: int) -> int:
        name = arg.split(",")[-1].strip()
        if name[:-1].isdigit() and name[-1] in "fb":
            spots = [i for label, i in local if label == name[:-1]]
            found = [i for i in spots if i > at] if name[-1] == "f" else [i for i in spots if i <= at]
            if not found:
                raise BuildError(f"{code[at].where}: no label {name}")
            return found[0] if name[-1] == "f" else found[-1]
        if name not in labels:
            raise BuildError(f"{code[at].where}: no label {name}")
        return labels[name]

    def cost(i: int) -> int:
        op = code[i].op
        if op in ONE or op in SKIPS or op.startswith("br"):
            return 1
        if op in TWO:
            return 2
        if op in CALLS:
            return CALLS[op]
        if op in ("ret", "reti"):
            return RETURN
        if op == "jmp":
            return 3
        raise BuildError(f"{code[i].where}: `{op}` is not an instruction the interrupts-off walk knows")

    def successors(i: int, stack: tuple) -> list[tuple[int, tuple, int]]:
        """Where execution goes after instruction i: (next instruction, return stack, cycles of i that way);
        [] where the walk ends (halted, the job done, player_run returned)."""
        ins = code[i]
        op, arg = ins.op, ins.args.strip()
        if op in CALLS:
            if arg in OPAQUE or arg in ENDS:
                return [(i + 1, stack, CALLS[op])]
            return [(target(arg, i), stack + (i + 1,), CALLS[op])]
        if op in ("ret", "reti"):
            return [(stack[-1], stack[:-1], RETURN)] if stack and op == "ret" else []
        if op in ("rjmp", "jmp"):
            return [] if arg in DONE else [(target(arg, i), stack, cost(i))]
        if op.startswith("br"):  # taken: 2 cycles, else 1
            return [(target(arg, i), stack, 2), (i + 1, stack, 1)]
        if op in SKIPS:  # skipping: 2 cycles, or 3 over a two-word instruction
            return [(i + 2, stack, 3 if code[i + 1].op in TWO_WORDS else 2), (i + 1, stack, 1)]
        return [(i + 1, stack, cost(i))]

    memo: dict[tuple, tuple[int, frozenset]] = {}
    walking: set = set()

    def off(i: int, stack: tuple) -> tuple[int, frozenset]:
        """With interrupts off at instruction i: the most cycles until they are back on, and where main goes on
        with them on (instruction, return stack)."""
        key = (i, stack)
        if key in memo:
            return memo[key]
        if key in walking:
            raise BuildError(f"{code[i].where}: a loop with interrupts off")
        walking.add(key)
        op, arg = code[i].op, code[i].args.strip()
        if op == "sei":  # and the instruction after it, which runs before any interrupt (a taken branch: 2)
            found = (1 + max(cost(i + 1), 2), frozenset({(i + 1, stack)}))
        elif op in CALLS and arg in OPAQUE:
            raise BuildError(f"{code[i].where}: {arg} called with interrupts off")
        elif op in CALLS and arg in ENDS:  # it returns with interrupts on
            found = (CALLS[op], frozenset({(i + 1, stack)}))
        elif op == "sleep":
            found = (0, frozenset())  # halted: the job is done
        else:
            most, exits = 0, set()
            for j, after, cycles in successors(i, stack):
                rest, more = off(j, after)
                most, exits = max(most, cycles + rest), exits | more
            found = (most, frozenset(exits))
        walking.discard(key)
        memo[key] = found
        return found

    best = Stretch(0, "")
    seen: set = set()
    start = labels["player_run"]
    todo = [(next(i for i in range(start, len(code)) if code[i].op == "sleep"), ())]  # after the player's set-up
    while todo:
        i, stack = todo.pop()
        if (i, stack) in seen:
            continue
        seen.add((i, stack))
        if code[i].op == "cli":
            cycles, exits = off(i + 1, stack)
            if exits and 1 + cycles > best.cycles:  # (a stretch with no way out halts: the job is done)
                best = Stretch(1 + cycles, code[i].where)
            todo += exits
        else:
            todo += [(j, after) for j, after, _ in successors(i, stack)]
    return best

def check_interrupts_off(sources: dict[str, str], config: FirmwareConfig, stream: bool) -> None:
    """BuildError when main's loop holds interrupts off longer than the plan's budget counts on (the target's
    main_cli_cycles in a streaming image, hold_poll_cycles with feed hold, heater_check_cycles with heaters)."""
    costs = target_info(config.board, stream=stream, laser=config.laser is not None,
                        hold=config.hold is not None).mcu_data
    allowed = max(int(costs.get("main_cli_cycles", 0)) if stream else 0,
                  int(costs.get("hold_poll_cycles", 0)) if config.hold is not None else 0,
                  int(costs.get("heater_check_cycles", 0)) if config.heaters and not stream else 0)
    stretch = longest_stretch(sources)
    if stretch.cycles > allowed:
        raise BuildError(f"main holds interrupts off for {stretch.cycles} cycles from {stretch.where}: the plan's "
                         f"rate budget counts on at most {allowed} (targets/{costs.get('name', 'atmega2560')}.yaml)")
