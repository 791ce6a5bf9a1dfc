"""Job file mutations: on the parsed job (a wrong type or an extreme number at any key, deep nesting, huge strings,
control characters, keys deleted, added or misspelt) and on its text (duplicate keys, anchors and aliases up to a
billion-laughs bomb, non-UTF-8 bytes, tabs, unbalanced brackets, a cut file)."""

from __future__ import annotations

import copy
import random

import yaml

from tests.fuzzing.gcode_mutations import ODD_BYTES

EXTREME_VALUES = (0, -0.0, -1, 1e308, -1e308, 1e-308, 1e20, 1e-9, 10 ** 400, -(10 ** 30), float("nan"),
                  float("inf"), float("-inf"), 2 ** 63, 0.5, True, None)
WRONG_TYPES = ("abc", "", "1e3", "0x10", [], [1, 2], [[1, 2], [3]], {}, {"a": 1}, {"x": {"y": None}}, "\x01\x7f",
               "é\u2028", "x" * 100_000, "9" * 4000)


def _paths(data, prefix=()) -> list[tuple]:
    """Every path of keys and indexes in `data`, the root's children first."""
    out = []
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list) else ()
    for key, value in items:
        out.append(prefix + (key,))
        out += _paths(value, prefix + (key,))
    return out


def _nested(depth: int, rng: random.Random):
    value = rng.choice((1, "x", None))
    for _ in range(depth):
        value = [value] if rng.random() < 0.5 else {"k": value}
    return value


def _value(rng: random.Random):
    kind = rng.random()
    if kind < 0.45:
        return rng.choice(EXTREME_VALUES)
    if kind < 0.9:
        return copy.deepcopy(rng.choice(WRONG_TYPES))  # a fresh list or mapping: later mutations change it
    return _nested(rng.choice((3, 30, 100)), rng)  # deeper: _deep_brackets, as text


def mutate_tree(data: dict, rng: random.Random) -> str:
    """One structural change at a random path; its name."""
    paths = _paths(data)
    if not paths:
        data["machine"] = _value(rng)
        return "root"
    path = rng.choice(paths)
    parent = data
    for key in path[:-1]:
        parent = parent[key]
    last = path[-1]
    kind = rng.random()
    if kind < 0.6:
        parent[last] = _value(rng)
        return "value"
    if kind < 0.75 and isinstance(parent, dict):
        del parent[last]
        return "delete"
    if kind < 0.9 and isinstance(parent, dict):
        parent[str(last)[:-1] + rng.choice("xs_")] = parent.pop(last)  # a typo of the key
        return "typo"
    if isinstance(parent, dict):
        parent[rng.choice(("extra", "range", "e", "laser", "heaters", "delta", "gcode"))] = _value(rng)
    else:
        parent.append(_value(rng))
    return "add"


def dump(data: dict) -> str:
    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=120)


def _duplicate_key(lines: list[str], rng: random.Random) -> None:
    keyed = [k for k, line in enumerate(lines) if ":" in line and not line.lstrip().startswith("#")]
    if keyed:
        k = rng.choice(keyed)
        lines.insert(k + 1, lines[k])


def _alias_bomb(lines: list[str], rng: random.Random) -> None:
    """Billion laughs: each level a list of ten aliases of the level before, the last level used as a value."""
    levels = rng.choice((3, 6, 9))
    bomb = ['lol0: &lol0 "lol"'] + [f"lol{n}: &lol{n} [{', '.join([f'*lol{n - 1}'] * 10)}]"
                                    for n in range(1, levels + 1)]
    keyed = [k for k, line in enumerate(lines) if ": " in line and not line.rstrip().endswith(":")]
    if keyed and rng.random() < 0.7:
        k = rng.choice(keyed)
        lines[k] = lines[k][:lines[k].index(": ") + 2] + f"*lol{levels}"
    lines[0:0] = bomb


def _shared_anchor(lines: list[str], rng: random.Random) -> None:
    """An anchor on one mapping value, merged (<<) or aliased at another."""
    keyed = [k for k, line in enumerate(lines) if ": {" in line]
    if len(keyed) < 2:
        return
    a, b = rng.sample(keyed, 2)
    lines[a] = lines[a].replace(": {", ": &shared {", 1)
    head = lines[b][:lines[b].index(": {")]
    lines[b] = f"{head}: *shared" if rng.random() < 0.5 else f"{head}: {{<<: *shared, extra: 1}}"


def _cut_or_break(lines: list[str], rng: random.Random) -> None:
    k = rng.randrange(len(lines))
    line = lines[k]
    at = rng.randint(0, len(line))
    lines[k] = line[:at] + rng.choice(("\t", "[", "{", "]", "}", "'", '"', "&", "*", "!!python/object:os.system ",
                                       "!!binary ", "? ", "- ", "---\n", "...\n", "#", ": ", "%YAML 1.1\n")) + line[at:]
    if rng.random() < 0.2:
        del lines[k + 1:]


def _deep_brackets(lines: list[str], rng: random.Random) -> None:
    depth = rng.choice((50, 500, 5000))
    lines.append("extra: " + "[" * depth + "]" * depth)


TEXT_MUTATIONS = (_duplicate_key, _duplicate_key, _alias_bomb, _shared_anchor, _cut_or_break, _cut_or_break,
                  _deep_brackets)


def mutate_text(text: str, rng: random.Random) -> tuple[bytes, list[str]]:
    """The text's bytes after one to three textual mutations, and their names."""
    lines = text.splitlines() or [""]
    applied = []
    for _ in range(rng.randint(1, 3)):
        mutation = rng.choice(TEXT_MUTATIONS)
        mutation(lines, rng)
        applied.append(mutation.__name__.lstrip("_"))
    data = ("\n".join(lines) + "\n").encode("utf-8")
    if rng.random() < 0.2:
        at = rng.randint(0, len(data))
        data = data[:at] + rng.choice(ODD_BYTES) + data[at:]
        applied.append("bytes")
    return data, applied
