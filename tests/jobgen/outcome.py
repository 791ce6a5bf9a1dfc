"""A whole random job file's text (`jobs`), and the invariant the property tests hold it to (`outcome`)."""

from __future__ import annotations

import re
from pathlib import Path

from hypothesis import strategies as st

from codegen.errors import BuildError, JobError
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.tables.format import stream_bytes
from codegen.verify.chapters import whole_chapter
from codegen.verify.program_check import ProgramCheck
from tests.jobgen.gcode import gcode
from tests.jobgen.machines import machines, mixed, num, point
from tests.jobgen.shapes import points, shape


@st.composite
def jobs(draw, kinematics: str, target: str, issue29: bool = True):
    """A whole job file's text; `issue29`: with input shapers, pressure advance, M593, M900 and M572 (machines.py,
    gcode.py)."""
    machine = draw(machines(kinematics, issue29))
    box = machine.box
    program = ["program:"]
    if draw(st.integers(0, 3)) == 0:
        start = draw(points(box, full=box.delta))[0]
        program.append(f"  start: {point(start)}")
    if kinematics != "delta" and draw(st.integers(0, 9)) == 4:
        program.append("  home: true")
    if draw(st.booleans()):
        program.append(f"  feed: {num(draw(mixed([120, 600, 1500, 6000, 30000], 30, 30000)))}")
    if draw(st.integers(0, 3)) == 0:
        program.append(f"  travel_feed: {num(draw(mixed([600, 3000, 12000], 60, 60000)))}")
    if draw(st.integers(0, 2)) == 0:
        program.append("  gcode: |")
        program += ["    " + line for line in draw(gcode(machine, issue29)).splitlines()]
    else:
        program.append("  shapes:")
        program += ["    " + draw(shape(box)) for _ in range(draw(st.integers(1, 3)))]
    return "\n".join(["name: prop", f"target: {target}", machine.text, *program]) + "\n"


# ---- the invariant ----

class Bug(AssertionError):
    """A job the loader accepted that neither built with every check passing nor was refused cleanly.
    `classes`: the failure's message classes (numbers blanked), one per problem."""

    def __init__(self, message: str, classes: list[str]):
        super().__init__(message)
        self.classes = classes


def message_class(text: str) -> str:
    """A message with its numbers, quoted names and file names blanked: one class per kind of message."""
    text = re.sub(r"/\S+\.yaml", "FILE", text)
    text = re.sub(r" \(y = .*", "", text)  # the function's expression
    text = re.sub(r"\b(motor|carriage|axis) \w\b", r"\1 M", text)
    text = re.sub(r"[-+]?\d+(\.\d+)?(e[-+]?\d+)?", "#", text)
    return re.sub(r"\s+", " ", text).strip()[:160]


def _positioned(err: JobError) -> bool:
    return bool(err.diagnostics) and all(d.where.file and d.where.line > 0 and d.where.col > 0
                                         for d in err.diagnostics)


def outcome(text: str, folder: Path) -> str:
    """Run one job through the loader and the host build (as `printer-codegen build` does, without compiling).
    Returns 'built', 'invalid: <class>' (the loader refused it), 'refused: <class>' (a positioned error from the
    build) or 'too big'; raises Bug for anything else."""
    path = folder / "job.yaml"
    path.write_text(text)
    try:
        job = load_job(path)
    except JobError as err:
        if not _positioned(err):
            raise Bug(f"loader error without file:line:col: {err.diagnostics}",
                      ["unpositioned loader error: " + message_class(d.message) for d in err.diagnostics])
        return "invalid: " + message_class(err.diagnostics[0].message)
    try:
        host = host_build(job)
    except JobError as err:
        if not _positioned(err):
            raise Bug(f"error without file:line:col: {err.diagnostics}",
                      ["unpositioned error: " + message_class(d.message) for d in err.diagnostics])
        return "refused: " + message_class(err.diagnostics[0].message)
    except BuildError as err:
        if "fit" in str(err):
            return "too big"
        raise Bug(f"BuildError not about size: {err}", ["BuildError: " + message_class(str(err))])
    except Exception as err:  # noqa: BLE001 - any other exception is a bug
        import traceback

        frame = traceback.extract_tb(err.__traceback__)[-1]
        where = f"{Path(frame.filename).name}:{frame.name}"
        raise Bug(f"{type(err).__name__} in {where}: {err}",
                  [f"{type(err).__name__} in {where}: " + message_class(str(err))]) from err
    f = host.findings
    if not f.ok:
        raise Bug("a check failed: " + "; ".join(f.problems), [message_class(p) for p in f.problems])
    if f.final != f.expected_final:
        raise Bug(f"final {f.final} != expected {f.expected_final}", ["final != expected_final"])
    against = ProgramCheck(host)  # the tables against verify's own reading of the G-code
    against.add(whole_chapter(host))
    problems = against.finish()
    if problems:
        raise Bug("the tables against the G-code: " + "; ".join(problems[:3]), [message_class(p) for p in problems])
    if stream_bytes(host.schedule) >= host.target.flash_bytes:  # build refuses it before compiling
        return "too big"
    return "built"
