"""The fuzz suite's short run (tests/fuzzing/, issue 28): a fixed seed's first inputs (about 40 s on one worker)
through `plan` in-process, with no failure signature. The long run: `python scripts/fuzz.py --minutes 10`."""

from __future__ import annotations

import dataclasses
import io

from tests.fuzzing.campaign import Settings, fuzz, table
from tests.fuzzing.outcomes import plan_input
from tests.fuzzing.pool import GiB

SHORT = Settings(seed=28, count=300, jobs=1, time_limit=10.0, memory_bytes=2 * GiB, shrink_seconds=3.0)


def test_a_short_fuzz_run_finds_nothing(tmp_path):
    results = fuzz(dataclasses.replace(SHORT, out=tmp_path), plan_input, stream=io.StringIO())
    assert results.inputs == SHORT.count
    assert not results.findings, "\n" + table(results)
