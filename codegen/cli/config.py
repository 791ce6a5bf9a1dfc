"""`printer-codegen config JOB`: the job as the loader holds it, every default filled in, printed as YAML (as
ESPHome's `config`), followed by `board_info:`, the board's pins for this job. Everything above `board_info:`
loads back as the same job (the normalized job: codegen/pipeline/normalized.py)."""

from __future__ import annotations

from pathlib import Path

import yaml

from codegen.firmware.config import MotorPins, board_socket
from codegen.job import load_job
from codegen.job.schema import Job
from codegen.kinematics import make_kinematics
from codegen.pipeline.normalized import LiteralText, Section, normalized_job
from codegen.program.homing import AXES
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
_Dumper.add_representer(Section, lambda d, mapping: d.represent_mapping("tag:yaml.org,2002:map", mapping, False))
_Dumper.add_representer(LiteralText, lambda d, text: d.represent_scalar("tag:yaml.org,2002:str", text, style="|"))


def config_yaml(job: Job) -> str:
    """The normalized job and `board_info:`, as YAML in a fixed key order."""
    return job_yaml({**normalized_job(job), "board_info": board_info(job)})


def job_yaml(document: dict) -> str:
    """A job file's keys as YAML in their order, as `config` prints them (a stepper on one line)."""
    return yaml.dump(document, Dumper=_Dumper, sort_keys=False, default_flow_style=False, allow_unicode=True,
                     width=120)


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
