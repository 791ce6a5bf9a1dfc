"""The interpreter's diagnostics: errors at a word or a line (up to MAX_ERRORS, then it stops), and the harmless
codes it skips, one warning per code (errors with --strict), and its notes.
"""

from __future__ import annotations

from codegen.errors import Diagnostic, SourceRef
from codegen.gcode.codes import code_name
from codegen.gcode.reader import Block, columns

MAX_ERRORS = 20


class Stop(Exception):
    """The program ends here (M2/M30), or there are too many errors."""


class Diagnostics:
    """Mixed into the Interpreter: `errors`, `warned` ({key: [where, count, reason]}) and `notes`."""

    errors: list[Diagnostic]
    warned: dict[str, list]
    notes: list[Diagnostic]

    def warnings(self) -> list[Diagnostic]:
        """The notes, then one warning per skipped key."""
        return self.notes + [Diagnostic(where, f"'{key}' ignored ({reason})" + (f"; {n} times" if n > 1 else ""),
                                        "warning") for key, (where, n, reason) in self.warned.items()]

    @staticmethod
    def word_index(block: Block, what: str | None) -> int | None:
        """The first word with this letter (`X`) or code (`G92`); None: the block itself."""
        if what is None:
            return None
        for k, (letter, number) in enumerate(block.words):
            if letter == what or (len(what) > 1 and letter == what[0] and code_name(letter, number) == what):
                return k
        return None

    @staticmethod
    def word(block: Block, letter: str) -> str:
        """The word of this letter as written (`E.5`)."""
        for word_letter, number in block.words:
            if word_letter == letter:
                return letter + number
        return letter

    def where(self, block: Block, k: int | None = None) -> SourceRef:
        return self.origin.at(block.index, block.indent if k is None else columns(block)[k])

    def source(self, block: Block) -> SourceRef:
        return self.origin.at(block.index, block.indent)

    def _error(self, where: SourceRef, message: str) -> None:
        if len(self.errors) >= MAX_ERRORS:
            self.errors.append(Diagnostic(where, f"too many errors ({MAX_ERRORS} reported), stopping here"))
            raise Stop
        self.errors.append(Diagnostic(where, message))

    def fail(self, block: Block, what: str | int | None, message: str) -> None:
        """An error at a word: its index, its letter, or its code (None: the line)."""
        k = what if isinstance(what, int) else self.word_index(block, what)
        self._error(self.where(block, k), message)

    def skip(self, block: Block, k: int, key: str, reason: str) -> bool:
        """A harmless code (or parameter): one warning per key, or an error with --strict. True if allowed."""
        if self.strict:
            self.fail(block, k, f"'{key}' is not accepted with --strict ({reason})")
            return False
        seen = self.warned.get(key)
        if seen is None:
            self.warned[key] = [self.where(block, k), 1, reason]
        else:
            seen[1] += 1
        return True
