"""verify in bounded memory (codegen/verify/bounded.py): the twin planned again and compared chapter by chapter
with the records simavr writes, on the streaming ATmega2560 firmware of a printer with its heaters.

One simulated session is kept (its records copied as the comparison begins); the comparison is then run again
over those records with other chapter sizes and with records taken out, in this process."""

from __future__ import annotations

import re
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

from codegen.cli.stream import _firmware, streamed_host
from codegen.job import load_job
from codegen.pipeline.streaming import stream_setup
from codegen.report.summaries import write_trace
from codegen.sim.avr import decode_edges
from codegen.sim.avr_edges import EDGE_RECORD, read_edges
from codegen.verify.bounded import RunOutputs, compare_run
from codegen.verify.stream import simulate_stream, simulate_stream_bounded
from tests.helpers import ROOT

BENCHY = ROOT / "examples" / "printers" / "benchy-mini.yaml"
GCODE = ROOT / "tests" / "data" / "gcode" / "slicer" / "benchy-prusaslicer.gcode"

needs_avr = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                               reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


class KeptRun:
    """A comparison in this process that keeps a copy of the session's records and its end (for the tests to
    compare again)."""

    kept: dict = {}
    folder: Path | None = None  # where the copy goes (the fixture's temporary folder)

    def __init__(self, host, strict, link, edges, switches, streamed, outputs=None):
        self.args, self.edges, self.outputs = (host, strict, link, switches, streamed), edges, outputs

    def result(self, end_trace):
        host, strict, link, switches, streamed = self.args
        copy = KeptRun.folder / "edges.bin"
        shutil.copy(self.edges, copy)
        KeptRun.kept.update(args=self.args, edges=copy, end=end_trace)
        return compare_run(host, strict, link, copy, lambda: True, lambda: end_trace, switches, streamed,
                           outputs=self.outputs)

    def stop(self):
        pass


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """The Benchy's start and first layer, streamed with its heaters: verify's result (bounded, kept) and the host
    build of a whole comparison's."""
    folder = tmp_path_factory.mktemp("bounded")
    KeptRun.folder = folder
    lines = GCODE.read_text().splitlines(keepends=True)
    changes = [i for i, line in enumerate(lines) if line.startswith(";LAYER_CHANGE")]
    (folder / "one-layer.gcode").write_text("".join(lines[:changes[1]]))
    job = re.sub(r"(?m)^  gcode: .*$", "  gcode: one-layer.gcode", BENCHY.read_text())
    (folder / "one-layer.yaml").write_text(job.replace("name: benchy-mini", "name: one-layer"))
    job = load_job(folder / "one-layer.yaml")
    setup = stream_setup(job)
    image, _ = _firmware(job, setup, str(folder / "out"))
    with tempfile.NamedTemporaryFile() as table:
        host = streamed_host(job, setup, False, keep=False, tables_out=table)
        result, _ = simulate_stream_bounded(host, setup, image, (), table, False, comparing=KeptRun)
    whole, _ = simulate_stream(streamed_host(job, setup, False, keep=True), setup, image, ())
    return result, whole, dict(KeptRun.kept)


@needs_avr
def test_the_bounded_comparison_finds_what_the_whole_one_finds(session):
    bounded, whole, _ = session
    assert bounded["pass"] and whole["pass"], (bounded["problems"], whole["problems"])
    for key in ("duration_s", "planned_duration_s", "max_path_error_mm", "motors", "holds", "heaters",
                "table_start_s", "link"):
        assert bounded[key] == whole[key], key


