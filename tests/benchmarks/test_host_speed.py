"""benchmarks/host_speed.py still runs against the pipeline it times (its Segments are built by hand)."""

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "host_speed.py"


@pytest.mark.parametrize("kinematics", ["cartesian", "delta"])
def test_host_speed_runs_and_its_checks_pass(kinematics):
    done = subprocess.run([sys.executable, str(SCRIPT), "--segments", "300", "--kinematics", kinematics],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "checks: pass" in done.stdout and "bytes/step" in done.stdout
