"""`printer-codegen plan JOB --json --quiet` in this process: the CLI's own parser and handler (codegen/cli/main.py
cmd_plan), its output captured, a failed plan's problems raised as PlanCheckFailed."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

from codegen.cli.main import parser
from tests.fuzzing.inputs import FuzzInput
from tests.fuzzing.outcomes import PlanCheckFailed

WORK = Path("fuzz-input")  # relative to the worker's own folder (pool.py)


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
