"""G-code aware mutations: numbers replaced by extremes, words duplicated, dropped, swapped or relettered, codes
swapped between the ones the front end knows, odd line ends, NULs, non-ASCII, long lines, unclosed comments,
checksums. `mutate_gcode` applies a few of them and returns the file's bytes."""

from __future__ import annotations

import random
import re

WORD = re.compile(r"([A-Za-z$])\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)")
NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
EXTREMES = ("0", "-0", "0.0", "1e308", "-1e308", "1e309", "1e-308", "1e20", "-1e20", "1e-9", "9" * 400,
            "-" + "9" * 400, "0." + "0" * 399 + "1", "nan", "NaN", "inf", "-inf", "-1", "-0.001", "-99999",
            "2147483648", "4294967296", "65536", "1e", ".", "-", "+", "1.2.3", "0x1F", "1_000")
CODES = ("G0", "G1", "G2", "G3", "G4", "G10 L2 P1", "G10 L20 P1", "G17", "G18", "G19", "G20", "G21", "G28",
         "G28.1", "G30", "G38.2", "G40", "G43.1", "G49", "G53", "G54", "G55", "G59", "G61", "G64", "G80", "G90",
         "G91", "G92", "G92.1", "G93", "G94", "M0", "M1", "M2", "M3", "M4", "M5", "M6", "M7", "M8", "M9", "M17",
         "M18", "M30", "M82", "M83", "M84", "M104", "M106", "M107", "M109", "M140", "M190", "M204", "M205",
         "M220", "M221", "M400", "M572", "M593", "M900", "T0", "T1", "$H", "$X", "$J=", "$$", "$10=1")
LETTERS = "XYZEABCIJKRFSPLNTQDHUVW"
ODD_BYTES = (b"\x00", b"\xff", b"\xc3(", b"\xe2\x80\xa8", "é".encode(), "\u00a0".encode(), b"\x1b[0m", b"\x7f",
             "Ｘ".encode(), b"\t", b"\x0c")


def _words(line: str) -> list[re.Match]:
    return list(WORD.finditer(line))


def extreme_number(line: str, rng: random.Random) -> str:
    numbers = list(NUMBER.finditer(line))
    if not numbers:
        return f"{line} {rng.choice(LETTERS)}{rng.choice(EXTREMES)}"
    m = rng.choice(numbers)
    return line[:m.start()] + rng.choice(EXTREMES) + line[m.end():]


def duplicate_word(line: str, rng: random.Random) -> str:
    words = _words(line)
    if not words:
        return line
    m = rng.choice(words)
    return line[:m.end()] + " " + m.group(0) + line[m.end():]


def drop_word(line: str, rng: random.Random) -> str:
    words = _words(line)
    if not words:
        return line
    m = rng.choice(words)
    return line[:m.start()] + line[m.end():]


def swap_words(line: str, rng: random.Random) -> str:
    words = _words(line)
    if len(words) < 2:
        return line
    a, b = sorted(rng.sample(words, 2), key=lambda m: m.start())
    return line[:a.start()] + b.group(0) + line[a.end():b.start()] + a.group(0) + line[b.end():]


def change_letter(line: str, rng: random.Random) -> str:
    words = _words(line)
    if not words:
        return line
    m = rng.choice(words)
    letter = rng.choice(LETTERS + LETTERS.lower() + "GM$%@")
    return line[:m.start()] + letter + line[m.start() + 1:]


def swap_code(line: str, rng: random.Random) -> str:
    codes = [m for m in _words(line) if m.group(1).upper() in "GMT$"]
    if not codes:
        return f"{rng.choice(CODES)} {line}"
    m = rng.choice(codes)
    return line[:m.start()] + rng.choice(CODES) + line[m.end():]


def odd_comment(line: str, rng: random.Random) -> str:
    cut = rng.randint(0, len(line))
    insert = rng.choice(("(", ")", ";", "%", "((", "(;)", "*", f"*{rng.randint(0, 300)}", "N",
                         f"N{rng.choice(EXTREMES)}"))
    return line[:cut] + insert + line[cut:]


def long_line(line: str, rng: random.Random) -> str:
    unit = rng.choice((" X1", "0", "(", "G1 ", ";x", " "))
    return line + unit * rng.randint(1_000, 30_000)


def random_code_line(line: str, rng: random.Random) -> str:
    words = " ".join(f"{rng.choice(LETTERS)}{rng.choice(EXTREMES + ('1', '10', '0.5', '-5'))}"
                     for _ in range(rng.randint(0, 4)))
    return f"{rng.choice(CODES)} {words}"


LINE_MUTATIONS = (extreme_number, extreme_number, duplicate_word, drop_word, swap_words, change_letter, swap_code,
                  swap_code, odd_comment, long_line, random_code_line)


def _lines_mutated(lines: list[str], rng: random.Random) -> list[str]:
    """One change to the list of lines: a line mutated, or lines deleted, repeated or moved."""
    if not lines:
        return [random_code_line("", rng)]
    k = rng.randrange(len(lines))
    kind = rng.random()
    if kind < 0.75:
        lines[k] = rng.choice(LINE_MUTATIONS)(lines[k], rng)
    elif kind < 0.85:
        del lines[k:k + rng.randint(1, 10)]
    elif kind < 0.95:
        lines[k:k] = [lines[k]] * rng.randint(1, 50)
    else:
        lines.insert(rng.randrange(len(lines) + 1), lines.pop(k))
    return lines


def _bytes_mutated(data: bytes, rng: random.Random) -> bytes:
    at = rng.randint(0, len(data))
    return data[:at] + rng.choice(ODD_BYTES) * rng.randint(1, 3) + data[at:]


def mutate_gcode(lines: list[str], rng: random.Random) -> tuple[bytes, list[str]]:
    """The mutated file's bytes and the names of the mutations applied."""
    applied = []
    for _ in range(rng.choice((1, 1, 1, 2, 3))):
        lines = _lines_mutated(lines, rng)
    applied.append("lines")
    end = rng.choices(("\n", "\r\n", "\r"), weights=(8, 1, 1))[0]
    if end != "\n":
        applied.append("CRLF" if end == "\r\n" else "CR")
    data = (end.join(lines) + (end if rng.random() < 0.9 else "")).encode("utf-8")
    if rng.random() < 0.15:
        data = _bytes_mutated(data, rng)
        applied.append("bytes")
    return data, applied
