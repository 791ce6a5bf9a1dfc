"""An 8051 board's pins and memories from its targets/<board>.yaml file and its MCU's: motors, tool, held pins."""

from __future__ import annotations

import re
from dataclasses import dataclass

from codegen.errors import BuildError
from codegen.firmware.config import FirmwareConfig, board_socket, load_target

SFR = {0: 0x80, 1: 0x90, 2: 0xA0, 3: 0xB0}  # each port's SFR address (P0 to P3)


@dataclass(frozen=True)
class Pin:
    name: str  # P1.0
    port: int  # 1
    bit: int  # 0

    @property
    def sfr(self) -> str:
        return f"P{self.port}"

    @property
    def mask(self) -> int:
        return 1 << self.bit

    @property
    def var(self) -> str:
        return f"p{self.port}"


def parse_pin(text: str) -> Pin:
    match = re.fullmatch(r"P([0-3])\.([0-7])", str(text).strip())
    if not match:
        raise BuildError(f"bad 8051 pin `{text}` in a board file (expected e.g. P1.0)")
    return Pin(match.group(0), int(match.group(1)), int(match.group(2)))


def board_data(board: str) -> tuple[dict, dict]:
    """The board file and its MCU file (the same file for a one-file MCU+board such as at89c52)."""
    data = load_target(board)
    if data.get("target") != "mcs51":
        raise BuildError(f"board {board} is not an mcs51 board (target: {data.get('target')})")
    return data, load_target(data["mcu"])


def memories(board: str) -> dict[str, int | str]:
    """Code, internal RAM and XRAM sizes and the memory model (the board may add external RAM)."""
    data, mcu = board_data(board)
    xram = int(data.get("xram", mcu.get("xram", 0)))
    model = data.get("memory_model", mcu.get("memory_model", "large" if xram else "small"))
    return {"flash": int(mcu["flash"]), "iram": int(mcu["ram"]), "xram": xram, "model": model,
            "mcu": data["mcu"], "f_cpu": int(mcu["f_cpu"]), "tick_hz": int(mcu["tick_hz"])}


def board_pins(config: FirmwareConfig) -> dict:
    """Every pin the image drives, by role: motors (step, dir, enable, invert), tool, held pins."""
    board, _ = board_data(config.board)
    motors = []
    for m in config.motors:
        s = board_socket(config.board, board, m)
        if "coils" in s:
            coils = [parse_pin(c) for c in s["coils"] or []]
            if len(coils) != 4:
                raise BuildError(f"board {config.board}: socket {m.socket} needs 4 coil pins (has {len(coils)})")
            motors.append({"name": m.name, "socket": m.socket, "coils": coils, "step": None, "dir": None,
                           "enable": None, "invert": m.invert_dir})
            continue
        motors.append({"name": m.name, "socket": m.socket, "step": parse_pin(s["step"]), "dir": parse_pin(s["dir"]),
                       "enable": parse_pin(s["enable"]), "invert": m.invert_dir, "coils": None})
    held = [{"pin": parse_pin(h["pin"]), "level": 1 if h["level"] == "high" else 0, "what": h.get("what", "")}
            for h in board.get("held_pins") or []]
    tool = parse_pin(board["tool"]["pin"])
    # Every STEP, DIR, tool and held pin is its own (motors may share an enable pin).
    uses: dict[str, list[str]] = {}
    roles = [(f"{m['name']} {kind.upper()}", m[kind]) for kind in ("step", "dir") for m in motors if m[kind]]
    roles += [(f"{m['name']} coil {i + 1}", c) for m in motors for i, c in enumerate(m["coils"] or [])]
    for role, pin in roles + [("tool", tool)] + [("held", h["pin"]) for h in held]:
        uses.setdefault(pin.name, []).append(role)
    for m in motors:
        if m["enable"]:
            uses.setdefault(m["enable"].name, []).append("enable")
    clash = {name: roles for name, roles in uses.items() if len(roles) > 1 and set(roles) != {"enable"}}
    if clash:
        raise BuildError(f"board {config.board}: pins used twice: "
                         + "; ".join(f"{name} ({', '.join(roles)})" for name, roles in sorted(clash.items())))
    # A coil port is rewritten whole at each event: nothing else on it may change while the player runs.
    coil_ports = {c.port for m in motors for c in m["coils"] or []}
    moving = [(f"{m['name']} {kind.upper()}", m[kind]) for kind in ("step", "dir") for m in motors if m[kind]]
    moving.append(("tool", tool))
    lcd = board.get("lcd") or {}
    moving += [(f"LCD {k}", parse_pin(v)) for k, v in lcd.items() if k in ("rs", "e", "rw") and v]
    moving += [("LCD data", parse_pin(v)) for v in lcd.get("data") or []]
    bad = [f"{pin.name} ({role})" for role, pin in moving if pin.port in coil_ports]
    if bad:
        raise BuildError(f"board {config.board}: coil pins share their port with pins that change while the player "
                         f"runs: {', '.join(bad)} (coil ports: {', '.join(f'P{p}' for p in sorted(coil_ports))})")
    if coil_ports and config.homing:
        raise BuildError(f"board {config.board}: homing is not supported with coil-driven motors")
    return {"motors": motors, "tool": tool,
            "tool_active_high": bool(board["tool"]["active_high"]),
            "enable_active_low": bool(board["enable_active_low"]), "held": held}
