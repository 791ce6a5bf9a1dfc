"""The fuzz suite's machinery (tests/fuzzing/) on fake pipelines: the classifier, the worker pool's limits, the
shrinker and a whole small campaign. The real pipeline's short run is tests/test_fuzz_short.py."""

from __future__ import annotations

import io
import os
import signal
import time

from codegen.errors import BuildError, Diagnostic, JobError, SourceRef
from tests.fuzzing.campaign import Budget, Settings, fuzz, shrink, table
from tests.fuzzing.inputs import FuzzInput, make_input
from tests.fuzzing.outcomes import (BUILD_FAILED, CRASH, HANG, LONG, LONG_EVENTS_PER_S, MEMORY, OK, REFUSED, TRACEBACK,
                                    UNPOSITIONED, classify, innermost_codegen_frame, plan_file)
from tests.fuzzing.pool import GiB, WorkerPool, _alarm
from tests.helpers import EXAMPLES


def _raise(error: BaseException):
    def call() -> int:
        raise error
    return call


def test_classify_names_each_outcome():
    positioned = JobError([Diagnostic(SourceRef("job.yaml", 3, 5), "bad")])
    unpositioned = JobError([Diagnostic(SourceRef("job.yaml"), "not UTF-8 text (byte 12)")])
    assert classify(lambda: 0).kind == OK
    assert classify(_raise(positioned)).kind == REFUSED
    assert classify(_raise(BuildError("too big"))).kind == BUILD_FAILED
    outcome = classify(_raise(unpositioned))
    assert (outcome.kind, outcome.signature) == (UNPOSITIONED, "unpositioned refusal: not UTF-N text (byte N)")
    outcome = classify(_raise(KeyError("x")))
    assert (outcome.kind, outcome.signature) == (TRACEBACK, "KeyError in ?")
    assert classify(_raise(MemoryError())).kind == MEMORY


def test_signature_is_the_innermost_codegen_frame():
    python = ('Traceback (most recent call last):\n  File "/r/codegen/cli/main.py", line 3, in cmd_plan\n'
              '  File "/r/codegen/job/loader.py", line 9, in read_yaml\n  File "/v/yaml/reader.py", line 1, in x\n')
    faulthandler = ('Timeout (0:00:23)!\nThread 0x1 (most recent call first):\n'
                    '  File "/r/codegen/motion/planner.py", line 5 in plan\n  File "/r/codegen/cli/main.py", line 3 in '
                    'cmd_plan\n')
    assert innermost_codegen_frame(python) == "codegen/job/loader.py:read_yaml"
    assert innermost_codegen_frame(faulthandler) == "codegen/motion/planner.py:plan"


def fake_pipeline(item: FuzzInput) -> int:
    """Fails on the words in its G-code: BOOM raises, SPIN works forever, MASKED does with SIGPROF blocked (only
    the watchdog ends it), SLEEP waits forever (the wall clock's watchdog ends it), NAP waits longer than the CPU
    time limit but works little (a worker sharing its core: not a hang), GREEDY asks for 2 GiB, SEGV dies by a
    signal."""
    gcode = item.gcode or b""
    if b"BOOM" in gcode:
        raise ValueError("boom")
    if b"MASKED" in gcode:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGPROF})
        _spin()
    if b"SPIN" in gcode:
        _spin()
    if b"SLEEP" in gcode:
        time.sleep(60)
    if b"NAP" in gcode:
        time.sleep(1.0)
    if b"GREEDY" in gcode:
        bytearray(2 * GiB)
    if b"SEGV" in gcode:
        os.kill(os.getpid(), signal.SIGSEGV)
    return 0


def _spin() -> None:
    while True:
        pass


