"""`printer-codegen config JOB`: the job as the loader holds it, every default filled in, printed as YAML (as
ESPHome's `config`), followed by `board_info:`, the board's pins for this job. Everything above `board_info:`
loads back as the same job. `job_fingerprint` hashes the same normalized job: `build` writes it into report.json
and `flash` compares it (codegen/cli/flash.py)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import yaml

from codegen import __version__
from codegen.firmware.config import MotorPins, board_socket
from codegen.program.homing import AXES
from codegen.pipeline.settings import homing_settings
from codegen.job import load_job
from codegen.job.schema import HEATERS, Job
from codegen.kinematics import make_kinematics
from codegen.paths import targets_dir
from codegen.targets import target_info

# The board file's keys shown under board_info.pins after the motors' sockets and switches, in this order.
BOARD_PIN_KEYS = ("tool", "laser_pwm", "heaters", "fan", "jog_keys", "hold_keys", "link", "lcd", "held_pins")
FLOW_KEYS = 6  # a mapping of at most this many values, none a mapping, on one line, as job files write steppers
MCS51_UART = {"rx": "P3.0", "tx": "P3.1"}  # the 8051's one UART has fixed pins (RXD, TXD): no board file names them


def add_parser(verbs) -> None:
    v = verbs.add_parser("config", help="print the job with every default filled in, and the board's pins, as YAML",
                         description="Print the job as the loader holds it, every default filled in (null: decided "
                                     "by the target, board or program), then board_info: the board's pins for this "
                                     "job. Everything above board_info: loads back as the same job.")
    v.set_defaults(handler=cmd_config)
    v.add_argument("job", help="the job file (YAML)")
    v.add_argument("--target", choices=("avr", "mcs51"), help="override the job's target")


def cmd_config(args) -> int:
    job = load_job(Path(args.job), args.target, program_required=False)  # a machine alone is a `build --stream` job
    print(config_yaml(job), end="")
    return 0


class _LiteralText(str):
    """Inline G-code: printed as a `|` block, which the loader reads as G-code rather than a file name."""


class _Section(dict):
    """A mapping printed as a block whatever it holds (`program:`)."""


class _Dumper(yaml.SafeDumper):
    def ignore_aliases(self, data) -> bool:
        return True  # the board file's shared values printed in full each time, no &anchors


def _plain(items) -> bool:
    return not any(isinstance(item, (list, dict)) for item in items)


def _list(dumper: yaml.SafeDumper, items: list) -> yaml.Node:
    return dumper.represent_sequence("tag:yaml.org,2002:seq", items, flow_style=_plain(items))  # a point: [x, y]


def _mapping(dumper: yaml.SafeDumper, mapping: dict) -> yaml.Node:
    flat = len(mapping) <= FLOW_KEYS and all(_plain(v) if isinstance(v, list) else not isinstance(v, dict)
                                             for v in mapping.values())
    return dumper.represent_mapping("tag:yaml.org,2002:map", mapping, flow_style=flat)  # a stepper on one line


_Dumper.add_representer(list, _list)
_Dumper.add_representer(dict, _mapping)
_Dumper.add_representer(_Section, lambda d, mapping: d.represent_mapping("tag:yaml.org,2002:map", mapping, False))
_Dumper.add_representer(_LiteralText, lambda d, text: d.represent_scalar("tag:yaml.org,2002:str", text, style="|"))


def config_yaml(job: Job) -> str:
    """The normalized job and `board_info:`, as YAML in a fixed key order."""
    document = {**normalized_job(job), "board_info": board_info(job)}
    return yaml.dump(document, Dumper=_Dumper, sort_keys=False, default_flow_style=False, allow_unicode=True,
                     width=120)


def normalized_job(job: Job) -> dict:
    """The job's keys as the models hold them after loading (JSON types, the file's key names). A key without a
    default of its own (decided by the board, the target or the program, e.g. `link.baud`) is null."""
    machine = job.machine.model_dump(mode="json", by_alias=True)
    machine["steppers"] = {name: machine["steppers"][name] for name in job.machine.motor_names}
    if machine["heaters"] is not None:
        machine["heaters"] = {name: machine["heaters"][name] for name in HEATERS if name in machine["heaters"]}
    out = {"name": job.name, "target": job.target, "board": job.board, "machine": machine}
    if job.program is not None:
        out["program"] = _program(job)
    return out


def _program(job: Job) -> dict:
    program = job.program
    out = program.model_dump(mode="json", by_alias=True, exclude={"shapes", "gcode"})
    if "start" not in program.model_fields_set and homing_settings(job).always:
        del out["start"]  # where a machine homes, a `start` given adds a travel move from home (codegen/program/program.py)
    if program.shapes is not None:
        out["shapes"] = [_shape(shape) for shape in program.shapes]
    elif _gcode_file(job) is not None:
        out["gcode"] = program.gcode  # relative to the job file, as written
    else:
        out["gcode"] = _LiteralText(program.gcode)
    return _Section(out)


def _shape(shape) -> dict:
    """A shape as the job file writes it: {kind: its keys}; a `points` shape is its list alone."""
    body = shape.model_dump(mode="json", by_alias=True, exclude_none=True)  # no feed or z: the program's
    return {shape.kind: body["points"] if shape.kind == "points" else body}


def _gcode_file(job: Job) -> Path | None:
    """The G-code file the program names, None for inline G-code (the rule of codegen.gcode._source)."""
    gcode = job.program.gcode if job.program is not None else None
    if gcode is None or "\n" in gcode or not (job.path.parent / gcode).is_file():
        return None
    return job.path.parent / gcode


def board_info(job: Job) -> dict:
    """The board's name, MCU and clock, and its pins for this job: each motor's socket, the switches the machine
    homes to (whether or not this program homes), then what the board file wires (tool, laser PWM, heaters, fan,
    jog and hold keys, link, display, held pins)."""
    target = target_info(job.board)
    board = target.board_data
    kin = make_kinematics(job.machine)
    steppers = {name: {"socket": kin.socket(name), **board_socket(job.board, board, MotorPins(name, kin.socket(name)))}
                for name in kin.motors}
    pins = {"steppers": steppers, "enable_active_low": board.get("enable_active_low")}
    switches = [switch for switch, _, motors, _ in AXES[job.machine.kinematics] if set(motors) <= set(kin.motors)]
    endstops = {switch: board["endstops"][switch] for switch in switches if switch in board.get("endstops", {})}
    if endstops:
        pins["endstops"] = endstops
    for key in BOARD_PIN_KEYS:
        if key in board:
            pins[key] = board[key]
    if target.target == "mcs51":
        pins.setdefault("link", MCS51_UART)
    return {"name": target.board, "mcu": target.mcu, "target": target.target, "f_cpu": target.f_cpu,
            "flash_bytes": target.flash_bytes, "ram_bytes": target.ram_bytes, "pins": pins}


def job_fingerprint(job: Job, stream_baud: int | None = None) -> str:
    """What an image was built from: printer-codegen's version, the normalized job, the board's and MCU's files
    and the G-code file's bytes. With `stream_baud` (the streaming firmware's link, 0: the target's), that of a
    streaming firmware, which plays any program of the machine: only `program.home` of the program counts
    (codegen/streaming.stream_homes), and the baud rate does."""
    document = normalized_job(job)
    gcode = _gcode_file(job)
    if stream_baud is not None:
        program = document.pop("program", None)
        document["stream"] = {"home": bool(program and program["home"]), "baud": stream_baud}
        gcode = None
    target = target_info(job.board)
    digest = hashlib.sha256()
    parts = [__version__.encode(), json.dumps(document, sort_keys=True).encode(),
             (targets_dir() / f"{target.board}.yaml").read_bytes(), (targets_dir() / f"{target.mcu}.yaml").read_bytes()]
    if gcode is not None:
        parts.append(gcode.read_bytes())
    for part in parts:
        digest.update(len(part).to_bytes(8, "little") + part)  # length-prefixed: no two part lists hash alike
    return digest.hexdigest()
