"""The job file: load it, validate it, report every problem like a compiler.

    from codegen.job import load_job
    job = load_job(Path("shape.yaml"), target_override=None)   # a Job, or JobError with every diagnostic

Nothing is written to disk. See /work/shared/JOB-FORMAT.md for the format and README for the added keys.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import yaml
from pydantic import ValidationError

from codegen.errors import Diagnostic, JobError, SourceRef, suggest
from codegen.job.expr import Expr, ExprError, parse
from codegen.job.loader import cross_check, translate
from codegen.job.reading import Marks, read_yaml
from codegen.job.schema import (DEFAULT_BOARDS, KINEMATICS, MOTORS, SHAPES, TARGETS, Arc, Circle, Delta, Ellipse,
                                Function, Job, Line, Machine, Points, Polyline, Program, Shape, Sine, Stepper, Travel)
from codegen.targets import board_heater_pins

__all__ = [
    "load_job", "board_targets", "Job", "Machine", "Stepper", "Delta", "Program", "Shape", "SHAPES",
    "Line", "Polyline", "Points", "Arc", "Circle", "Ellipse", "Sine", "Function", "Travel",
    "Expr", "ExprError", "parse", "TARGETS", "DEFAULT_BOARDS", "KINEMATICS", "MOTORS",
]


def board_targets() -> dict[str, str]:
    """Every board file in targets/ that names its target: board name (the file's stem) -> target."""
    from codegen.paths import targets_dir

    folder = targets_dir()
    files = tuple(sorted((f.name, f.stat().st_mtime_ns) for f in folder.glob("*.yaml")))
    return dict(_board_targets(str(folder), files))


@lru_cache(maxsize=8)
def _board_targets(folder: str, files: tuple[tuple[str, int], ...]) -> tuple[tuple[str, str], ...]:
    """Read once per state of the folder (`files`: names and modification times): PyYAML read the eight board
    files in 0.27 s, on every job loaded."""
    boards = []
    for name, _ in files:
        try:
            doc = yaml.safe_load((Path(folder) / name).read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, yaml.YAMLError):
            continue
        if isinstance(doc, dict) and isinstance(doc.get("target"), str):
            boards.append((Path(name).stem, doc["target"]))
    return tuple(boards)


def _check_board(data: dict, target: str, marks: Marks) -> list[Diagnostic]:
    """`<board>.yaml` must exist in targets/ with `target: <target>`. While targets/ has no board of that
    target at all, only a board of another target is an error (the build says the target is missing)."""
    boards = board_targets()
    valid = sorted(b for b, t in boards.items() if t == target)
    board = data.get("board", DEFAULT_BOARDS[target])
    if not isinstance(board, str) or board in valid or (not valid and board not in boards):
        return []
    listed = f"; {target} boards: {', '.join(valid)}" if valid else f"; there is no {target} board yet"
    if "board" not in data:
        where = marks.value(("target",)) if "target" in data else SourceRef(marks.file)
        return [Diagnostic(where, f"board: the default board '{board}' of target {target} is missing{listed}")]
    if board in boards:
        message = f"board: '{board}' is a board for target {boards[board]}, not {target}{listed}"
    else:
        message = f"board: unknown board '{board}' for target {target}{suggest(board, valid)}{listed}"
    return [Diagnostic(marks.value(("board",)), message)]


def _check_heaters(job: Job, marks: Marks) -> list[Diagnostic]:
    """Every heater of `machine.heaters` is one of the board's heater outputs (the 8051 boards have none)."""
    outputs = board_heater_pins(job.board)
    has = f"its heaters: {', '.join(outputs)}" if outputs else "it has no heater outputs"
    return [Diagnostic(marks.key(("machine", "heaters", name)), f"machine.heaters: board '{job.board}' has no {name} "
                                                                 f"heater ({has})")
            for name in job.machine.heaters or {} if name not in outputs]


def _inline_gcode(gcode: str, marks: Marks) -> bool:
    """G-code written in the job file (a block scalar, or several lines) rather than a file name."""
    style = marks.styles.get(("program", "gcode"), (None, True))[0]
    return style in ("|", ">") or "\n" in gcode.strip()


def _check_gcode_file(job: Job, path: Path, marks: Marks) -> list[Diagnostic]:
    gcode = None if job.program is None else job.program.gcode
    if gcode is None or _inline_gcode(gcode, marks):
        return []
    where = marks.value(("program", "gcode"))
    try:
        if (path.parent / gcode).is_file():
            return []
    except (OSError, ValueError) as e:  # a name too long for the file system, a NUL in it
        reason = getattr(e, "strerror", None) or str(e)
        return [Diagnostic(where, f"program.gcode: cannot read '{_shortened(gcode)}': {reason} (G-code written "
                                  f"in the job goes in a block scalar, `gcode: |`)")]
    return [Diagnostic(where, f"program.gcode: no such file '{_shortened(gcode)}'")]


def _shortened(text: str, most: int = 60) -> str:
    return text if len(text) <= most else text[:most] + "..."


def _validate(data: dict) -> Job:
    """Job.model_validate by the file's key names only (`from`, not the attribute name `from_`)."""
    try:
        return Job.model_validate(data, by_name=False)
    except TypeError:  # pydantic < 2.11 has no by_name: `from_` is then accepted too
        return Job.model_validate(data)


def load_job(path: Path, target_override: str | None = None, program_required: bool = True) -> Job:
    """Read and validate a job file.

    Returns a `Job` with the defaults filled in (name: the file's stem; target: avr unless `target_override`;
    board: per target), `job.path` absolute, every shape's `source` at its kind key, and `program.gcode_source`
    at the G-code (its first line when inline). Raises `JobError` carrying every diagnostic of the file,
    sorted by position: YAML syntax (one diagnostic), unknown and missing keys, wrong values, cross-key rules,
    the board, a G-code file that does not exist. Without `program_required` (a streaming firmware is the
    machine's), the program may be missing.
    """
    path = Path(path)
    if target_override is not None and target_override not in TARGETS:
        message = f"'{target_override}' is not one of {', '.join(TARGETS)}{suggest(target_override, TARGETS)}"
        raise JobError([Diagnostic(SourceRef("--target"), message)])
    data, marks, diagnostics = read_yaml(path)
    read_problems = list(diagnostics)
    if not isinstance(data, dict):
        message = "expected a mapping with the keys machine and program (and optionally name, target, board)"
        raise JobError(diagnostics + [Diagnostic(marks.value(()), message)])
    data = {"name": path.stem, **data}
    if target_override is not None:
        data["target"] = target_override
    job = None
    try:
        job = _validate(data)
    except ValidationError as e:
        diagnostics += translate(e.errors(), marks)
    diagnostics += cross_check(data, marks)
    if program_required and "program" not in data:
        diagnostics.append(Diagnostic(marks.mapping(()), "missing key 'program' (only `build --stream` goes "
                                                         "without one)"))
    elif program_required and data["program"] is None:
        diagnostics.append(Diagnostic(marks.value(("program",)), "program: expected a mapping with `shapes` or "
                                                                 "`gcode` (only `build --stream` goes without one)"))
    board_problems = _check_board(data, data.get("target", "avr"), marks) if data.get("target", "avr") in TARGETS \
        else []
    diagnostics += board_problems
    if job is not None:
        diagnostics += _check_gcode_file(job, path, marks)
        diagnostics += [] if board_problems else _check_heaters(job, marks)
    if diagnostics or job is None:  # a value YAML could not build has its message from the reading alone
        later = [d for d in diagnostics[len(read_problems):] if (d.where.line, d.where.col) not in marks.unbuilt]
        diagnostics = read_problems + later
        unique = {(d.where.line, d.where.col, d.message): d for d in diagnostics}
        raise JobError(sorted(unique.values(), key=lambda d: (d.where.line, d.where.col)))
    job.path = path.resolve()
    for name, stepper in job.machine.steppers.items():
        stepper.steps_source = marks.value(("machine", "steppers", name, "steps_per_mm"))
    if job.program is None:
        return job
    for i, shape in enumerate(job.program.shapes or ()):
        shape.source = marks.key(("program", "shapes", i, shape.kind))
    if "start" in job.program.model_fields_set:
        job.program.start_source = marks.value(("program", "start"))
    gcode = job.program.gcode
    if gcode is not None:
        where = ("program", "gcode")
        job.program.gcode_source = marks.block(where) if _inline_gcode(gcode, marks) else marks.value(where)
    return job
