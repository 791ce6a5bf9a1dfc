"""plan --report and verify --report (codegen/report/html.py): the plots each kind of job's page has (and the one
line for each it cannot have), every embedded PNG decoded and not blank, the page rendered in headless Chromium with
every image loaded at its size; no page for a bad job. The simulators are the real simavr and the real firmware."""

import base64
import contextlib
import io
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from codegen.cli.main import main
from tests.helpers import ROOT

STAR, LASER, DELTA = (ROOT / "examples" / p for p in ("star.yaml", "laser/power.yaml", "delta-seed.yaml"))
IMG = re.compile(r"<img data-plot='([\w-]+)' data-colour='(\w*)' alt='[^']*' src='data:image/png;base64,([^']+)'>")
MISSING = re.compile(r"data-missing='([\w-]+)'")
SIZES_SCRIPT = """<script>window.addEventListener('load', () => {
  const out = document.createElement('pre'); out.id = 'sizes';
  out.textContent = [...document.images].map(
    i => [i.dataset.plot, i.complete, i.naturalWidth, i.naturalHeight].join(' ')).join(';');
  document.body.appendChild(out); });</script>"""  # each image's load as the browser saw it, into the DOM

HEATED = """name: heated
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
    y: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
program:
  gcode: |
    M104 S200
    M140 S60
    G1 X10 F3000
    M109 S150
    G1 X20 Y10
    M104 S0
"""

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


def run(*argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def pages(tmp_path_factory) -> dict[str, tuple[Path, dict]]:
    """Each kind of job's page, with the JSON its run printed: star (corexy, flash image), the laser (PWM power), the
    delta, the star streamed, the star planned only, and a short job that heats (and waits for the hot end)."""
    tmp = tmp_path_factory.mktemp("reports")
    (tmp / "heated.yaml").write_text(HEATED)
    runs = {"star": ("verify", STAR), "laser": ("verify", LASER), "delta": ("verify", DELTA),
            "stream": ("verify", STAR, "--stream"), "plan": ("plan", STAR), "heated": ("verify", tmp / "heated.yaml")}
    out = {}
    for name, (verb, job, *more) in runs.items():
        page = tmp / f"{name}.html"
        code, stdout, err = run(verb, job, *more, "--json", "--report", page,
                                *(("--out", tmp / name) if verb == "verify" else ()))
        assert code == 0, err
        out[name] = (page, json.loads(stdout))
    return out


def plots_of(page: Path) -> dict[str, tuple[str, bytes]]:
    """The page's images by data-plot: their colouring and PNG bytes."""
    return {key: (colour, base64.b64decode(data)) for key, colour, data in IMG.findall(page.read_text())}


def assert_drawn(key: str, png: bytes) -> np.ndarray:
    """The PNG decodes, and more than axes and text are on it: many colours, a fair share of pixels off the
    background, and some coloured ones (data, not black and grey)."""
    rgb = imread(io.BytesIO(png), format="png")[..., :3]
    pixels = np.round(rgb.reshape(-1, 3) * 255).astype(np.int32)
    colours, counts = np.unique(pixels @ np.array([1 << 16, 1 << 8, 1]), return_counts=True)
    background = colours[np.argmax(counts)] >> np.array([16, 8, 0]) & 0xFF
    off = np.any(np.abs(pixels - background) > 8, axis=1).mean()
    chromatic = (pixels.max(axis=1) - pixels.min(axis=1) > 50).mean()
    assert len(colours) > 50 and off > 0.03 and chromatic > 0.002, (key, len(colours), off, chromatic)
    return rgb


@pytest.mark.parametrize("name, plots, colour, missing", [
    ("star", {"path", "motion", "timing"}, "speed", set()),
    ("laser", {"path", "motion", "timing"}, "power", set()),
    ("delta", {"path", "motion", "timing"}, "speed", set()),
    ("stream", {"path", "motion", "timing", "ring-fill"}, "speed", set()),
    ("plan", {"path", "motion"}, "speed", {"simulated-path", "timing"}),
    ("heated", {"path", "motion", "timing", "heaters"}, "speed", set()),
])
def test_each_kind_of_job_has_its_plots_drawn(pages, name, plots, colour, missing):
    page, _ = pages[name]
    found = plots_of(page)
    assert set(found) == plots
    assert set(MISSING.findall(page.read_text())) == missing
    assert found["path"][0] == colour
    for key, (_, png) in found.items():
        assert_drawn(key, png)


def test_the_header_has_the_verdict_and_the_figures_of_the_json(pages):
    page, result = pages["star"]
    text = page.read_text()
    assert "<span class='pass' id='verdict'>PASS</span>" in text and "<td>star</td>" in text
    assert "<td>avr (ramps-1.4, atmega2560)</td>" in text
    assert f"<th>simulated duration (s)</th><td>{result['duration_s']:.6g}</td>" in text
    for name, m in result["motors"].items():
        assert (f"<tr><th>{name}</th><td>{m['steps']}</td><td>{m['final']}</td><td>{m['expected_final']}</td>"
                f"<td>{m['max_timing_error_us']:.6g}</td><td>{100 * m['max_rate_ratio']:.1f} %</td>") in text
    delta, result = pages["delta"]
    assert all(f"<tr><th>{m}</th><td>{result['motors'][m]['steps']}</td>" in delta.read_text() for m in "abc")
    stream, result = pages["stream"]
    assert f"<th>link frames</th><td>{result['link']['frames']}</td>" in stream.read_text()
    laser, result = pages["laser"]
    assert f"<th>laser cuts</th><td>{result['laser']['cuts']}</td>" in laser.read_text()
    heated, result = pages["heated"]
    hotend = result["heaters"]["hotend"]
    assert (f"<th>heater hotend</th><td>target (°C) {hotend['target_c']:g}, time to target (s) "
            f"{hotend['time_to_target_s']:g}, ") in heated.read_text()


def test_the_paths_are_drawn_in_the_planes_the_jobs_move_in(pages):
    """verify draws the planned and the simulated path side by side, plan the planned one alone; the star moves in
    x and y, the delta mostly in z (down from the top, then across)."""
    star, delta, plan = (assert_drawn("path", plots_of(pages[name][0])["path"][1])
                         for name in ("star", "delta", "plan"))
    assert star.shape[1] > 1.5 * star.shape[0] and star.shape[1] > 1.5 * plan.shape[1]  # two square-ish panels
    assert delta.shape[0] > 0.8 * delta.shape[1]  # two tall panels (z up): the figure is about as high as wide


def test_every_page_renders_in_chromium_with_every_image_loaded(pages, tmp_path):
    chromium = shutil.which("chromium")
    if chromium is None:
        pytest.skip("needs chromium (scripts/setup.sh --tests installs it)")
    for name, (page, _) in pages.items():
        probe = tmp_path / f"{name}.html"
        probe.write_text(page.read_text().replace("</body>", SIZES_SCRIPT + "</body>"))
        dom = subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                              "--no-first-run", "--disable-background-networking", "--disable-component-update",
                              "--disable-sync", f"--user-data-dir={tmp_path / 'profile'}", "--dump-dom",
                              probe.as_uri()], capture_output=True, text=True, timeout=60).stdout
        sizes = re.search(r"<pre id=\"sizes\">([^<]*)</pre>", dom)
        assert sizes, f"{name}: the page's script did not run:\n{dom[:500]}"
        seen = [row.split() for row in sizes.group(1).split(";")]
        expected = {key: imread(io.BytesIO(png), format="png").shape[:2] for key, (_, png) in
                    plots_of(page).items()}
        assert [key for key, *_ in seen] == list(expected)
        for key, complete, width, height in seen:
            assert complete == "true" and (int(height), int(width)) == expected[key], (name, key, width, height)


