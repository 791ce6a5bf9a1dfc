"""G-code reading: words and their columns, numbers, comments, delimiters, checksums, line ends; and the
per-line rules the interpreter enforces on the words (one word per letter, one code per modal group)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace as NS

import pytest

from codegen.errors import Diagnostic, JobError, SourceRef
from codegen.gcode import toolpath_from_gcode
from codegen.gcode.codes import code_name
from codegen.gcode.reader import Block, Origin, columns, read
from tests.helpers import DATA, machine

DATA = DATA / "gcode"
ORIGIN = Origin("t.gcode")


def blocks(text: str) -> list[Block | Diagnostic]:
    return list(read(text, ORIGIN))


def words(text: str) -> list[list[tuple[str, str]]]:
    return [b.words for b in blocks(text)]


def cols(text: str) -> list[int]:
    """1-based columns of the words of the only line."""
    (block,) = blocks(text)
    return [c + 1 for c in columns(block)]


def problems(text: str) -> list[tuple[int, int, str]]:
    return [(d.where.line, d.where.col, d.message) for d in blocks(text) if isinstance(d, Diagnostic)]


def job(gcode: str, motors=("x", "y", "z", "e")):
    return NS(machine=machine(motors=motors),
              program=NS(start=(0, 0), feed=1200, travel_feed=None, gcode=gcode,
                         gcode_source=SourceRef("job.yaml", 8, 5)),
              path=Path("/nowhere/job.yaml"))


def job_errors(gcode: str) -> list[tuple[int, int, str]]:
    with pytest.raises(JobError) as caught:
        toolpath_from_gcode(job(gcode))
    return [(d.where.line, d.where.col, d.message) for d in caught.value.diagnostics]


# ---- words, numbers, columns ----

def test_words_without_spaces():
    assert words("G1X10Y5") == [[("G", "1"), ("X", "10"), ("Y", "5")]]
    assert cols("G1X10Y5") == [1, 3, 6]


def test_spaces_inside_words():
    assert words("G0 X -5 Y 0 Z 0 F 200") == [[("G", "0"), ("X", "-5"), ("Y", "0"), ("Z", "0"), ("F", "200")]]
    assert cols("G0 X -5 Y 0 Z 0 F 200") == [1, 4, 9, 13, 17]


def test_number_forms_and_lower_case():
    assert words("g1 x.5 y5. z+3 e-.25") == [[("G", "1"), ("X", ".5"), ("Y", "5."), ("Z", "+3"), ("E", "-.25")]]
    assert cols("  g1 x.5") == [3, 6]


def test_code_names_drop_leading_zeros():
    assert [code_name("G", n) for n in ("01", "1", "00", "38.2", "1.0", "1.25", "-1")] == \
        ["G1", "G1", "G0", "G38.2", "G1", None, None]
    assert code_name("M", "862.3") == "M862.3"


def test_line_numbers_are_words():
    assert words("N10 G1 X1") == [[("N", "10"), ("G", "1"), ("X", "1")]]


def test_comments():
    assert words("G1 X1 ; move (not a comment end") == [[("G", "1"), ("X", "1")]]
    assert words("G1 (move) X2") == [[("G", "1"), ("X", "2")]]
    assert cols("G1 (move) X2") == [1, 11]
    assert words("(only a comment)\n; another\nG90;svg#svg8 > g#layer1 > path") == [[("G", "90")]]
    assert words("M5;") == [[("M", "5")]]


def test_blank_lines_and_crlf():
    got = blocks("G0 X1\r\n\r\n   \r\nG1 Y2\r\n")
    assert [(b.index, b.words, b.text) for b in got] == [(0, [("G", "0"), ("X", "1")], "G0 X1"),
                                                       (3, [("G", "1"), ("Y", "2")], "G1 Y2")]


def test_percent_delimiters():
    assert words("%\nG0 X1\n%\nG0 X2\n") == [[("G", "0"), ("X", "1")]]  # the second % ends the program
    assert words("G0 X1\n%\nG0 X2\n") == [[("G", "0"), ("X", "1")], [("G", "0"), ("X", "2")]]
    assert words("% (program 1)\nG0 X1\n%\n") == [[("G", "0"), ("X", "1")]]


def test_block_delete():
    assert words("/G1 X5\n  / G1 X6\nG1 X7") == [[("G", "1"), ("X", "7")]]


def test_free_text_codes():
    assert words("M117 Layer 5 of 12") == [[("M", "117")]]
    assert words("M117 X5") == [[("M", "117")]]  # the text is not words, even when it looks like them
    assert words('N2 M862.3 P "MINI"') == [[("N", "2"), ("M", "862.3")]]


def test_letter_alone_is_a_word_without_number():
    assert words("G28 X Y") == [[("G", "28"), ("X", ""), ("Y", "")]]
    assert cols("G28 X Y") == [1, 5, 7]


def test_letter_alone_is_an_error_except_for_g28():
    assert job_errors("G1 X\nG28 X Y\nG28 E\nG92 X\n") == [(8, 8, "expected a number after 'X'"),
                                                           (10, 9, "expected a number after 'E'"),
                                                           (11, 9, "expected a number after 'X'")]


def test_origin_maps_to_the_job_file():
    assert Origin("job.yaml", 8, 5).at(2, 3) == SourceRef("job.yaml", 10, 8)
    assert Origin("part.gcode").at(0, 0) == SourceRef("part.gcode", 1, 1)


# ---- reading errors ----

def test_reading_errors_with_columns():
    assert problems("G1 X1\nG1 X1 #5\nG1 (unclosed\nG1 X1)\nG1 X1*\nG1 X-\n") == [
        (2, 7, "unexpected '#'"),
        (3, 4, "comment '(' is not closed on its line"),
        (4, 6, "')' without '('"),
        (5, 6, "expected a checksum number after '*'"),
        (6, 4, "expected a number after 'X'"),
    ]


# ---- checksums ----

def test_checksum_right():
    assert words("N3 T0*57") == [[("N", "3"), ("T", "0")]]
    assert words("N7 G1 X2.0 Y2.0 F3000.0*85 ; fine") == [[("N", "7"), ("G", "1"), ("X", "2.0"), ("Y", "2.0"),
                                                          ("F", "3000.0")]]


def test_checksum_wrong():
    assert problems("N8 G1 X3.0 Y3.0*30 ; checksum failed") == [
        (1, 16, "checksum mismatch: the line says *30, its checksum is 33")]


def test_a_checksum_of_thousands_of_digits_is_refused_at_its_star():
    """The fuzzer's ValueError: int() of 6,855 digits exceeds Python's limit for integer strings."""
    assert problems("G28*" + "2" * 6855) == [(1, 4, "a checksum is 0 to 255, not a number of 6855 digits")]


def test_special_fields_file_has_exactly_its_wrong_checksum():
    got = blocks((DATA / "parser" / "special-fields.gcode").read_text())
    assert [(d.where.line, d.where.col, d.message) for d in got if isinstance(d, Diagnostic)] == [
        (8, 16, "checksum mismatch: the line says *30, its checksum is 33")]
    assert [b.words[1] for b in got if isinstance(b, Block)] == [
        ("G", "20"), ("G", "90"), ("T", "0"), ("G", "92"), ("G", "28"), ("G", "1"), ("G", "1")]


# ---- one word per letter, one code per modal group (interpreter rules on the read words) ----

def test_duplicate_letters():
    assert job_errors("G1 X1 X2\nG1 X1 Y2 F100 F200\n") == [(8, 11, "'X' appears twice on this line"),
                                                              (9, 19, "'F' appears twice on this line")]


def test_modal_group_conflicts():
    assert job_errors("G0 G1 X3\nG90 G91\nG20 G21\nG17 G18\nM3 M5\nG1 G1 X2\nG4 P1 G92 X0\n") == [
        (8, 8, "'G1' and 'G0' on one line: both are in the motion group"),
        (9, 9, "'G91' and 'G90' on one line: both are in the distance group"),
        (10, 9, "'G21' and 'G20' on one line: both are in the units group"),
        (11, 9, "'G18' and 'G17' on one line: both are in the plane group"),
        (12, 8, "'M5' and 'M3' on one line: both are in the spindle group"),
        (13, 8, "'G1' twice on one line"),
        (14, 11, "'G92' and 'G4' on one line: both are in the non-modal group"),
    ]


def test_two_printer_mcodes_on_one_line():
    assert job_errors("M104 S200 M140\n") == [
        (8, 15, "'M140' and 'M104' on one line: both are in the M command group")]


def test_codes_of_different_groups_share_a_line():
    toolpath, warnings = toolpath_from_gcode(job("G17 G21 G90 G94 G1 X2 F600\n"))
    assert len(toolpath.items) == 1 and warnings == []


def test_a_line_of_many_words_that_fails_at_its_end_is_read_in_linear_time():
    """Issue 28: each number matched two ways (`11` as 1+1), so a failing line of 24 words took 31 s; of 60 words
    (here) it would never end."""
    diagnostics = [d for d in read(["G1" + " X11" * 60 + " #"], Origin("p.gcode")) if isinstance(d, Diagnostic)]
    assert [(d.where.col, d.message) for d in diagnostics] == [(244, "unexpected '#'")]  # 1-based


def test_a_code_number_beyond_any_code_names_none():
    """Issue 28: G followed by 400 nines overflowed float -> int in code_name (exit 1, a traceback)."""
    assert code_name("G", "9" * 400) is None and code_name("G", "1000000") is None and code_name("G", "28") == "G28"
    assert code_name("G", "-" + "9" * 400) is None  # -inf: the fuzzer's OverflowError
