"""One input's outcome and its signature. Acceptable: OK (the plan finished), REFUSED (JobError, every
diagnostic at file:line:col), BUILD FAILED (BuildError), LONG (a plan at its time limit that was still planning
at the planner's pace). Failures: traceback, hang, memory, crash, a refusal
without a line:col, a plan whose own checks failed. A failure's signature names the bug, not the input: the
exception type and the innermost codegen frame, the stage a hang was in, a message with its numbers blanked.
The pipeline is `printer-codegen plan JOB --json --quiet` in this process (plan_input)."""

from __future__ import annotations

import contextlib
import io
import json
import re
import signal
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from codegen.cli.main import parser
from codegen.errors import BuildError, JobError
from tests.fuzzing.inputs import FuzzInput

OK, REFUSED, BUILD_FAILED, LONG = "ok", "refused", "build failed", "long"
TRACEBACK, HANG, MEMORY, CRASH, UNPOSITIONED, CHECK = ("traceback", "hang", "memory", "crash", "unpositioned",
                                                       "check")
ACCEPTABLE = (OK, REFUSED, BUILD_FAILED, LONG)
# A plan still going at the time limit with at least this many events planned per second of it is a long job (a
# mutated slicer file's 256 M extruder steps plan in 59 s), not a hang: the planner makes 1-3 M events a second.
LONG_EVENTS_PER_S = 200_000
CODEGEN_FRAME = re.compile(r'File "[^"]*/(codegen/[^"]+)", line \d+,? in (\S+)')
DIGITS = re.compile(r"\d+(\.\d+)?(e[-+]?\d+)?")
PREFIX = 60  # characters of a message kept in a signature
WORK = Path("fuzz-input")  # relative to the worker's own folder (pool.py)


class Hang(BaseException):
    """Raised in a worker at its time limit (a BaseException: no `except Exception` in codegen swallows it)."""


class PlanCheckFailed(Exception):
    """The plan finished but its own checks failed (`plan` exits 1): the tables do not do what the job says."""


@dataclass(frozen=True)
class Outcome:
    kind: str
    signature: str = ""  # empty for the acceptable kinds
    detail: str = ""  # the message or the traceback's last lines

    @property
    def failed(self) -> bool:
        return self.kind not in ACCEPTABLE


def innermost_codegen_frame(text: str) -> str:
    """'codegen/x.py:function' of the innermost codegen frame in a formatted stack (Python's traceback, most
    recent call last, or faulthandler's, most recent call first), or '?'."""
    frames = CODEGEN_FRAME.findall(text)
    if not frames:
        return "?"
    file, function = frames[0] if text.lstrip().startswith(("Fatal", "Timeout", "Current", "Thread")) else frames[-1]
    return f"{file}:{function}"


def blanked(message: str) -> str:
    first = message.strip().splitlines()[0] if message.strip() else ""
    return DIGITS.sub("N", first)[:PREFIX]


def _unpositioned(error: JobError) -> list[str]:
    return [d.message for d in error.diagnostics if d.severity == "error" and d.where.line <= 0]


def _failure(kind: str, error: BaseException, prefix: str) -> Outcome:
    stack = "".join(traceback.format_exception(type(error), error, error.__traceback__))
    return Outcome(kind, f"{prefix} in {innermost_codegen_frame(stack)}", stack[-3000:])


def events_planned(error: BaseException) -> int:
    """The events the interrupted plan had made (codegen/pipeline/host.py `_host_build`'s stages), or 0."""
    for frame, _ in traceback.walk_tb(error.__traceback__):
        if frame.f_code.co_name == "_host_build" and frame.f_locals.get("stages") is not None:
            return frame.f_locals["stages"].totals.events
    return 0


def classify(call: Callable[[], int], time_limit: float = 20.0) -> Outcome:
    """Run `call` (the pipeline on one input; returns the exit code) and name what happened."""
    try:
        code = call()
    except Hang as hang:
        events = events_planned(hang)
        if events >= LONG_EVENTS_PER_S * time_limit:
            return Outcome(LONG, "", f"{events} events planned in {time_limit:g} s")
        return _failure(HANG, hang, "hang")
    except JobError as error:
        try:
            rendered = error.render()  # as the CLI prints it: rendering is part of the path
        except Exception as render_error:  # noqa: BLE001 - a failing diagnostic is a finding like any other
            return _failure(TRACEBACK, render_error, type(render_error).__name__)
        missing = _unpositioned(error)
        if missing:
            return Outcome(UNPOSITIONED, f"unpositioned refusal: {blanked(missing[0])}", rendered[-3000:])
        return Outcome(REFUSED, "", rendered[-500:])
    except BuildError as error:
        return Outcome(BUILD_FAILED, "", str(error)[-500:])
    except PlanCheckFailed as failed:
        return Outcome(CHECK, f"plan check failed: {blanked(str(failed))}", str(failed)[-3000:])
    except MemoryError as error:
        return _failure(MEMORY, error, "MemoryError")
    except Exception as error:  # noqa: BLE001 - any other exception is what the fuzzer looks for
        return _failure(TRACEBACK, error, type(error).__name__)
    return Outcome(OK) if code == 0 else Outcome(CHECK, f"exit code {code}")


def died(exitcode: int | None, dump: str, timed_out: bool) -> Outcome:
    """The outcome of a worker that died (or was killed at its hard deadline); `dump`: its faulthandler output,
    innermost frame first (its head is kept)."""
    stage = innermost_codegen_frame(dump)
    if timed_out or "Timeout (" in dump:
        return Outcome(HANG, f"hang in {stage}", dump[:3000])
    if exitcode is not None and exitcode < 0:
        name = signal.Signals(-exitcode).name
        kind = MEMORY if name == "SIGKILL" else CRASH  # SIGKILL from outside: the kernel's OOM killer
        return Outcome(kind, f"{'killed' if kind == MEMORY else 'crash'} by {name} in {stage}", dump[:3000])
    return Outcome(CRASH, f"worker exited with {exitcode} in {stage}", dump[:3000])


def plan_file(job: Path) -> int:
    """`plan`'s exit code on the job file; JobError and BuildError go to the caller as in main()."""
    args = parser().parse_args(["plan", str(job), "--json", "--quiet"])
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        code = args.handler(args)
    if code == 1:
        problems = json.loads(out.getvalue()).get("problems") or ["plan exited 1"]
        raise PlanCheckFailed("; ".join(problems))
    return code


def plan_input(item: FuzzInput) -> int:
    """The input written to ./fuzz-input/ and planned."""
    for old in WORK.glob("*"):
        old.unlink()
    return plan_file(item.write(WORK))
