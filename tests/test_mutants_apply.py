"""scripts/mutants.py still fits today's sources: every mutant's old text is in its file exactly once and its new
text differs (scripts/mutation_test.py applies them to copies of the repository; it is too slow for the suite)."""

from __future__ import annotations

import sys

import pytest

from tests.helpers import ROOT

sys.path.insert(0, str(ROOT / "scripts"))
from mutants import FIRMWARE, HOST, MUTANTS  # noqa: E402


@pytest.mark.parametrize("mutant", MUTANTS, ids=[m.name for m in MUTANTS])
def test_mutant_applies_to_todays_sources(mutant):
    text = (ROOT / mutant.path).read_text(encoding="utf-8")
    assert text.count(mutant.old) == 1, f"{mutant.path}: the old text is there {text.count(mutant.old)} times"
    assert mutant.new != mutant.old and mutant.names
    assert (ROOT / mutant.job).is_file()


def test_the_set_has_verify_mutants_kinds():
    """VERIFY-MUTANTS.md's 49: 29 in the firmware templates, 20 in the host code, each name once; and the table
    encoder's bug in a stream's bytes."""
    assert len(FIRMWARE) == 29 and len(HOST) == 21
    assert all(m.path.startswith("templates/") for m in FIRMWARE)
    assert not any(m.path.startswith("templates/") for m in HOST)
    assert len({m.name for m in MUTANTS}) == len(MUTANTS)
