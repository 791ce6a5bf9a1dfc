"""Read a job file: YAML through PyYAML's composer, so every key and value keeps its line and column.

`read_yaml` turns the node tree into plain Python data plus `Marks`, a map from paths (tuples of keys and
list indexes, e.g. ("program", "shapes", 2, "circle", "radius")) to positions. A file that is no YAML text
(not UTF-8, control characters, nesting too deep for PyYAML's parser) is refused at its first such place.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from codegen.errors import Diagnostic, JobError, SourceRef

YPath = tuple  # of str (mapping keys) and int (list indexes)

_FLOAT_12 = re.compile(r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)[eE][-+]?[0-9]+")  # YAML 1.2 floats such as 1e-3
_MAX_NODES = 100_000
_SURROGATE = re.compile("[\ud800-\udfff]")
MAX_DEPTH = 50  # a job nests about 6 levels; PyYAML's parser recurses about 3 frames a level
_NON_PRINTABLE = yaml.reader.Reader.NON_PRINTABLE  # the characters PyYAML refuses to read
_OPENING = (yaml.BlockMappingStartToken, yaml.BlockSequenceStartToken, yaml.FlowMappingStartToken,
            yaml.FlowSequenceStartToken)
_CLOSING = (yaml.BlockEndToken, yaml.FlowMappingEndToken, yaml.FlowSequenceEndToken)


def dotted(path: YPath) -> str:
    """('program', 'shapes', 2, 'circle') -> 'program.shapes[2].circle'."""
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out


@dataclass
class Marks:
    """1-based (line, col) of every key and value of a job file, by path."""

    file: str
    lines: list[str] = field(default_factory=list)
    keys: dict[YPath, tuple[int, int]] = field(default_factory=dict)
    values: dict[YPath, tuple[int, int]] = field(default_factory=dict)
    styles: dict[YPath, tuple[str | None, bool]] = field(default_factory=dict)  # scalar style, single line?
    unbuilt: set[tuple[int, int]] = field(default_factory=set)  # values YAML could not build (reported once)

    def _at(self, pos: tuple[int, int]) -> SourceRef:
        return SourceRef(self.file, pos[0], pos[1])

    def value(self, path: YPath) -> SourceRef:
        """The value at path, else the nearest enclosing value that exists in the file."""
        for n in range(len(path), -1, -1):
            if path[:n] in self.values:
                return self._at(self.values[path[:n]])
        return SourceRef(self.file)

    def key(self, path: YPath) -> SourceRef:
        """The key of path (its value for list items and the root)."""
        return self._at(self.keys[path]) if path in self.keys else self.value(path)

    def mapping(self, path: YPath) -> SourceRef:
        """For a key missing from the mapping at path: the mapping's own key, else its first key."""
        if path in self.keys:
            return self._at(self.keys[path])
        firsts = [pos for p, pos in self.keys.items() if len(p) == len(path) + 1 and p[:-1] == path]
        return self._at(min(firsts)) if firsts else self.value(path)

    def inside(self, path: YPath, offset: int) -> SourceRef:
        """The character at `offset` inside the single-line scalar at path (plain or quoted)."""
        ref = self.value(path)
        style, single = self.styles.get(path, ("|", False))
        if path not in self.values or not single or style not in (None, "'", '"'):
            return ref
        start = ref.col - 1 + (1 if style else 0)
        raw = self.lines[ref.line - 1][start:] if ref.line <= len(self.lines) else ""
        i = n = 0
        while n < offset and i < len(raw):
            if style == "'" and raw.startswith("''", i):
                i += 2
            elif style == '"' and raw[i] == "\\":
                i += {"x": 4, "u": 6, "U": 10}.get(raw[i + 1 : i + 2], 2)
            else:
                i += 1
            n += 1
        return SourceRef(self.file, ref.line, start + i + (offset - n) + 1)

    def block(self, path: YPath) -> SourceRef:
        """The first content line of a block scalar (`key: |`), else the value."""
        ref = self.value(path)
        if self.styles.get(path, (None, True))[0] not in ("|", ">"):
            return ref
        for n in range(ref.line, len(self.lines)):  # the lines after the indicator, 0-based index n
            text = self.lines[n]
            if text.strip():
                return SourceRef(self.file, n + 1, len(text) - len(text.lstrip()) + 1)
        return ref


