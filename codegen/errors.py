"""Errors the way a compiler reports them: file:line:col, the source line, a caret.

Exit codes follow CLI.md: 2 for bad input (JobError), 1 for a failed build or verification (BuildError).
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence


@dataclass(frozen=True)
class SourceRef:
    """A place in an input file; line and col are 1-based (0 when unknown)."""

    file: str
    line: int = 0
    col: int = 0

    def __str__(self) -> str:
        if self.line <= 0:
            return self.file
        return f"{self.file}:{self.line}:{max(self.col, 1)}"


@dataclass(frozen=True)
class Diagnostic:
    where: SourceRef
    message: str
    severity: str = "error"  # error | warning

    def render(self, source_lines: Sequence[str] | None = None) -> str:
        text = f"{self.where}: {self.severity}: {self.message}"
        if source_lines is None:
            source_lines = _read_lines(self.where.file)
        if 0 < self.where.line <= len(source_lines):
            line = source_lines[self.where.line - 1].rstrip("\r\n")
            caret = " " * (max(self.where.col, 1) - 1) + "^"
            text += f"\n{line}\n{caret}"
        return text


def _read_lines(file: str) -> list[str]:
    try:
        return Path(file).read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return []


def render_all(diagnostics: Iterable[Diagnostic]) -> str:
    """Every diagnostic with its source line and caret, each file read once."""
    cache: dict[str, list[str]] = {}
    parts = []
    for d in diagnostics:
        lines = cache.setdefault(d.where.file, _read_lines(d.where.file))
        parts.append(d.render(lines))
    return "\n".join(parts)


class JobError(Exception):
    """Bad input (job file, G-code, shape). Carries every diagnostic found; exit code 2."""

    exit_code = 2

    def __init__(self, diagnostics: Iterable[Diagnostic]):
        self.diagnostics = list(diagnostics)
        super().__init__(self.render())

    def render(self) -> str:
        return render_all(self.diagnostics)

    def __reduce__(self):  # from a child process (codegen/overlap.py): rebuilt from its diagnostics
        return JobError, (self.diagnostics,)


class BuildError(Exception):
    """The build failed, the image does not fit, or a check found a difference; exit code 1."""

    exit_code = 1


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """' (did you mean `x`?)' for the closest choice, or ''."""
    match = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean `{match[0]}`?)" if match else ""


def closest(word: str, choices: Iterable[str]) -> str | None:
    """The choice closest to `word` (difflib, same cutoff as did_you_mean), or None."""
    match = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=0.6)
    return match[0] if match else None


def suggest(word: str, choices: Iterable[str]) -> str:
    """Like did_you_mean, with single quotes: " (did you mean 'x'?)" or ''."""
    match = closest(word, choices)
    return f" (did you mean '{match}'?)" if match else ""
