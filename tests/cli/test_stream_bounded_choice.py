"""verify --stream picks its comparison: a job with machine.feed_hold and no request is compared a chapter at a
time like any other (codegen/verify/bounded.py), with the verdict the whole run gives; one with M0/M1 (whose
pauses wait for resume frames) and one with --hold are simulated whole (codegen/verify/hold.py)."""

from __future__ import annotations

import json
import shutil

import pytest

import codegen.cli.stream
from codegen.cli.main import main
from tests.helpers import ROOT

pytestmark = pytest.mark.skipif(shutil.which("avr-gcc") is None or shutil.which("simavr") is None,
                                reason="needs gcc-avr and simavr (scripts/setup.sh installs them)")


@pytest.fixture
def taken(monkeypatch):
    """The comparisons verify --stream ran, by name."""
    seen: list[str] = []
    for name in ("simulate_stream_bounded", "simulate_stream", "hold_verify"):
        real = getattr(codegen.cli.stream, name)

        def spied(*args, _real=real, _name=name, **kw):
            seen.append(_name)
            return _real(*args, **kw)

        monkeypatch.setattr(codegen.cli.stream, name, spied)
    return seen


def test_a_feed_hold_stream_without_requests_is_compared_a_chapter_at_a_time(taken, tmp_path, capsys, monkeypatch):
    star = str(ROOT / "examples" / "star.yaml")
    assert main(["verify", star, "--stream", "--json", "--out", str(tmp_path)]) == 0
    bounded = json.loads(capsys.readouterr().out)
    assert taken == ["simulate_stream_bounded"] and bounded["pass"]
    monkeypatch.setattr(codegen.cli.stream, "bounded", lambda *args, **kw: False)
    assert main(["verify", star, "--stream", "--json", "--out", str(tmp_path)]) == 0
    assert taken[1:] == ["simulate_stream"] and json.loads(capsys.readouterr().out) == bounded


def test_m0_and_hold_requests_are_simulated_whole(taken, tmp_path, capsys):
    pen_change = str(ROOT / "examples" / "gcode" / "pen-change.yaml")
    assert main(["verify", pen_change, "--stream", "--out", str(tmp_path)]) == 0
    assert "M0/M1 pause: at rest" in capsys.readouterr().out
    assert main(["verify", str(ROOT / "examples" / "star.yaml"), "--stream", "--hold", "1.0", "--out",
                 str(tmp_path / "star")]) == 0
    assert taken == ["hold_verify", "hold_verify"]
