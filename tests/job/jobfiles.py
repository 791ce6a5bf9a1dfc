"""Job files written for the job tests, and their diagnostics as (line, col, message)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from codegen.errors import JobError
from codegen.job import load_job

STEPPERS = """\
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
    y: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
"""


def errors(path: Path, target: str | None = None) -> list[tuple[int, int, str]]:
    with pytest.raises(JobError) as info:
        load_job(path, target)
    return [(d.where.line, d.where.col, d.message) for d in info.value.diagnostics]


def write(tmp_path: Path, text: str, name: str = "job.yaml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path
