"""verify --hold/--override of an ATmega2560 flash image in bounded memory (codegen/verify/hold_bounded.py): with a
host build that keeps only its tables, the run is read beside the simulation a chapter at a time, never as one
trace of every pulse, and gives the verdict the whole run's comparison gives; the ceilings' shares and the edges'
register writes come out the same read in pieces, and the laser's writes that no pulse to come reads are forgotten."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import yaml

import codegen.verify.chapters
from codegen.cli.main import _build, main
from codegen.job import load_job
from codegen.report.summaries import write_trace
from codegen.sim.avr import PHASE_RUN, simulate
from codegen.sim.avr_edges import DUTY_HIGH_PIN, DUTY_LOW_PIN, EDGE_RECORD, EdgeDecoder
from codegen.tables.twin import Pulses
from codegen.verify.bounded import verify_flash
from codegen.verify.compare import Comparison, compare, simulated_switches
from codegen.verify.hold import hold_verify
from codegen.verify.hold_limits import CeilingShares, ceiling_shares
from codegen.verify.hold_search import Requests
from codegen.verify.results import verify_json
from codegen.verify.run_reader import RunReader
from tests.helpers import ROOT
from tests.verify.test_hold_heaters import PRINTER

needs_simavr = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                  reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")
SMALL_CHAPTERS = 1 << 14  # the star's twin (122852 pulses) in two chapters


@pytest.fixture
def chapters_seen(monkeypatch):
    """Small chapters, and the twin's pulses of every chapter the held run's comparison was handed."""
    monkeypatch.setattr(codegen.verify.chapters, "CHAPTER_PULSES", SMALL_CHAPTERS)
    seen: list[int] = []
    add = Comparison.add

    def spied(self, chapter, sim, clock):
        seen.append(len(chapter.pulses.tick))
        return add(self, chapter, sim, clock)

    monkeypatch.setattr(Comparison, "add", spied)
    return seen


def _tables_only(job_path, out) -> tuple:
    host, image, _ = _build(load_job(job_path), str(out), reuse=True, strict=False, keep="tables")
    assert host.pulses is None and host.events is None
    return host, image


@needs_simavr
@pytest.mark.parametrize("hold_s, override", [(1.0, None), (0.6, 150)])
def test_the_star_held_a_chapter_at_a_time_has_the_whole_run_s_verdict(star_flash, chapters_seen, monkeypatch,
                                                                        hold_s, override):
    read = []  # the events placing the requests reads, whole and bounded
    place = Requests.place

    def spied(self, sim, resume_arrived):
        read.append(len(sim.event))
        return place(self, sim, resume_arrived)

    monkeypatch.setattr(Requests, "place", spied)
    host, image = star_flash
    whole, whole_trace = hold_verify(host, image, hold_s, override)
    assert len(chapters_seen) == 1 and whole["pass"]  # the whole run: one chapter of every pulse
    chapters_seen.clear()
    tables, _ = _tables_only(ROOT / "examples" / "star.yaml", image.hex_path.parent)
    bounded, trace = hold_verify(tables, image, hold_s, override)
    assert bounded == whole
    assert read[0] > 80_000 and read[1] < read[0] / 2  # only the events near the requests: not one per event
    assert len(chapters_seen) == 2 and sum(chapters_seen) == len(host.pulses.tick) == 122852
    assert max(chapters_seen) < len(host.pulses.tick)
    # the trace holds no pulse of the table: they were read and dropped a chapter at a time
    assert not (trace.step_phase == PHASE_RUN).any() and (whole_trace.step_phase == PHASE_RUN).sum() == 122852
    assert trace.timer_start_cycle == whole_trace.timer_start_cycle and trace.resumes == whole_trace.resumes


@needs_simavr
def test_a_heated_printer_paused_by_m0_a_chapter_at_a_time_has_the_whole_run_s_verdict(tmp_path, chapters_seen):
    path = tmp_path / "hot-pause.yaml"
    path.write_text(PRINTER.format(name="hot-pause", middle="    M0\n"))
    host, image, _ = _build(load_job(path), str(tmp_path / "out"), reuse=False, strict=False)
    whole, _ = hold_verify(host, image, None, None)
    bounded, _ = hold_verify(_tables_only(path, tmp_path / "out")[0], image, None, None)
    assert bounded == whole and whole["pass"] and [r["kind"] for r in whole["hold"]["rests"]] == ["pause"]
    assert whole["holds"][0]["heaters"] == ["hotend"]


@needs_simavr
def test_verify_hold_writes_the_trace_as_it_compares(star_flash, tmp_path, capsys):
    """The command line compares a held flash image a chapter at a time: --trace's rows are the whole run's."""
    host, image = star_flash
    _, whole_trace = hold_verify(host, image, 1.0, None)
    write_trace(tmp_path / "whole.csv", host, whole_trace)
    code = main(["verify", str(ROOT / "examples" / "star.yaml"), "--out", str(image.hex_path.parent), "--hold",
                 "1.0", "--trace", str(tmp_path / "bounded.csv")])
    assert code == 0 and capsys.readouterr().out.startswith("PASS star")
    rows = (tmp_path / "bounded.csv").read_text()
    assert rows == (tmp_path / "whole.csv").read_text() and rows.count(",run\n") == 122852


def test_the_ceilings_shares_over_chapters_are_the_whole_twin_s(star_host):
    """Windows of 8 steps across a chapter's end count once, and the first of the highest stays the answer."""
    twin = star_host.pulses
    shares = CeilingShares(star_host)
    ends = np.searchsorted(twin.event, [0, 9000, 9001, 40000, len(twin.event_tick)])  # a chapter of one event
    for lo, hi in zip(ends[:-1], ends[1:]):
        first = int(twin.event[lo]) if lo < len(twin.event) else 0
        part = Pulses(twin.tick[lo:hi], twin.motor[lo:hi], twin.dir[lo:hi], twin.event[lo:hi] - first,
                      twin.event_tick, twin.event_block, twin.event_position)
        shares.add(part, first)
    assert shares.shares() == ceiling_shares(star_host)
    assert list(shares.shares()) == ["a", "b"] and shares.shares()["a"][0] > 0.9


