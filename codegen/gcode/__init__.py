"""G-code -> Toolpath: the job's `program.gcode`, a file (relative to the job file) or inline text.

`GcodeStream(job, strict)` gives the toolpath items in batches as it reads; `toolpath_from_gcode(job,
strict=False)` returns the whole toolpath and the warnings (the known-harmless codes it
skipped, one per code); every error (up to 20) is raised at once as a JobError, pointing into the .gcode
file, or into the job file for inline G-code (a YAML block scalar). `strict` makes the skipped codes errors.
reader.py turns text into words; interpreter.py (with mcodes.py) runs them; arcs.py is the G2/G3 geometry.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, TextIO

import numpy as np

from codegen.errors import Diagnostic, JobError
from codegen.gcode.diagnostics import MAX_ERRORS
from codegen.gcode.dialect import dialect_of
from codegen.gcode.fast import NativeLines
from codegen.gcode.interpreter import Interpreter
from codegen.gcode.reader import LineReader, Origin
from codegen.toolpath.items import Toolpath, expanded

__all__ = ["GcodeStream", "toolpath_from_gcode", "MAX_ERRORS"]

BATCH_LINES = 4096  # blocks (lines with code) read and interpreted at a time
CHUNK_CHARS = 1 << 20  # characters of the file read at a time


class GcodeStream:
    """The program's toolpath items in batches, as its G-code is read (a file line by line). The first error
    stops the items; reading goes on to report every error (up to MAX_ERRORS) at once, as a JobError at the
    end. `warnings` is complete once the batches are."""

    def __init__(self, job, strict: bool = False):
        self.job = job
        self.source, self.origin = _source(job)
        self.interpreter = Interpreter(job, self.origin, strict, dialect_of(job, self.source))
        self.start = np.array(self.interpreter.flat[:4], dtype=float)
        self.read_share = 0.0  # of the text read into the batches so far: for a progress bar

    def batches(self, size: int = BATCH_LINES) -> Iterator[list]:
        """The items of `size` blocks (lines with code) at a time."""
        interpreter, reader = self.interpreter, LineReader(self.origin)
        native = interpreter.native = NativeLines.load(size)
        pending, going = 0, True  # blocks read into this batch; False once the program has ended
        with self._lines() as text:
            # A file's size in bytes counts its characters, near enough.
            chars = max(len(text) if isinstance(text, str) else os.fstat(text.fileno()).st_size, 1)
            begin = 0  # characters before the chunk
            for first, lines, end in _chunks(text):
                if native is not None:
                    native.read(lines, first)
                at = 0
                while going and at < len(lines):
                    if native is not None and not interpreter.inverse_time:
                        at, blocks = native.run(interpreter, at, size - pending)  # up to a line it leaves
                        pending += blocks
                        reader.started |= blocks > 0
                    if pending < size and at < len(lines):
                        block = reader.block(first + at, lines[at])
                        at += 1
                        going = not reader.ended
                        if block is not None:
                            pending += 1
                            going = interpreter.run(block)
                    if pending == size or not going:
                        pending = 0
                        self.read_share = min((begin + (end - begin) * at / len(lines)) / chars, 1.0)
                        yield from self._items()
                begin = end
                if not going:
                    break
        self.read_share = 1.0
        yield from self._items()
        if interpreter.errors:
            raise JobError(interpreter.errors)

    def _items(self) -> Iterator[list]:
        """The items read since the last call, unless there has been an error."""
        items = self.interpreter.take()
        if items and not self.interpreter.errors:
            yield items

    @contextmanager
    def _lines(self) -> Iterator[str | TextIO]:
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


def _chunks(text: str | TextIO) -> Iterator[tuple[int, list[str], int]]:
    """The text's lines (without their line ends), a file's CHUNK_CHARS or so at a time, each chunk with the index
    of its first line and the characters read up to its end."""
    if isinstance(text, str):
        lines = text.split("\n")
        if lines and not lines[-1]:
            lines.pop()
        yield 0, lines, len(text)
        return
    first, rest, read = 0, [], 0  # rest: the text of a line not yet ended
    while piece := text.read(CHUNK_CHARS):
        read += len(piece)
        lines = piece.split("\n")
        if len(lines) > 1:
            lines[0] = "".join(rest) + lines[0]
            rest = [lines.pop()]
            yield first, lines, read
            first += len(lines)
        else:
            rest.append(piece)
    if any(rest):
        yield first, ["".join(rest)], read


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
    return Toolpath(stream.start, expanded(items)), stream.warnings
