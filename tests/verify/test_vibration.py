"""Issue 29's proof in the simulators: the toolhead's residual vibration after every acceleration change and corner
(codegen/verify/vibration.py) of a ringing-test job, shaped against unshaped, is the shaper's theoretical remaining
vibration (Klipper's estimate: codegen/motion/shapers.py remaining_vibration) within 2 percentage points, at the
design frequency and at +-20 % of it; unshaped, the job rings at the full amplitude.

All six shapers are measured on the twin's pulses (what the image plays, as `build` predicts them); one, MZV,
through `verify` in simavr too (a run of 0.8 s simulated, a few seconds)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

import codegen.motion.pieces as pieces
from codegen.job import load_job
from codegen.motion.shapers import SHAPERS
from codegen.pipeline.host import host_build
from codegen.verify.chapters import Chapters, whole_chapter
from codegen.verify.resonance import AxisResonance
from codegen.verify.results import vibration_lines
from codegen.verify.vibration import VibrationCheck, vibration_check
from tests.helpers import run_cli

FREQ, DAMPING = 40.0, 0.1
SCALES = (1.0, 0.8, 1.2)  # the resonance against the shaper's design frequency
WITHIN = 0.02  # of the unshaped amplitude

needs_avr = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                               reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


SIDES = [[0, 0], [15, 0], [15, 15], [0, 15]]


def ringing_job(folder: Path, shaper: str | None, points=SIDES, motors=("x", "y")) -> Path:
    """Three sides of a 15 mm square at 60 mm/s, 12,000 mm/s^2: every acceleration sharp against a 40 Hz period,
    two corners, a stop; 400 steps/mm, so a step (2.5 um) is small against the ringing (about 200 um). On a corexy
    (motors a, b: its belts' limits higher, for the same motion) its axes come from both belts' steps."""
    shaping = "" if shaper is None else (f"  input_shaper: {{x: {{type: {shaper}, freq: {FREQ}}}, "
                                         f"y: {{type: {shaper}, freq: {FREQ}}}}}\n")
    path = folder / f"ringing-{shaper or 'unshaped'}.yaml"
    kinematics = "cartesian" if motors == ("x", "y") else "corexy"
    limits = "max_velocity: 200, max_accel: 12000" if kinematics == "cartesian" else \
        "max_velocity: 300, max_accel: 30000"
    steppers = "".join(f"    {m}: {{steps_per_mm: 400, {limits}}}\n" for m in motors)
    path.write_text(f"machine:\n  kinematics: {kinematics}\n  steppers:\n{steppers}"
                    f"{shaping}program:\n  start: [0, 0]\n  feed: 3600\n  shapes:\n"
                    f"    - polyline: {{points: {points}}}\n")
    return path


def twin_vibration(host, freq: float) -> dict:
    """verify's vibration figures of the twin's pulses, with both axes resonating at `freq`."""
    resonances = tuple(AxisResonance(axis, freq, DAMPING) for axis in (0, 1))
    check = VibrationCheck.of(host, resonances)
    check.add(whole_chapter(host), host.pulses.tick / host.target.tick_hz, host.pulses.motor, host.pulses.dir)
    return check.figures()


def assert_theory(vibration: dict, label: str) -> None:
    for axis in ("x", "y"):
        v = vibration[axis]
        assert v["places"] >= 3 and v["unshaped_peak_um"] > 150
        assert abs(v["ratio"] - v["theory_ratio"]) <= WITHIN, (label, axis, v)


@pytest.mark.parametrize("shaper, motors", [(name, ("x", "y")) for name in sorted(SHAPERS)] + [("mzv", ("a", "b"))])
def test_the_residual_vibration_is_the_shapers_theory_on_the_twin(tmp_path, shaper, motors):
    host = host_build(load_job(ringing_job(tmp_path, shaper, motors=motors)))
    assert host.findings.ok, host.findings.problems
    for scale in SCALES:
        assert_theory(twin_vibration(host, FREQ * scale), f"{shaper} at {scale:g} f")


def test_unshaped_the_job_rings_at_the_full_amplitude(tmp_path):
    """The job without a shaper: its residual is its own unshaped figure, as large as the ringing the first
    acceleration leaves in closed form (an acceleration step of a rings a / w^2 / sqrt(1 - zeta^2), and the one
    that ends it after T adds the same, turned by exp(p T)), and the same as the shaped job's unshaped run."""
    plain = host_build(load_job(ringing_job(tmp_path, None)))
    vibration = twin_vibration(plain, FREQ)["x"]
    assert vibration["shaper"] is None and vibration["theory_ratio"] is None
    assert vibration["residual_peak_um"] == pytest.approx(vibration["unshaped_peak_um"], rel=1e-12)
    omega = 2 * math.pi * FREQ
    pole = complex(-DAMPING * omega, omega * math.sqrt(1 - DAMPING**2))
    accel, t_acc = plain.plan.accel[0], plain.plan.t_acc[0]
    first = accel / omega**2 / math.sqrt(1 - DAMPING**2) * abs(1 - np.exp(pole * t_acc)) * 1000
    assert vibration["residual_peak_um"] >= 0.98 * first
    shaped = twin_vibration(host_build(load_job(ringing_job(tmp_path, "mzv"))), FREQ)["x"]
    assert shaped["unshaped_peak_um"] == pytest.approx(vibration["residual_peak_um"], rel=0.01)


@needs_avr
def test_verify_in_simavr_reports_the_shapers_theory(tmp_path, capsys):
    """`verify --json` of the MZV job in simavr: at its design frequency (the job's), and with --resonance at
    +-20 % (the build reused)."""
    job = ringing_job(tmp_path, "mzv")
    for scale in SCALES:
        extra = ["--report", tmp_path / "report.html"] if scale == 1.0 else [
            f"--resonance=x={FREQ * scale:g}", f"--resonance=y={FREQ * scale:g},0.1"]
        code, out, _ = run_cli(capsys, "verify", job, "--out", tmp_path / "build", "--json", "--quiet", *extra)
        result = json.loads(out)
        assert code == 0 and result["pass"], result["problems"]
        assert {v["freq_hz"] for v in result["vibration"].values()} == {FREQ * scale}
        assert result["smoothing_mm"] > 0.1  # MZV at 40 Hz cuts the corners at 12,000 mm/s^2 (plan says it too)
        assert_theory(result["vibration"], f"simavr at {scale:g} f")
    page = (tmp_path / "report.html").read_text()
    assert "data-plot='vibration'" in page and "<th>vibration x (µm)</th>" in page  # the worst place, the figures


@pytest.mark.parametrize("chapter_pulses", [700, 3000])
def test_chapter_by_chapter_the_figures_are_the_whole_runs(tmp_path, monkeypatch, chapter_pulses):
    """verify measures a chapter at a time (codegen/verify/chapters.py): places and samples that run on past a
    chapter's pulses wait for the next one, and the figures come out as from the run in one piece."""
    path = ringing_job(tmp_path, "ei", SIDES + [[0, 5], [10, 5], [10, 10]])  # six windows, a corner each
    # y's shaper shorter than x's: its shaped command settles after the plan's window ends (the shaped clock runs
    # x's mean impulse time behind), so its samples there wait for the next chapter's pulses.
    path.write_text(path.read_text().replace("y: {type: ei", "y: {type: zv"))
    monkeypatch.setattr(pieces, "CHUNK_EVENTS", 1500)  # the front end hands on a few segments at a time: windows
    whole = twin_vibration(host_build(load_job(path)), FREQ * 0.8)
    host = host_build(load_job(path), keep=False)
    check = VibrationCheck.of(host, tuple(AxisResonance(axis, FREQ * 0.8, DAMPING) for axis in (0, 1)))
    chapters = []

    def measure(chapter):
        chapters.append(chapter.last)
        check.add(chapter, chapter.pulses.tick / host.target.tick_hz, chapter.pulses.motor, chapter.pulses.dir)

    observer = Chapters(measure, chapter_pulses)
    host_build(load_job(path), keep=False, observe=observer)
    observer.close()
    assert len(chapters) >= 3 and chapters[-1]
    for axis in ("x", "y"):
        for key in ("places", "residual_peak_um", "residual_rms_um", "unshaped_peak_um", "unshaped_rms_um"):
            assert check.figures()[axis][key] == pytest.approx(whole[axis][key], rel=1e-6), (axis, key)


def test_the_text_names_the_figures_and_the_theory(tmp_path):
    """verify's text: per axis its resonance and shaper, the residual and the unshaped run's, their ratio against
    the shaper's theory; an unshaped job's residual alone."""
    shaped = twin_vibration(host_build(load_job(ringing_job(tmp_path, "zvd"))), FREQ * 0.8)
    x = shaped["x"]
    line = vibration_lines(shaped)[0]
    assert line.startswith(f"  vibration x (32 Hz, damping 0.1, zvd): residual {x['residual_peak_um']:.2f} um peak")
    assert f"unshaped {x['unshaped_peak_um']:.2f} um peak" in line
    assert f"{100 * x['ratio']:.1f} % of unshaped (the shaper's theory: {100 * x['theory_ratio']:.1f} %)" in line
    plain = vibration_lines(twin_vibration(host_build(load_job(ringing_job(tmp_path, None))), FREQ))
    assert len(plain) == 2 and "unshaped)" in plain[0] and "% of unshaped" not in plain[0]


def test_which_runs_are_modelled(tmp_path):
    """The job's shaped axes, or --resonance's in their place and beside them; none for an unshaped job without
    --resonance; a held run's, not at all, and it says so."""
    shaped = host_build(load_job(ringing_job(tmp_path, "zv")))
    check, notes = vibration_check(shaped, (AxisResonance(0, 30.0, 0.05), AxisResonance(2, 70.0)), held=False)
    assert [(v.resonance.name, v.resonance.freq, v.resonance.damping) for v in check.axes] == [
        ("x", 30.0, 0.05), ("y", FREQ, 0.1), ("z", 70.0, 0.1)] and notes == []
    check, notes = vibration_check(shaped, (), held=True)
    assert check is None and notes[0].startswith("toolhead vibration: a held or overridden run")
    plain = host_build(load_job(ringing_job(tmp_path, None)))
    assert vibration_check(plain, (), held=True) == (None, [])
