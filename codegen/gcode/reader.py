"""G-code text -> blocks: the words of every line, with comments, checksums and delimiters dealt with.

A line is words: a letter, optional spaces, a number (`G1X10Y5`, `X -5`, `.5`, `5.`, `+3`), letters in
either case; a letter standing alone (`G28 X Y`) is a word with an empty number, for the interpreter to judge.
`;` starts a comment to the end of the line, `( )` encloses one. A `*` outside comments ends the code: the
number after it is the RepRap checksum, the XOR of every byte before the `*` (N word included), and a wrong
one is an error on its line. A line starting with `/` is deleted (block delete on). `%` on a line of its own
is a program delimiter: when the program opens with one, the next one ends it. Lines end in LF or CRLF.
Codes taking free text (M117 messages) keep the rest of the line as their text; so does a Grbl `$` line (`$H`,
`$110=5000`): one word, `$` and the rest.

`read` yields a `Block` per line with words, and a `Diagnostic` per bad line; columns are 0-based offsets
into the line and become positions through an `Origin` (a .gcode file, or a block scalar in the job file).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import reduce
from operator import xor
from typing import Iterable, Iterator, NamedTuple

from codegen.errors import Diagnostic, SourceRef
from codegen.gcode.codes import TEXT_CODES, code_name, family

_NUMBER = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)"  # one way to match each number: no backtracking over a line's words
_FLAGS = re.ASCII | re.IGNORECASE
LINE_OF_WORDS = re.compile(rf"\s*(?:[A-Z]\s*{_NUMBER}\s*)*", _FLAGS)  # fullmatch: a line of words only
WORD = re.compile(rf"([A-Z])\s*({_NUMBER})", re.ASCII)  # on upper-cased text that LINE_OF_WORDS accepted
WORD_AT = re.compile(rf"\s*([A-Z])\s*({_NUMBER})", _FLAGS)  # one word at a position, with its column
BARE_AT = re.compile(r"\s*([A-Z])(?=\s|[A-Z]|$)", _FLAGS)  # a letter with no number: `G28 X Y`


@dataclass(frozen=True)
class Origin:
    """Where line 0, column 0 of the G-code text is: (1, 1) of a .gcode file, or the first line of a block
    scalar in the job file."""

    file: str
    line: int = 1
    col: int = 1

    def at(self, index: int, offset: int) -> SourceRef:
        return SourceRef(self.file, self.line + index, self.col + offset)


class Block(NamedTuple):
    index: int  # 0-based line index in the text
    text: str  # the line's code (comments blanked, checksum cut, free text cut): same columns as the line
    words: list[tuple[str, str]]  # (upper-case letter, number text)
    indent: int  # column of the first word


def columns(block: Block) -> list[int]:
    """The 0-based column of every word of the block (computed again: only errors and warnings need it)."""
    cols, pos = [], 0
    for _, number in block.words:
        m = (WORD_AT if number else BARE_AT).match(block.text, pos)
        cols.append(m.start(1))
        pos = m.end()
    return cols


def read(text: str | Iterable[str], origin: Origin) -> Iterator[Block | Diagnostic]:
    """`text`: the whole G-code, or its lines as a file yields them (opened with newline="\n")."""
    if isinstance(text, str):
        lines = text.split("\n")
        if lines and not lines[-1]:
            lines.pop()
    else:
        lines = (line[:-1] if line[-1:] == "\n" else line for line in text)
    reader = LineReader(origin)
    for index, line in enumerate(lines):
        block = reader.block(index, line)
        if block is not None:
            yield block
        elif reader.ended:
            return


class LineReader:
    """`read` a line at a time: whether the program has started, and whether a `%` opened it, carry over from
    line to line; `ended` once the closing `%` is read (nothing after it is program)."""

    def __init__(self, origin: Origin):
        self.origin = origin
        self.opened = self.started = self.ended = False

    def block(self, index: int, line: str) -> Block | Diagnostic | None:
        """The line's block or its problem; None for a line without code."""
        if not line or line[0] == ";":
            return None  # the many comment lines of slicer files
        if line[-1] == "\r":
            line = line[:-1]
        if "(" in line or ")" in line:
            code, problem = _blank_parens(line)
            if problem is not None:
                return Diagnostic(self.origin.at(index, problem[0]), problem[1])
        else:
            cut = line.find(";")
            code = line if cut < 0 else line[:cut]
        if "*" in code:
            code, problem = _checksum(line, code)
            if problem is not None:
                return Diagnostic(self.origin.at(index, problem[0]), problem[1])
        indent = 0
        if not code or code[0].isspace():  # \v and \f too
            indent = len(code) - len(code.lstrip())
            if indent == len(code):
                return None  # blank
        first = code[indent]
        if first == "%" and not code[indent + 1:].strip():
            if self.opened:
                self.ended = True  # the closing delimiter
                return None
            self.opened = not self.started
            self.started = True
            return None
        self.started = True
        if first == "/":
            return None  # block delete
        if first == "$":  # Grbl's system commands (codegen/gcode/system.py)
            return Block(index, code, [("$", code[indent + 1:].strip().upper())], indent)
        if LINE_OF_WORDS.fullmatch(code):
            words = WORD.findall(code.upper())
            if "M" in code or "m" in code:
                words, code = _cut_text(words, code)
            return Block(index, code, words, indent)
        block = _slow(index, code, indent)
        if isinstance(block, Block):
            return block
        return Diagnostic(self.origin.at(index, block[0]), block[1])


