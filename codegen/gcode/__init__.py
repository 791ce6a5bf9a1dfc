"""G-code -> Toolpath: the job's `program.gcode`, a file (relative to the job file) or inline text.

`toolpath_from_gcode(job, strict=False)` returns the toolpath and the warnings (the known-harmless codes it
skipped, one per code); every error (up to 20) is raised at once as a JobError, pointing into the .gcode
file, or into the job file for inline G-code (a YAML block scalar). `strict` makes the skipped codes errors.
reader.py turns text into words; interpreter.py (with mcodes.py) runs them; arcs.py is the G2/G3 geometry.
"""

from __future__ import annotations

from pathlib import Path

from codegen.errors import Diagnostic, JobError
from codegen.gcode.interpreter import MAX_ERRORS, Interpreter
from codegen.gcode.reader import Origin, read
from codegen.toolpath import Toolpath

__all__ = ["toolpath_from_gcode", "gcode_text", "MAX_ERRORS"]


def gcode_text(job) -> tuple[str, Origin]:
    """The program's G-code and where its first character is. `program.gcode` is inline text when it holds a
    line break or names no file next to the job file (the loader has already reported a missing file)."""
    program = job.program
    gcode = program.gcode
    where = program.gcode_source
    base = Path(job.path).parent
    if "\n" not in gcode and (base / gcode).is_file():
        path = (base / gcode).resolve()
        try:
            data = path.read_bytes()
        except OSError as err:
            raise JobError([Diagnostic(where, f"program.gcode: cannot read '{gcode}': {err.strerror}")]) from None
        return data.decode("utf-8", "surrogateescape"), Origin(str(path))
    return gcode, Origin(where.file, where.line, where.col)


def toolpath_from_gcode(job, strict: bool = False) -> tuple[Toolpath, list[Diagnostic]]:
    text, origin = gcode_text(job)
    interpreter = Interpreter(job, origin, strict)
    interpreter.run(read(text, origin))
    if interpreter.errors:
        raise JobError(interpreter.errors)
    return interpreter.toolpath(), interpreter.warnings()
