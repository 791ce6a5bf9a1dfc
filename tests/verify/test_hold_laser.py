"""Feed hold beside a PWM laser (codegen/tables/laser.py follow, the player's dilated path): M4's power follows the feed
factor at every event while the clock is dilated, the laser is dark while the machine rests, M3's power stays
what the program says while it moves; examples/laser/power.yaml with feed_hold, held in simavr in its M3 square and
in its M4 zigzag, and overridden to half speed."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import yaml

import codegen.verify.laser
from codegen.cli.main import _build
from codegen.job import load_job
from codegen.tables.hold import F_MAX, F_ONE, PARKED
from codegen.tables.laser import DYNAMIC_FLAG, follow
from codegen.verify.hold import hold_verify
from tests.helpers import ROOT

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None, reason="avr-gcc not installed")


@pytest.fixture(scope="module")
def laser(tmp_path_factory):
    """The laser example with feed_hold, built once."""
    folder = tmp_path_factory.mktemp("laser-hold")
    job = yaml.safe_load((ROOT / "examples" / "laser" / "power.yaml").read_text())
    job["machine"]["feed_hold"] = {}
    path = folder / "laser-hold.yaml"
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    host, image, _ = _build(load_job(path), str(folder / "out"), reuse=False, strict=False)
    return host, image


def test_m4_follows_the_factor_and_nothing_burns_at_rest():
    """The host's model of the player's integers: G = 2 F over 256 below F_ONE, all of it at and above F_ONE (the
    override's headroom: M4 never burns more than its S), M3's as they are, dark parked."""
    records = np.array([1000 | DYNAMIC_FLAG, 1000, 7999 | DYNAMIC_FLAG])
    assert follow(records, F_ONE).tolist() == [1000, 1000, 7999]
    assert follow(records, F_MAX).tolist() == [1000, 1000, 7999]
    assert follow(records, 64).tolist() == [500, 1000, 7999 * 128 >> 8]
    assert follow(records, 0).tolist() == [0, 1000, 0]  # F 0 and still moving: M3 burns until the rest
    assert follow(records, PARKED).tolist() == [0, 0, 0]
    f = np.arange(F_MAX + 1)
    played = follow(np.full(F_MAX + 1, 0x7FFF | DYNAMIC_FLAG), f) / 0x7FFF
    assert np.max(np.abs(played - np.minimum(f, F_ONE) / F_ONE)) < 0.0001


def _power_during(trace, start: int, end: int) -> np.ndarray:
    """The PWM counts in force from cycle `start` to `end`: the one set before, and every write within."""
    duty = trace.laser_duty
    before = np.searchsorted(duty[:, 0], start, side="right") - 1
    inside = duty[(duty[:, 0] > start) & (duty[:, 0] < end), 1]
    return np.concatenate([duty[max(before, 0):before + 1, 1], inside])


@pytest.mark.parametrize("at_s, mode", [(1.5, "M3"), (8.0, "M4")])
def test_a_hold_mid_cut_darkens_the_laser_at_rest_and_resumes_its_power(laser, at_s, mode):
    host, image = laser
    result, trace = hold_verify(host, image, at_s, None)
    assert result["pass"], result["problems"]
    assert result["laser"]["max_power_error_pct"] <= 1.0
    hold, f_cpu, tick0 = result["hold"], host.target.f_cpu, trace.timer_start_cycle
    rest, resume = (tick0 + int(hold[k] * f_cpu) for k in ("at_rest_s", "resume_s"))
    # the power the cut had when the key came, then nothing from the rest to the resume
    pressed = tick0 + int(hold["hold_s"] * f_cpu)
    assert _power_during(trace, pressed - 1000, pressed)[-1] > 0
    assert not _power_during(trace, rest + 2000, resume).any()
    after = _power_during(trace, resume, resume + int(0.3 * f_cpu))
    assert after[-1] > 0
    if mode == "M3":  # constant power: the same before the hold and once moving again
        assert _power_during(trace, pressed - 1000, pressed)[-1] == after[-1]
    else:  # dynamic: it fell with the factor towards the rest, and rose with it after
        stopping = _power_during(trace, pressed, rest)
        assert stopping.min() < 0.05 * stopping.max()
        assert len(np.unique(stopping)) > 20  # written again as the factor fell, not once per record


def test_the_override_scales_m4_and_not_m3(laser):
    host, image = laser
    result, _ = hold_verify(host, image, None, 50)
    assert result["pass"], result["problems"]
    assert result["laser"]["max_power_error_pct"] <= 1.0
    assert result["laser"]["max_energy_per_mm_error_pct"] <= 1.0


def test_a_twin_whose_m4_ignores_the_factor_does_not_pass(laser, monkeypatch):
    """The comparison can fail: played as if M4's power did not follow the factor, the simulated PWM differs."""
    host, image = laser
    monkeypatch.setattr(codegen.verify.laser, "follow", lambda records, factor: follow(records, F_ONE))
    result, _ = hold_verify(host, image, 8.0, None)
    assert not result["pass"]
    assert any(p.startswith("laser: at simulated event") for p in result["problems"])
