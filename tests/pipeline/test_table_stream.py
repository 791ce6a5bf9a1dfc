"""`plan --tables FILE` writes the table stream a window at a time, as the windows are made: the same bytes as
the whole program's schedule encoded at once, and no file when the plan fails its checks."""


import numpy as np
import pytest

import codegen.cli.main as cli
import codegen.motion.lookahead as lookahead
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.tables.format import encode
from tests.helpers import ROOT, gcode_job_file


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    """A job planned once for this file, by (job, target): an example, or a G-code file on the RAMPS printer of
    tests/helpers.py (the Cura puzzle takes seconds, and two tests here plan it): (job file, host)."""
    made = {}

    def get(job: str, target: str):
        if (job, target) not in made:
            path = (ROOT / job if job.startswith("examples") else
                    gcode_job_file(tmp_path_factory.mktemp("tables"), job, target))
            made[job, target] = path, host_build(load_job(path, target))
        return made[job, target]

    yield get
    made.clear()


@pytest.mark.parametrize("job, target", [
    ("examples/plotter-set-51.yaml", "mcs51"), ("examples/kossel-mini.yaml", "avr"),
    ("slicer/puzzle-cura.gcode", "avr"), ("laser/hiking.gcode", "mcs51")])
def test_the_stream_written_window_by_window_is_the_whole_programs(planned, tmp_path, job, target):
    path, whole = planned(job, target)
    out = tmp_path / "tables.bin"
    assert cli.main(["plan", str(path), "--target", target, "--tables", str(out)]) == 0
    assert out.read_bytes() == encode(whole.compressed.schedule).data
    if not job.startswith("examples"):
        assert whole.totals.table_bytes == out.stat().st_size  # `plan` counts what it writes
        assert whole.totals.windows > 3


def test_a_plan_that_fails_its_checks_leaves_no_table_file(tmp_path, monkeypatch, capsys):
    real = cli.host_build

    def failing(*args, **kw):
        host = real(*args, **kw)
        host.findings.problems.append("motor x exceeds its rate over 8 steps by 1.0 %")
        return host

    monkeypatch.setattr(cli, "host_build", failing)
    out = tmp_path / "tables.bin"
    assert cli.main(["plan", str(ROOT / "examples/star.yaml"), "--tables", str(out)]) == 1
    assert not out.exists() and list(tmp_path.iterdir()) == []
    assert "exceeds its rate" in capsys.readouterr().out


def test_windows_make_the_tables_one_window_would_to_rounding(planned, monkeypatch):
    """Against one window over the whole program: the same blocks to the bit; event times to rounding (the plan
    sums durations from each window's start, not from the program's: 0.006 ticks on this file); at most one run
    more per window (a run cannot go on into the next window)."""
    path, windowed = planned("slicer/puzzle-cura.gcode", "avr")
    job = load_job(path)
    monkeypatch.setattr(lookahead, "settled", lambda prof: np.zeros(len(prof) + 1, dtype=bool))
    monkeypatch.setattr(lookahead, "MAX_HELD", 1 << 40)
    whole = host_build(job)
    assert whole.totals.windows == 1 and windowed.totals.windows > 50
    a, b = windowed.compressed.schedule, whole.compressed.schedule
    for name in ("block_steps", "block_init", "block_modulus", "block_dirs", "block_events", "block_tool"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.abs(windowed.compressed.ideal_ticks - whole.compressed.ideal_ticks).max() < 0.05
    assert b.n_runs <= a.n_runs <= b.n_runs + windowed.totals.windows
    assert windowed.findings.ok and whole.findings.ok
