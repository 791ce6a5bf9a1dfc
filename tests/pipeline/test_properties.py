"""Property tests: random machines and programs on both table formats (tests/jobgen/). A job the loader
accepts builds with every check passing, or is refused with a positioned error (exit 2) or a size error (exit 1).

The short profile here is derandomized (the same ~200 examples on every run, about 35 per kinematics and
format), with issue 29's input shapers, pressure advance and their G-code. scripts/property_run.py runs the long
one and writes each failure class's minimal job (tests/data/jobs/open while open, found once fixed)."""

import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings

from tests.helpers import DATA
from tests.jobgen import KINEMATICS, TARGETS, Bug, jobs, outcome

SHORT = settings(max_examples=34, deadline=None, derandomize=True, database=None, print_blob=True,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                        HealthCheck.filter_too_much])


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("kinematics", KINEMATICS)
def test_every_accepted_job_builds_or_is_refused_cleanly(kinematics, target):
    @SHORT
    @given(jobs(kinematics, target))
    def check(text):
        with tempfile.TemporaryDirectory() as folder:
            outcome(text, Path(folder))  # raises tests.jobgen.Bug, with the job's text shown by hypothesis

    check()


FOUND = sorted((DATA / "jobs" / "found").glob("*.yaml"))


@pytest.mark.parametrize("job", FOUND, ids=lambda p: p.stem)
def test_jobs_the_generator_found_build(job, tmp_path):
    """The minimal jobs the generator shrank each bug it found to (tests/data/jobs/found)."""
    assert outcome(job.read_text(), tmp_path) == "built"


OPEN = sorted((DATA / "jobs" / "open").glob("*.yaml"))


@pytest.mark.xfail(raises=Bug, strict=True, reason="open bugs the generator found, not yet fixed (each file's "
                                                    "comment: the message and what makes it build)")
@pytest.mark.parametrize("job", OPEN, ids=lambda p: p.stem)
def test_jobs_the_generator_found_open(job, tmp_path):
    """The minimal jobs of bugs the generator found and nobody fixed yet (tests/data/jobs/open): once one builds,
    it moves to tests/data/jobs/found."""
    assert outcome(job.read_text(), tmp_path) == "built"