def test_a_bad_job_gives_exit_2_and_no_page(tmp_path):
    job = tmp_path / "bad.yaml"
    job.write_text(STAR.read_text().replace("steps_per_mm: 80", "steps_per_mm: -80", 1))
    for verb in ("verify", "plan"):
        page = tmp_path / f"{verb}.html"
        code, _, err = run(verb, job, "--report", page, *(("--out", tmp_path / "out") if verb == "verify" else ()))
        assert code == 2 and "must be > 0" in err
        assert not page.exists() and not list(tmp_path.glob(".*.partial"))


def test_the_plan_report_gathers_its_motion_a_window_at_a_time():
    """plan --report keeps no pulses: the motors' motion it draws, gathered per window on a fine grid, is the one
    drawn from the whole job's twin (the star's grid is 10 ms, two of the fine grid's steps: the same positions)."""
    from codegen.job import load_job
    from codegen.pipeline.host import host_build
    from codegen.report.plan_samples import PlanSamples
    from codegen.report.plots import motor_motion

    job = load_job(ROOT / "examples" / "star.yaml")
    whole = host_build(job)
    samples = PlanSamples()
    windowed = host_build(job, keep=False, observe=samples)
    assert windowed.pulses is None and samples.duration_s == whole.pulses.event_tick[-1] / whole.target.tick_hz
    tick_hz, spm = whole.target.tick_hz, whole.kin.limits.steps_per_mm
    trains = [(t / tick_hz, d) for t, d in map(whole.pulses.of_motor, range(len(whole.kin.motors)))]
    for ours, theirs in zip(samples.motion(spm), motor_motion(trains, spm, samples.duration_s)):
        assert ours.shape == theirs.shape and np.allclose(ours, theirs, atol=1e-9)
    assert len(samples.segments()) == len(whole.segments)
    assert np.array_equal(samples.plan().t_start, whole.plan.t_start)