@needs_avr
@pytest.mark.parametrize("chapter", [3_000, 40_000])
def test_chapters_of_any_size_give_the_same_figures(session, chapter):
    """Chapter boundaries fall anywhere: mid-corner, between a window's last segment and the next's."""
    _, _, kept = session
    host, strict, link, switches, streamed = kept["args"]
    default = compare_run(host, strict, link, kept["edges"], lambda: True, lambda: kept["end"], switches, streamed)
    small = compare_run(host, strict, link, kept["edges"], lambda: True, lambda: kept["end"], switches, streamed,
                        chapter_pulses=chapter)
    a, b = default.verdict, small.verdict
    assert (a.problems, a.findings.problems) == (b.problems, b.findings.problems) == ([], [])
    assert a.timing_error_us == b.timing_error_us
    assert a.findings.rate_ratio == b.findings.rate_ratio
    assert a.findings.accel_ratio == b.findings.accel_ratio
    assert a.findings.max_path_error_mm == pytest.approx(b.findings.max_path_error_mm, abs=1e-12)
    assert a.duration_s == b.duration_s and a.planned_duration_s == b.planned_duration_s


@needs_avr
def test_a_lost_pulse_in_the_records_is_named(session, tmp_path):
    """One STEP pulse of motor x taken out of the middle of the run: the counts differ, timing and path are not
    compared past it, and nothing else is claimed."""
    _, _, kept = session
    host, strict, link, switches, streamed = kept["args"]
    rec = read_edges(kept["edges"])
    rises = np.flatnonzero((rec["pin"] == 0) & (rec["level"] == 1))
    k = rises[len(rises) // 2]
    edges = tmp_path / "edges.bin"
    np.delete(rec, [k, k + 1 + np.argmax(rec[k + 1:]["pin"] == 0)]).astype(EDGE_RECORD).tofile(edges)
    verdict = compare_run(host, strict, link, edges, lambda: True, lambda: kept["end"], switches, streamed).verdict
    assert any(p.startswith("motor x: the simulator made") for p in verdict.problems), verdict.problems
    assert any(r.startswith("path error") for r in verdict.not_compared)
    assert not verdict.ok


@needs_avr
def test_the_trace_file_written_chapter_by_chapter_is_the_whole_runs(session, tmp_path):
    """verify --trace in bounded memory: the rows the comparison writes as it goes are those write_trace makes of
    the whole run (homing's first, then the table's, in time order)."""
    _, _, kept = session
    host, strict, link, switches, streamed = kept["args"]
    compare_run(host, strict, link, kept["edges"], lambda: True, lambda: kept["end"], switches, streamed,
                chapter_pulses=3_000, outputs=RunOutputs(steps_csv=tmp_path / "chapters.csv"))
    end = kept["end"]
    whole = decode_edges(read_edges(kept["edges"]), host.firmware_config(), end.state, end.cycles,
                         end.timer_start_cycle, None)
    write_trace(tmp_path / "whole.csv", host, whole)
    rows = (tmp_path / "chapters.csv").read_text()
    assert rows == (tmp_path / "whole.csv").read_text()
    assert rows.count(",run\n") == len(whole.run_only().step_cycle) > 10_000


@needs_avr
def test_the_waveform_written_chapter_by_chapter_is_the_whole_runs(session, tmp_path):
    """verify --vcd in bounded memory: the waveform written from the records as they are read has every signal's
    changes that write_vcd makes of the whole run, at the same times; --report's samples come back with the run."""
    from codegen.verify.waveform import write_vcd
    from tests.report.test_vcd import read_vcd

    _, _, kept = session
    host, strict, link, switches, streamed = kept["args"]
    compared = compare_run(host, strict, link, kept["edges"], lambda: True, lambda: kept["end"], switches, streamed,
                           chapter_pulses=3_000, outputs=RunOutputs(vcd=tmp_path / "chapters.vcd", report=True))
    end = kept["end"]
    whole = decode_edges(read_edges(kept["edges"]), host.firmware_config(), end.state, end.cycles,
                         end.timer_start_cycle, None)
    write_vcd(tmp_path / "whole.vcd", host.job.name, whole)
    assert read_vcd(tmp_path / "chapters.vcd") == read_vcd(tmp_path / "whole.vcd")
    samples = compared.samples
    assert samples.count == len(whole.run_only().step_cycle) > 10_000
    assert np.array_equal(samples.net, compared.made_position)