def _blank_parens(line: str) -> tuple[str, tuple[int, str] | None]:
    """The line's code with ( ) comments blanked to spaces and a ; comment cut, or a problem."""
    out, i, n = [], 0, len(line)
    while i < n:
        c = line[i]
        if c == ";":
            break
        if c == "(":
            close = line.find(")", i + 1)
            if close < 0:
                return "", (i, "comment '(' is not closed on its line")
            out.append(" " * (close + 1 - i))
            i = close + 1
            continue
        if c == ")":
            return "", (i, "')' without '('")
        out.append(c)
        i += 1
    return "".join(out), None


def _checksum(line: str, code: str) -> tuple[str, tuple[int, str] | None]:
    star = code.find("*")
    given = code[star + 1:].strip()
    if not given.isdigit() or not given.isascii():
        return code, (star, "expected a checksum number after '*'")
    actual = reduce(xor, line[:star].encode("utf-8", "surrogateescape"), 0)
    if len(given) > 3:  # a checksum is one byte; int() of thousands of digits is refused, and slow
        return code, (star, f"a checksum is 0 to 255, not a number of {len(given)} digits")
    if int(given) != actual:
        return code, (star, f"checksum mismatch: the line says *{given}, its checksum is {actual}")
    return code[:star], None


def _is_text_code(letter: str, number: str) -> bool:
    if letter != "M":
        return False
    name = code_name(letter, number)
    return name is not None and family(name) in TEXT_CODES


def _cut_text(words: list[tuple[str, str]], code: str) -> tuple[list[tuple[str, str]], str]:
    """Words up to and including a free-text code; the code text cut after it."""
    for k, (letter, number) in enumerate(words):
        if _is_text_code(letter, number):
            pos = 0
            for _ in range(k + 1):
                pos = WORD_AT.match(code, pos).end()
            return words[: k + 1], code[:pos]
    return words, code


def _slow(index: int, code: str, indent: int) -> Block | tuple[int, str]:
    """A line the fast pattern refused: its words up to a free-text code, or where it goes wrong."""
    words, pos, n = [], 0, len(code)
    while True:
        m = WORD_AT.match(code, pos)
        if m is not None:
            letter, number = m.group(1).upper(), m.group(2)
            words.append((letter, number))
            pos = m.end()
            if _is_text_code(letter, number):
                return Block(index, code[:pos], words, indent)
            continue
        m = BARE_AT.match(code, pos)  # a letter alone (`G28 X Y`): a word without a number
        if m is None:
            break
        words.append((m.group(1).upper(), ""))
        pos = m.end()
    rest = code[pos:]
    at = pos + len(rest) - len(rest.lstrip())
    if at >= n:
        return Block(index, code, words, indent)
    if code[at].isascii() and code[at].isalpha():
        return at, f"expected a number after '{code[at]}'"
    return at, f"unexpected '{code[at]}'"
