"""The residual vibration over M593 eras (codegen/verify/vibration_eras.py): the frame keeps its resonance while
the program changes its shapers, and each era's residual, shaped against unshaped, is its own shaper's theoretical
remaining vibration within 2 percentage points (at the resonance and detuned either side); an era turned off
(M593 F0) rings as the unshaped run. What an era before left ringing is not counted in the next one's figures.

On the twin's pulses (a G-code job of five eras, a triangle each), chapter by chapter as verify measures, and in
simavr: that job, and a ringing tower as `calibrate ringing` writes it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

import codegen.motion.pieces as pieces
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.verify.chapters import Chapters, whole_chapter
from codegen.verify.resonance import AxisResonance
from codegen.verify.results import vibration_lines
from codegen.verify.vibration import VibrationCheck, vibration_check
from tests.helpers import run_cli

FREQ = 40.0  # Hz: the frame's resonance, the job's input_shaper frequency
WITHIN = 0.02  # of the unshaped amplitude
# The shapers' frequency era by era: the machine's (at the resonance), off, detuned either side (the resonance at
# 0.8 and 1.2 of it), at the resonance again.
ERAS = (FREQ, 0.0, 50.0, FREQ / 1.2, FREQ)
TRIANGLE = "G1 X15 Y0 F3600\nG1 X15 Y15\nG1 X0 Y0\n"  # its diagonal last: both axes ring on into the next era

needs_avr = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                               reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


def eras_job(folder: Path, shaper: str | None = "mzv") -> Path:
    """A triangle in every era of ERAS at 60 mm/s and 12,000 mm/s^2, 400 steps/mm (as tests/verify/
    test_vibration.py's ringing job); `shaper` None: the machine shapes nothing (M593 shapes with ZV)."""
    eras = "".join(f"M593 F{freq:g}\n{TRIANGLE}" for freq in ERAS[1:])
    (folder / "eras.gcode").write_text(f"G21\nG90\n{TRIANGLE}{eras}")
    shaping = "" if shaper is None else \
        f"  input_shaper: {{x: {{type: {shaper}, freq: {FREQ:g}}}, y: {{type: {shaper}, freq: {FREQ:g}}}}}\n"
    steppers = "".join(f"    {m}: {{steps_per_mm: 400, max_velocity: 200, max_accel: 12000}}\n" for m in "xy")
    path = folder / "eras.yaml"
    path.write_text(f"machine:\n  kinematics: cartesian\n  steppers:\n{steppers}{shaping}"
                    f"program:\n  start: [0, 0]\n  dialect: marlin\n  gcode: eras.gcode\n")
    return path


def twin_vibration(host, resonance: tuple[AxisResonance, ...] = ()) -> dict:
    check, notes = vibration_check(host, resonance, held=False)
    assert notes == []
    check.add(whole_chapter(host), host.pulses.tick / host.target.tick_hz, host.pulses.motor, host.pulses.dir)
    return check.figures()


def assert_eras(vibration: dict, label: str, shaper: str = "mzv", first: str | None = "mzv") -> None:
    """Every era's ratio its theory's; the one turned off rings as the unshaped run; one at the resonance rings
    least."""
    for axis in ("x", "y"):
        v = vibration[axis]
        assert v["theory_ratio"] is None and [e["era"] for e in v["eras"]] == list(range(len(ERAS))), (label, v)
        for era, freq in zip(v["eras"], ERAS):
            where = (label, axis, era)
            assert era["places"] >= 3 and era["unshaped_peak_um"] > 150, where
            assert abs(era["ratio"] - era["theory_ratio"]) <= WITHIN, where
            kind = first if era["era"] == 0 else shaper if freq else None
            assert era["shaper"] == kind, where
            assert era["shaper_freq_hz"] == (pytest.approx(freq, rel=1e-5) if kind else None), where
            if kind is None:
                assert era["theory_ratio"] == 1.0, where
                assert era["residual_peak_um"] == pytest.approx(era["unshaped_peak_um"], rel=0.01), where
                assert era["residual_rms_um"] == pytest.approx(era["unshaped_rms_um"], rel=0.01), where
        least = min(v["eras"], key=lambda e: e["ratio"])
        assert least["shaper_freq_hz"] == FREQ and least["ratio"] < 0.02, (label, axis, least)
        detuned = [e["ratio"] for e in v["eras"][2:4]]
        assert 0.08 < min(detuned) and max(detuned) < 0.3, (label, axis, detuned)  # MZV at 0.8 f and 1.2 f


def test_each_era_rings_as_its_shapers_theory_on_the_twin(tmp_path):
    host = host_build(load_job(eras_job(tmp_path)))
    assert host.findings.ok and len(host.shapings) == len(ERAS), host.findings.problems
    vibration = twin_vibration(host)
    assert_eras(vibration, "twin")
    x = vibration["x"]
    assert x["shaper"] == "mzv/none" and x["places"] == sum(e["places"] for e in x["eras"])
    # The whole run as the toolhead rings: its worst place is where the shaper is off.
    assert x["worst"]["era"] == 1 and x["worst"]["shaper"] is None
    assert x["residual_peak_um"] == pytest.approx(x["eras"][1]["residual_peak_um"], rel=0.01)


def test_an_axis_shaped_in_no_era_at_first_and_no_resonance_known(tmp_path):
    """A machine without input_shaper: era 0 is unshaped (no shaper anywhere), M593 shapes with ZV; with
    --resonance the model runs, without it verify says why not."""
    host = host_build(load_job(eras_job(tmp_path, None)))
    assert host.shapings[0] is None and host.shapings[1] is None and host.shaper_specs[2][0] == ("zv", 50.0, 0.1)
    resonances = tuple(AxisResonance(axis, FREQ) for axis in (0, 1))
    assert_eras(twin_vibration(host, resonances), "no input_shaper", "zv", None)
    check, notes = vibration_check(host, (), held=False)
    assert check is None and notes == ["toolhead vibration: no resonance known (the machine has no input_shaper, "
                                       "and no --resonance AXIS=HZ[,ZETA] was given): not modelled"]


@pytest.mark.parametrize("chapter_pulses", [700, 3000])
def test_chapter_by_chapter_the_eras_figures_are_the_whole_runs(tmp_path, monkeypatch, chapter_pulses):
    """Chapters end anywhere, at an M593's rest too: a place's era, the next era's clock and what an era leaves
    ringing carry over, and the figures come out as from the run in one piece."""
    path = eras_job(tmp_path)
    monkeypatch.setattr(pieces, "CHUNK_EVENTS", 1500)
    whole = twin_vibration(host_build(load_job(path)))
    host = host_build(load_job(path), keep=False)
    check = VibrationCheck.of(host, tuple(AxisResonance(axis, FREQ) for axis in (0, 1)))
    chapters = []

    def measure(chapter):
        chapters.append(chapter.last)
        check.add(chapter, chapter.pulses.tick / host.target.tick_hz, chapter.pulses.motor, chapter.pulses.dir)

    observer = Chapters(measure, chapter_pulses)
    host_build(load_job(path), keep=False, observe=observer)
    observer.close()
    assert len(chapters) >= 5 and chapters[-1]
    keys = ("places", "residual_peak_um", "residual_rms_um", "unshaped_peak_um", "unshaped_rms_um")
    for axis in ("x", "y"):
        figures = check.figures()[axis]
        for era, want in zip(figures["eras"], whole[axis]["eras"]):
            for key in keys:
                assert era[key] == pytest.approx(want[key], rel=1e-6, abs=1e-9), (axis, era["era"], key)
        for key in keys:
            assert figures[key] == pytest.approx(whole[axis][key], rel=1e-6), (axis, key)


def test_the_text_gives_every_era_and_the_one_that_rings_least(tmp_path):
    vibration = twin_vibration(host_build(load_job(eras_job(tmp_path))))
    lines = vibration_lines(vibration)
    x = vibration["x"]
    assert lines[0].startswith("  vibration x (40 Hz, damping 0.1, 5 eras of M593: mzv/none): residual ")
    assert "theory" not in lines[0] and len(lines) == 2 * (2 + len(ERAS))
    era = x["eras"][2]
    assert lines[3] == (f"    era 2 from line {era['line']} (mzv 50 Hz, damping 0.1): residual "
                        f"{era['residual_peak_um']:.2f} um peak, {era['residual_rms_um']:.2f} um RMS after "
                        f"{era['places']} changes; unshaped {era['unshaped_peak_um']:.2f} um peak, "
                        f"{era['unshaped_rms_um']:.2f} um RMS: {100 * era['ratio']:.1f} % of unshaped (theory "
                        f"{100 * era['theory_ratio']:.1f} %)")
    assert "era 1 from line" in lines[2] and "(unshaped)" in lines[2]
    least = min(x["eras"], key=lambda e: e["ratio"])
    assert lines[1 + len(ERAS)] == (f"  vibration x rings least in era {least['era']} from line {least['line']} "
                                    f"(mzv 40 Hz, damping 0.1): {100 * least['ratio']:.1f} % of unshaped")


@needs_avr
def test_verify_in_simavr_reports_each_eras_theory(tmp_path, capsys):
    code, out, _ = run_cli(capsys, "verify", eras_job(tmp_path), "--out", tmp_path / "build", "--json", "--quiet",
                           "--report", tmp_path / "report.html")
    result = json.loads(out)
    assert code == 0 and result["pass"], result["problems"]
    assert not any("vibration" in reason for reason in result["not_compared"])
    assert_eras(result["vibration"], "simavr")
    page = (tmp_path / "report.html").read_text()
    assert "vibration x: least ringing M593 era" in page and "data-plot='vibration'" in page


TOWER_MACHINE = """name: printer
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 400, max_velocity: 200, max_accel: 10000, range: [0, 200]}
    y: {steps_per_mm: 400, max_velocity: 200, max_accel: 10000, range: [0, 200]}
    z: {steps_per_mm: 400, max_velocity: 12, max_accel: 400, range: [0, 180]}
    e: {steps_per_mm: 100, max_velocity: 80, max_accel: 5000}
program:
  start: [0, 0, 0]
  shapes:
    - line: {to: [1, 1]}
"""


@needs_avr
def test_a_ringing_tower_verifies_with_the_model(tmp_path, capsys):
    """`calibrate ringing` (ZV, Marlin's, the machine has no shaper) at 40, 50 and 60 Hz on a frame resonating
    at 50 Hz (--resonance): every band as its shaper's theory, the 50 Hz band the least."""
    job = tmp_path / "machine.yaml"
    job.write_text(TOWER_MACHINE)
    code, _, err = run_cli(capsys, "calibrate", "ringing", job, "--out", tmp_path / "ringing.gcode", "--height", "1.5",
                           "--size", "10", "--layer-height", "0.5", "--start", "40", "--end", "60", "--step", "10")
    assert code == 0, err
    code, out, _ = run_cli(capsys, "verify", tmp_path / "ringing.yaml", "--out", tmp_path / "build", "--json",
                           "--quiet", "--resonance=x=50", "--resonance=y=50")
    result = json.loads(out)
    assert code == 0 and result["pass"], result["problems"]
    for axis in ("x", "y"):
        eras = result["vibration"][axis]["eras"]
        assert [e["shaper_freq_hz"] for e in eras] == [None, 40.0, 50.0, 60.0], eras  # era 0: the travel there
        for era in eras:
            assert era["places"] >= 3 and abs(era["ratio"] - era["theory_ratio"]) <= WITHIN, (axis, era)
        assert min(eras, key=lambda e: e["ratio"])["shaper_freq_hz"] == 50.0