def test_a_register_write_split_between_two_pieces_decodes_whole():
    """The harness writes a 16-bit register as a low record, then a high one; a piece of the file read while it
    writes may end between them: the low one waits for the next piece."""
    records = np.zeros(4, EDGE_RECORD)
    records["cycle"] = [100, 100, 200, 200]
    records["pin"] = [DUTY_LOW_PIN, DUTY_HIGH_PIN, DUTY_LOW_PIN, DUTY_HIGH_PIN]
    records["level"] = [0x34, 0x12, 0x78, 0x05]
    whole, pieces = EdgeDecoder([False], []), EdgeDecoder([False], [])
    whole.feed(records)
    for piece in (records[:1], records[1:3], records[3:]):
        pieces.feed(piece)
    assert pieces.duty().tolist() == whole.duty().tolist() == [[100, 0x1234], [200, 0x578]]


def test_the_reader_forgets_the_laser_writes_no_pulse_to_come_reads():
    """A held run's player writes the laser's power at every dilated event: the reader keeps the writes before the
    table starts and from the one in force at the next pulse on, and every level from there reads the same."""
    records = np.zeros(12, EDGE_RECORD)
    records["cycle"] = np.repeat([50, 100, 200, 300, 400, 500], 2)
    records["pin"] = [DUTY_LOW_PIN, DUTY_HIGH_PIN] * 6
    records["level"] = [7, 0, 1, 0, 2, 0, 3, 0, 4, 0, 5, 0]
    decoder = EdgeDecoder([False], [])
    decoder.feed(records)
    whole = decoder.duty()
    decoder.forget_duty(start=80, upcoming=350)
    assert decoder.duty().tolist() == [[50, 7], [300, 3], [400, 4], [500, 5]]
    later = np.array([350, 399, 400, 450, 10**6])
    assert np.array_equal(whole[np.searchsorted(whole[:, 0], later, side="right") - 1],
                          decoder.duty()[np.searchsorted(decoder.duty()[:, 0], later, side="right") - 1])


@needs_simavr
def test_a_laser_overridden_a_chapter_at_a_time_keeps_a_chapter_s_power_writes(tmp_path, monkeypatch):
    """At 50 % the player writes the laser's power at every event (33342 writes): the chapters' comparison forgets
    those no pulse to come reads, ends holding two (reset's and the last), and its verdict is the one it gives
    keeping every write."""
    job = yaml.safe_load((ROOT / "examples" / "laser" / "power.yaml").read_text())
    job["machine"]["feed_hold"] = {}
    path = tmp_path / "laser-hold.yaml"
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    host, image, _ = _build(load_job(path), str(tmp_path / "out"), reuse=False, strict=False)
    whole, whole_trace = hold_verify(host, image, None, 50)
    assert whole["pass"] and len(whole_trace.laser_duty) == 33342
    monkeypatch.setattr(codegen.verify.chapters, "CHAPTER_PULSES", 4096)  # the laser's 41600 pulses: two chapters
    tables = _tables_only(path, tmp_path / "out")[0]
    forgetting, trace = hold_verify(tables, image, None, 50)
    assert trace.laser_duty.tolist() == [whole_trace.laser_duty[0].tolist(), whole_trace.laser_duty[-1].tolist()]
    monkeypatch.setattr(RunReader, "forget_duty", lambda reader: None)
    keeping, trace = hold_verify(tables, image, None, 50)
    assert len(trace.laser_duty) == 33342 and forgetting == keeping and forgetting["pass"]
    assert forgetting["laser"] == whole["laser"]  # a cut across the chapters is judged whole (it was 0.0016 %)


@needs_simavr
def test_plain_verify_of_a_feed_hold_image_is_compared_a_chapter_at_a_time(star_flash, monkeypatch, capsys):
    """No request and no M0/M1: the command line compares the star's image (it has feed_hold) as any other flash
    image, beside the simulation (verify_flash), and says what the whole run's comparison says."""
    host, image = star_flash
    switches = simulated_switches(host)
    trace = simulate(image.hex_path, host.firmware_config(), int((host.plan.total * 1.2 + 1.0) * host.target.f_cpu),
                     switches=switches)
    whole = json.loads(json.dumps(verify_json(host, compare(host, trace, switches), image)))
    compared = []

    def spied(tables, *args, **kwargs):
        result, found = verify_flash(tables, *args, **kwargs)
        compared.append((tables.pulses, int((found.trace.step_phase == PHASE_RUN).sum())))
        return result, found

    monkeypatch.setattr("codegen.verify.bounded.verify_flash", spied)  # main.py imports it as verify runs
    code = main(["verify", str(ROOT / "examples" / "star.yaml"), "--out", str(image.hex_path.parent), "--json"])
    assert code == 0 and json.loads(capsys.readouterr().out) == whole and whole["pass"]
    assert compared == [(None, 0)]  # the host kept its tables only; the trace, none of the table's 122852 pulses
