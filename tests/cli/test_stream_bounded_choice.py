"""verify --stream picks its comparison: a job with machine.feed_hold and no request is compared a chapter at a
time like any other (codegen/verify/bounded.py); one with M0/M1 (whose pauses wait for resume frames) or --hold
on an ATmega2560 goes to codegen/verify/hold.py with a build that keeps only its tables, compared a chapter at a
time too (codegen/verify/hold_bounded.py); each with the verdict the whole run gives."""

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


@pytest.mark.parametrize("example, options", [("gcode/pen-change.yaml", []), ("star.yaml", ["--hold", "1.0"]),
                                              ("star.yaml", ["--override", "50"])])
def test_m0_and_requests_on_a_stream_are_compared_a_chapter_at_a_time(taken, tmp_path, capsys, monkeypatch,
                                                                       example, options):
    hosts = []
    hold_verify = codegen.cli.stream.hold_verify
    monkeypatch.setattr(codegen.cli.stream, "hold_verify", lambda host, *a, **kw: hosts.append(host) or
                        hold_verify(host, *a, **kw))
    command = ["verify", str(ROOT / "examples" / example), "--stream", "--json", "--out", str(tmp_path), *options]
    assert main(command) == 0
    bounded = json.loads(capsys.readouterr().out)
    assert hosts[0].pulses is None and bounded["pass"]  # the tables only
    streamed_host = codegen.cli.stream.streamed_host
    monkeypatch.setattr(codegen.cli.stream, "streamed_host", lambda *a, keep, **kw: streamed_host(*a, keep=True, **kw))
    assert main(command) == 0
    assert hosts[1].pulses is not None and json.loads(capsys.readouterr().out) == bounded