class _Builder:
    """Plain data from composed nodes, recording marks and the problems the models cannot see."""

    def __init__(self, loader: yaml.SafeLoader, marks: Marks):
        self.loader, self.marks = loader, marks
        self.diagnostics: list[Diagnostic] = []
        self.stack: set[int] = set()
        self.count = 0

    def error(self, node: Node, message: str) -> None:
        m = node.start_mark
        self.diagnostics.append(Diagnostic(SourceRef(self.marks.file, m.line + 1, m.column + 1), message))

    def build(self, node: Node, path: YPath) -> Any:
        self.marks.values[path] = (node.start_mark.line + 1, node.start_mark.column + 1)
        self.count += 1
        if self.count > _MAX_NODES:
            if self.count == _MAX_NODES + 1:
                self.error(node, f"{dotted(path) or 'job'}: the document is too large (aliases?)")
            return None
        if isinstance(node, ScalarNode):
            self.marks.styles[path] = (node.style, node.start_mark.line == node.end_mark.line)
            return self.scalar(node, path)
        if id(node) in self.stack:
            self.error(node, f"{dotted(path)}: recursive alias")
            return None
        self.stack.add(id(node))
        try:
            if isinstance(node, SequenceNode):
                return [self.build(child, path + (i,)) for i, child in enumerate(node.value)]
            assert isinstance(node, MappingNode)
            return self.mapping(node, path)
        finally:
            self.stack.discard(id(node))

    def mapping(self, node: MappingNode, path: YPath) -> dict:
        out: dict[str, Any] = {}
        for key_node, value_node in node.value:
            if not isinstance(key_node, ScalarNode):
                self.error(key_node, f"{dotted(path) or 'job'}: keys must be plain names")
                continue
            if self.half_pair(key_node, path):
                continue
            key = key_node.value
            if key in out:
                first = self.marks.keys[path + (key,)][0]
                where = f"{dotted(path)}: " if path else ""
                self.error(key_node, f"{where}duplicate key '{key}' (first given on line {first})")
            self.marks.keys[path + (key,)] = (key_node.start_mark.line + 1, key_node.start_mark.column + 1)
            out[key] = self.build(value_node, path + (key,))
            if isinstance(value_node, ScalarNode) and value_node.style is None and value_node.value == "":
                self.marks.values[path + (key,)] = self.marks.keys[path + (key,)]  # `key:` alone: point at it
        return out

    def half_pair(self, node: ScalarNode, path: YPath) -> bool:
        """Whether a `\\uD83D` escape left half a surrogate pair in the scalar: no character, nothing can print it."""
        half = _SURROGATE.search(node.value)
        if half:
            where = f"{dotted(path)}: " if path else ""
            self.error(node, f"{where}\\u{ord(half.group()):04X} is half of a UTF-16 surrogate pair, not a character; "
                             f"write the character itself or its \\U00XXXXXX escape")
        return half is not None

    def scalar(self, node: ScalarNode, path: YPath) -> Any:
        if self.half_pair(node, path):
            return _SURROGATE.sub("\ufffd", node.value)  # reported once: the models see a replacement character
        if node.style is None and node.tag == "tag:yaml.org,2002:str" and _FLOAT_12.fullmatch(node.value):
            return float(node.value)
        try:
            return self.loader.construct_object(node, deep=True)
        except yaml.YAMLError as e:
            problem = getattr(e, "problem", None) or str(e)
        except (ValueError, OverflowError, KeyError, AttributeError, TypeError):  # `!!timestamp x`, `!!bool x`
            problem = f"'{node.value}' is not a valid {node.tag.rsplit(':', 1)[-1]}"
        self.error(node, f"{dotted(path) or 'job'}: {problem}")
        self.marks.unbuilt.add((node.start_mark.line + 1, node.start_mark.column + 1))
        return None


