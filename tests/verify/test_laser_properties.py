"""Property tests of laser power: random laser machines and Grbl-style engravings (M3 and M4 switched on and off,
S on its own lines and on the moves, feeds, arcs, G0 between cuts). The tables' power is within half a power step
of the ideal at every event, dark while the tool is off, decodes from the bytes as the twin says, and moves no
event; a dozen of them run in simavr, where the PWM's writes must equal the tables' at every step."""

from __future__ import annotations

import contextlib
import io
import json
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from codegen.cli.main import main
from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.tables.format import encode
from codegen.tables.laser import POWER_STEP, event_power, played_counts
from tests.reference_player import play_stream

HOST = settings(max_examples=30, deadline=None, derandomize=True, database=None, print_blob=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
SIMULATED = settings(HOST, max_examples=12)


@st.composite
def engravings(draw) -> str:
    """A job file's text: a laser machine and an engraving program."""
    kinematics = draw(st.sampled_from(["cartesian", "corexy"]))
    a, b = ("x", "y") if kinematics == "cartesian" else ("a", "b")
    spm = draw(st.sampled_from([40, 80, 100, 160]))
    vmax = draw(st.sampled_from([60, 150, 300]))
    amax = draw(st.sampled_from([500, 1500, 4000]))
    s_max = draw(st.sampled_from([255, 1000]))
    lines = ["G21 G90", "G0 X5 Y5"]
    x, y = 5.0, 5.0
    for _ in range(draw(st.integers(2, 9))):
        kind = draw(st.sampled_from(["M3", "M4", "M5", "S", "G0", "G1", "G1", "G1", "G2"]))
        if kind in ("M3", "M4"):
            lines.append(f"{kind} S{draw(st.integers(0, s_max))}")
        elif kind in ("M5", "S"):
            lines.append("M5" if kind == "M5" else f"S{draw(st.integers(0, s_max))}")
        else:
            nx, ny = draw(st.integers(1, 40)), draw(st.integers(1, 40))
            if (nx, ny) == (x, y):
                continue
            words = f"X{nx} Y{ny}"
            if kind == "G2":
                words += f" I{(nx - x) / 2:g} J{(ny - y) / 2:g}"
            if kind != "G0" and draw(st.booleans()):
                words += f" S{draw(st.integers(0, s_max))}"
            if kind != "G0" and draw(st.booleans()):
                words += f" F{draw(st.sampled_from([300, 1200, 3000, 9000]))}"
            lines.append(f"{kind} {words}")
            x, y = nx, ny
    lines.append("M5")
    steppers = "\n".join(f"    {m}: {{steps_per_mm: {spm}, max_velocity: {vmax}, max_accel: {amax}}}" for m in (a, b))
    gcode = "\n".join("    " + line for line in lines)
    return (f"name: engraving\nmachine:\n  kinematics: {kinematics}\n  steppers:\n{steppers}\n"
            f"  laser: {{pwm_hz: {draw(st.sampled_from([100, 1000, 5000, 20000]))}}}\n"
            f"program:\n  s_max: {s_max}\n  feed: 1200\n  gcode: |\n{gcode}\n")


def _host(text: str, folder: Path):
    path = folder / "engraving.yaml"
    path.write_text(text)
    return path, host_build(load_job(path))


@HOST
@given(engravings())
def test_power_records_follow_the_plan_and_change_no_pulse(text):
    with tempfile.TemporaryDirectory() as folder:
        _, host = _host(text, Path(folder))
    assert host.findings.ok, host.findings.problems
    top = host.laser.top
    counts = played_counts(host.schedule)
    ideal = event_power(host.events, host.plan, host.segments)
    assert np.max(np.abs(counts / top - ideal), initial=0) <= POWER_STEP / 2 + 0.5 / top + 1e-9
    tool = np.repeat(host.events.block_tool, np.diff(host.events.block_first))
    assert not np.any(counts[~tool])  # dark while the tool is off
    power: list = []
    pulses, _, _ = play_stream(encode(host.schedule).data, len(host.kin.motors), power=power)
    assert [p[0] for p in pulses] == host.pulses.tick.tolist()  # the split runs time every event as before
    changes = np.flatnonzero(counts != np.concatenate([[0], counts[:-1]]))
    assert power == list(zip(changes.tolist(), counts[changes].tolist()))


@SIMULATED
@given(engravings())
def test_the_simulated_pwm_equals_the_tables(text):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "engraving.yaml"
        path.write_text(text)
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            code = main(["verify", str(path), "--json", "--out", str(Path(folder) / "build")])
    result = json.loads(out.getvalue())
    assert code == 0, result["problems"]
    assert result["laser"]["max_power_error_pct"] <= 100 * POWER_STEP / 2 + 0.1
