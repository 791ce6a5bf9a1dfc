"""Fixtures shared by the whole suite: the example jobs that several test files plan or build, made once per
session. The suite runs on every core (pyproject.toml: pytest-xdist, `-n auto --dist worksteal`): a session here
is one worker's, so a fixture is made at most once per worker; the tests of one file mostly run on one worker.

What these fixtures return is shared by every test that asks for it: read it, never change it in place (copy an
array before editing it, dataclasses.replace a host or a config).

Each worker's files go to its own tmp_path_factory folder (pytest's basetemp/popen-gw<N>), so no two workers
write one folder. The native helpers and the simavr harness that codegen compiles into ~/.cache/printer-codegen
at first use are written to a temporary file and renamed into place (codegen/native/__init__.py,
codegen/sim/avr.py), so two workers that build them at once from an empty cache each load a whole file.
"""

from __future__ import annotations

import pytest

from tests.helpers import EXAMPLES, streamed

# Modules whose tests take 10 s and more each (simulated streams, the 8051's holds, every example end to end): run
# first, so that the two workers do not end on one of them while the other waits (pytest-xdist worksteal).
SLOW_FIRST = ("tests/verify/test_stream_examples.py", "tests/firmware/mcs51/test_stream_iram.py",
              "tests/cli/test_end_to_end.py", "tests/verify/test_hold_mcs51.py",
              "tests/verify/test_hold_mcs51_stream.py", "tests/report/test_html.py", "tests/pipeline/test_properties.py",
              "tests/tables/test_hold.py", "tests/verify/test_bounded.py", "tests/verify/test_pins.py",
              "tests/test_fuzz_short.py")


def pytest_collection_modifyitems(items: list) -> None:
    rank = {name: k for k, name in enumerate(SLOW_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))  # stable: the rest as collected


@pytest.fixture(scope="session")
def planned_example():
    """examples/<name> (e.g. "star.yaml", "gcode/mixed.yaml") planned by host_build, once per session."""
    from codegen.job import load_job
    from codegen.pipeline.host import host_build

    hosts = {}

    def get(name: str):
        if name not in hosts:
            hosts[name] = host_build(load_job(EXAMPLES / name))
        return hosts[name]

    return get


@pytest.fixture(scope="session")
def star_host(planned_example):
    """examples/star.yaml (corexy, RAMPS, feed hold) planned."""
    return planned_example("star.yaml")


@pytest.fixture(scope="session")
def star_flash(tmp_path_factory):
    """examples/star.yaml built into a flash image as `build` does: (host, image)."""
    from codegen.cli.main import _build
    from codegen.job import load_job

    out = tmp_path_factory.mktemp("star-flash")
    host, image, _ = _build(load_job(EXAMPLES / "star.yaml"), str(out), reuse=False, strict=False)
    return host, image


@pytest.fixture(scope="session")
def star_stream(tmp_path_factory):
    """examples/star.yaml for the streaming firmware as `stream` plans it: (host, image, setup)."""
    return streamed(EXAMPLES / "star.yaml", tmp_path_factory.mktemp("star-stream"))