def read_yaml(path: Path, file: str | None = None) -> tuple[Any, Marks, list[Diagnostic]]:
    """The plain data of a YAML file, its marks and the problems found while reading it (duplicate keys,
    unknown tags). Raises JobError when there is no data at all: missing file, YAML syntax error, empty file."""
    file = str(path) if file is None else file
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise JobError([Diagnostic(SourceRef(file), "no such file")]) from None
    except IsADirectoryError:
        raise JobError([Diagnostic(SourceRef(file), "is a directory, not a job file")]) from None
    except OSError as e:
        raise JobError([Diagnostic(SourceRef(file), f"cannot read: {e.strerror or e}")]) from None
    except UnicodeDecodeError as e:
        raise JobError([_not_utf8(file, e)]) from None
    unprintable = [_unprintable(file, text, found) for _, found in zip(range(20), _NON_PRINTABLE.finditer(text))]
    if unprintable:  # the first 20: a binary file would give thousands
        raise JobError(unprintable)
    marks = Marks(file, text.splitlines())
    loader = yaml.SafeLoader(text)
    try:
        try:
            root = loader.get_single_node()
        except RecursionError:  # PyYAML's parser recurses a few frames a level: find the level too deep
            _check_depth(text, file)
            raise
        if root is None:
            raise JobError([Diagnostic(SourceRef(file, 1, 1), "the job file is empty")])
        builder = _Builder(loader, marks)
        data = builder.build(root, ())
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        message = f"invalid YAML: {e.problem or e.context}"
        if e.problem and e.context:
            line = f" (line {e.context_mark.line + 1})" if e.context_mark is not None else ""
            message += f"; {e.context}{line}"
        where = SourceRef(file, mark.line + 1, mark.column + 1) if mark else SourceRef(file)
        raise JobError([Diagnostic(where, message)]) from None
    except yaml.YAMLError as e:
        raise JobError([Diagnostic(SourceRef(file), f"invalid YAML: {e}")]) from None
    finally:
        loader.dispose()
    return data, marks, builder.diagnostics


def _position(text: str, offset: int) -> tuple[int, int]:
    """1-based line and column of the character at `offset`."""
    line_start = text.rfind("\n", 0, offset) + 1
    return text.count("\n", 0, offset) + 1, offset - line_start + 1


def _not_utf8(file: str, error: UnicodeDecodeError) -> Diagnostic:
    data = error.object
    line_start = data.rfind(b"\n", 0, error.start) + 1
    col = len(data[line_start:error.start].decode("utf-8", errors="replace")) + 1
    byte = data[error.start:error.start + 1].hex().upper()
    return Diagnostic(SourceRef(file, data.count(b"\n", 0, error.start) + 1, col),
                      f"not UTF-8 text: byte 0x{byte} (save the job file as UTF-8)")


def _unprintable(file: str, text: str, found: re.Match) -> Diagnostic:
    line, col = _position(text, found.start())
    return Diagnostic(SourceRef(file, line, col), f"control character U+{ord(found.group()):04X} is not allowed in a "
                                                  f"YAML file (write it as an escape in a double-quoted string)")


def _check_depth(text: str, file: str) -> None:
    """Refuse nesting deeper than MAX_DEPTH, where PyYAML's recursive parser met its end (a RecursionError); the
    scanner alone reads the file without recursion."""
    depth = 0
    for token in yaml.scan(text, Loader=yaml.SafeLoader):
        if isinstance(token, _OPENING):
            depth += 1
            if depth > MAX_DEPTH:
                mark = token.start_mark
                raise JobError([Diagnostic(SourceRef(file, mark.line + 1, mark.column + 1),
                                           f"nested deeper than {MAX_DEPTH} levels; a job file needs a few")])
        elif isinstance(token, _CLOSING):
            depth -= 1
