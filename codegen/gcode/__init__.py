"""G-code -> Toolpath: the job's `program.gcode`, a file (relative to the job file) or inline text.

`GcodeStream(job, strict)` gives the toolpath items in batches as it reads; `toolpath_from_gcode(job,
strict=False)` returns the whole toolpath and the warnings (the known-harmless codes it
skipped, one per code); every error (up to 20) is raised at once as a JobError, pointing into the .gcode
file, or into the job file for inline G-code (a YAML block scalar). `strict` makes the skipped codes errors.
reader.py turns text into words; interpreter.py (with mcodes.py) runs them; arcs.py is the G2/G3 geometry.
"""

from __future__ import annotations

from contextlib import contextmanager
from itertools import islice
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from codegen.errors import Diagnostic, JobError
from codegen.gcode.interpreter import MAX_ERRORS, Interpreter
from codegen.gcode.reader import Origin, read
from codegen.toolpath import Toolpath

__all__ = ["GcodeStream", "toolpath_from_gcode", "MAX_ERRORS"]

BATCH_LINES = 4096  # G-code lines read at a time


class GcodeStream:
    """The program's toolpath items in batches, as its G-code is read (a file line by line). The first error
    stops the items; reading goes on to report every error (up to MAX_ERRORS) at once, as a JobError at the
    end. `warnings` is complete once the batches are."""

    def __init__(self, job, strict: bool = False):
        self.job = job
        self.source, self.origin = _source(job)
        self.interpreter = Interpreter(job, self.origin, strict)
        self.start = np.array(self.interpreter.flat[:4], dtype=float)

    def batches(self, lines: int = BATCH_LINES) -> Iterator[list]:
        interpreter = self.interpreter
        with self._lines() as text:
            blocks = read(text, self.origin)
            going = True
            while going:
                chunk = list(islice(blocks, lines))
                if not chunk:
                    break
                going = interpreter.run(chunk)
                items = interpreter.take()
                if items and not interpreter.errors:
                    yield items
        if interpreter.errors:
            raise JobError(interpreter.errors)

    @contextmanager
    def _lines(self) -> Iterator[str | Iterable[str]]:
        if isinstance(self.source, str):
            yield self.source
            return
        try:
            file = open(self.source, encoding="utf-8", errors="surrogateescape", newline="\n")
        except OSError as err:
            message = f"program.gcode: cannot read '{self.job.program.gcode}': {err.strerror}"
            raise JobError([Diagnostic(self.job.program.gcode_source, message)]) from None
        with file:
            yield file

    @property
    def warnings(self) -> list[Diagnostic]:
        return self.interpreter.warnings()


def _source(job) -> tuple[str | Path, Origin]:
    """The G-code file's path, or the inline text, and where its first character is. `program.gcode` is inline
    text when it holds a line break or names no file next to the job file (the loader has already reported a
    missing file)."""
    program = job.program
    gcode = program.gcode
    where = program.gcode_source
    base = Path(job.path).parent
    if "\n" not in gcode and (base / gcode).is_file():
        path = (base / gcode).resolve()
        return path, Origin(str(path))
    return gcode, Origin(where.file, where.line, where.col)


def toolpath_from_gcode(job, strict: bool = False) -> tuple[Toolpath, list[Diagnostic]]:
    """The whole toolpath at once."""
    stream = GcodeStream(job, strict)
    items = [item for batch in stream.batches() for item in batch]
    return Toolpath(stream.start, items), stream.warnings
