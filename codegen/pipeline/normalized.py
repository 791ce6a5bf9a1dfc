"""The job as the loader holds it, every default filled in (`printer-codegen config` prints it as YAML), and the
fingerprint of what an image was built from: `build` writes it into report.json and `flash` compares it."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from codegen import __version__
from codegen.job.schema import HEATERS, Job
from codegen.paths import targets_dir
from codegen.pipeline.settings import homing_settings
from codegen.targets import target_info


class LiteralText(str):
    """Inline G-code: printed as a `|` block, which the loader reads as G-code rather than a file name."""


class Section(dict):
    """A mapping printed as a block whatever it holds (`program:`)."""


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
    elif gcode_file(job) is not None:
        out["gcode"] = program.gcode  # relative to the job file, as written
    else:
        out["gcode"] = LiteralText(program.gcode)
    return Section(out)


def _shape(shape) -> dict:
    """A shape as the job file writes it: {kind: its keys}; a `points` shape is its list alone."""
    body = shape.model_dump(mode="json", by_alias=True, exclude_none=True)  # no feed or z: the program's
    return {shape.kind: body["points"] if shape.kind == "points" else body}


def gcode_file(job: Job) -> Path | None:
    """The G-code file the program names, None for inline G-code (the rule of codegen.gcode._source)."""
    gcode = job.program.gcode if job.program is not None else None
    if gcode is None or "\n" in gcode or not (job.path.parent / gcode).is_file():
        return None
    return job.path.parent / gcode


def job_fingerprint(job: Job, stream_baud: int | None = None) -> str:
    """What an image was built from: printer-codegen's version, the normalized job, the board's and MCU's files
    and the G-code file's bytes. With `stream_baud` (the streaming firmware's link, 0: the target's), that of a
    streaming firmware, which plays any program of the machine: only `program.home` of the program counts,
    and the baud rate does."""
    document = normalized_job(job)
    gcode = gcode_file(job)
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