def test_pool_classifies_hangs_memory_and_crashes_and_replaces_workers():
    words = [b"G1 X1", b"SPIN", b"NAP", b"GREEDY", b"SEGV", b"MASKED", b"SLEEP", b"BOOM", b"G0"]
    with WorkerPool(fake_pipeline, jobs=2, time_limit=0.5, memory_bytes=1 * GiB) as pool:
        outcomes = dict(pool.imap((w, FuzzInput(b"", w)) for w in words))
    kinds = {word: outcome.kind for word, outcome in outcomes.items()}
    assert kinds == {b"G1 X1": OK, b"SPIN": HANG, b"NAP": OK, b"GREEDY": MEMORY, b"SEGV": CRASH, b"MASKED": HANG,
                     b"SLEEP": HANG, b"BOOM": TRACEBACK, b"G0": OK}
    assert outcomes[b"SEGV"].signature.startswith("crash by SIGSEGV")
    assert "Timeout (" not in outcomes[b"SPIN"].detail  # the CPU time limit's Hang
    assert "Timeout (" in outcomes[b"MASKED"].detail and "Timeout (" in outcomes[b"SLEEP"].detail  # the watchdog's


def test_shrink_keeps_the_smallest_input_that_fails_the_same_way():
    failing = FuzzInput(b"name: x\nmachine: {kinematics: cartesian}\n",
                        b"G21 G90\nG1 X10 Y10 F1200\nG1 X20 BOOM Y5 ; here\nM5\n")

    def reproduces(candidates):
        return next((k for k, c in enumerate(candidates) if classify(lambda: fake_pipeline(c)).kind == TRACEBACK),
                    None)

    shrunk = shrink(failing, reproduces, batch=2)
    assert (shrunk.gcode, shrunk.job) == (b"BOOM", b"")


def test_shrink_stops_at_its_budget():
    failing = FuzzInput(b"", b"BOOM " * 200)
    calls = []

    def reproduces(candidates):  # never the same failure: every deletion would be tried but for the budget
        calls.append(len(candidates))
        return None

    assert shrink(failing, reproduces, batch=2, budget=Budget(attempts=5)) == failing
    assert sum(calls) <= 6 and len(calls) == 3


def test_inputs_are_the_same_for_a_seed():
    first = [make_input(28, k) for k in range(30)]
    assert first == [make_input(28, k) for k in range(30)]
    assert first != [make_input(29, k) for k in range(30)]
    assert any(item.gcode is not None for item in first) and any(item.gcode is None for item in first)


def gcode_is_a_bug(item: FuzzInput) -> int:
    if item.gcode is not None and b"G" in item.gcode:
        raise ZeroDivisionError("G")
    return 0


def test_a_campaign_writes_each_signature_shrunk(tmp_path):
    settings = Settings(seed=28, count=8, jobs=2, out=tmp_path, shrink_seconds=30)
    results = fuzz(settings, gcode_is_a_bug, stream=io.StringIO())
    assert results.inputs == 8
    (finding,) = results.findings.values()
    assert finding.signature == "ZeroDivisionError in ?" and finding.count == results.kinds[TRACEBACK] > 0
    assert (finding.path.read_bytes(), (finding.path.parent / "input.gcode").read_bytes()) == (b"", b"G")
    assert str(finding.path) in table(results)


def test_an_empty_campaign_has_no_table_rows(tmp_path):
    results = fuzz(Settings(count=0, out=tmp_path), gcode_is_a_bug, stream=io.StringIO())
    assert results.inputs == 0 and table(results).count("\n") == 0


def test_a_plan_at_the_planners_pace_at_its_time_limit_is_long_not_a_hang(monkeypatch):
    """A job of millions of steps runs past the limit while planning as fast as it should: LONG. The same
    interruption with nothing planned (a stage that never ends) is a hang. The front end in this process, as in the
    pool's workers: the CPU time limit counts this process's time only."""
    LIMIT_S = 0.8  # s of CPU: the Benchy's plan takes about twice that here
    monkeypatch.setenv("PRINTER_CODEGEN_JOBS", "1")
    previous = signal.signal(signal.SIGPROF, _alarm)  # the pool's CPU time limit
    try:
        signal.setitimer(signal.ITIMER_PROF, LIMIT_S)
        outcome = classify(lambda: plan_file(EXAMPLES / "printers" / "benchy-mini.yaml"), LIMIT_S)
        signal.setitimer(signal.ITIMER_PROF, 0.5)
        stuck = classify(lambda: _spin() or 0, 0.5)
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0)
        signal.signal(signal.SIGPROF, previous)
    assert outcome.kind == LONG and int(outcome.detail.split()[0]) >= LIMIT_S * LONG_EVENTS_PER_S
    assert (stuck.kind, stuck.signature) == (HANG, "hang in ?")
