"""verify --stream of an 8051 in bounded memory (codegen/verify/stream.py _s51_session): s51's records written into
an edges file as they come (codegen/sim/mcs51_edges.py) and compared chapter by chapter in a second process, on
tests/verify/helpers.py's plotter (2.15 s) without its feed hold: the verdict and every figure are the whole run's,
and the whole run is never decoded."""

from __future__ import annotations

import json
import shutil

import pytest

from codegen.cli.main import main
from codegen.verify.stream import simulate_stream
from tests.helpers import streamed
from tests.verify.helpers import job_file

pytestmark = pytest.mark.skipif(shutil.which("sdcc") is None or shutil.which("s51") is None,
                                reason="needs sdcc and s51 (scripts/setup.sh installs them)")


@pytest.fixture(scope="module")
def plotter(tmp_path_factory):
    """The job file, its firmware's folder, and verify's result of the whole run."""
    folder = tmp_path_factory.mktemp("bounded51")
    job = job_file(folder, hold="")
    host, image, setup = streamed(job, folder / "out")
    whole, _ = simulate_stream(host, setup, image, ())
    return job, folder / "out", whole


def test_the_bounded_comparison_of_an_8051_stream_finds_what_the_whole_one_finds(plotter, monkeypatch, capsys):
    job, out, whole = plotter

    def whole_run(*args, **kwargs):
        raise AssertionError("the whole run was kept")

    monkeypatch.setattr("codegen.cli.stream.simulate_stream", whole_run)
    monkeypatch.setattr("codegen.sim.mcs51_link.trace_of", whole_run)
    code = main(["verify", str(job), "--stream", "--json", "--out", str(out)])
    bounded = json.loads(capsys.readouterr().out)
    assert code == 0 and bounded["pass"] and whole["pass"], (bounded["problems"], whole["problems"])
    assert bounded["display"] == whole["display"] and bounded["display"][0].startswith("X ")
    for key in ("duration_s", "planned_duration_s", "max_path_error_mm", "start_offset_us", "motors", "link",
                "homing"):
        assert bounded[key] == whole[key], key
    assert bounded["motors"]["x"]["steps"] > 0
