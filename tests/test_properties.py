"""Property tests: random machines and programs on both table formats (tests/jobgen.py). A job the loader
accepts builds with every check passing, or is refused with a positioned error or a size error.

The short profile here is derandomized (the same examples on every run); scripts/property_run.py runs the
long one."""

import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings

from tests.jobgen import TARGETS, jobs, outcome

SHORT = settings(max_examples=35, deadline=None, derandomize=True, database=None,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("kinematics", ["cartesian", "corexy", "delta"])
def test_every_accepted_job_builds_or_is_refused_cleanly(kinematics, target):
    @SHORT
    @given(jobs(kinematics, target))
    def check(text):
        with tempfile.TemporaryDirectory() as folder:
            outcome(text, Path(folder))

    check()


FOUND = sorted((Path(__file__).resolve().parent / "data" / "jobs" / "found").glob("*.yaml"))


@pytest.mark.parametrize("job", FOUND, ids=lambda p: p.stem)
def test_jobs_the_generator_found_build(job, tmp_path):
    """The minimal jobs hypothesis shrank each bug it found to (tests/data/jobs/found): each broke a limit."""
    assert outcome(job.read_text(), tmp_path) == "built"
