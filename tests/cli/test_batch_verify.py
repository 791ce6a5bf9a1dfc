"""`verify JOB.yaml... | DIR --jobs N --junit FILE.xml` end to end: real children, real compilers and simulators,
over a folder of small jobs (never examples/printers: the Benchy takes minutes)."""

import json
import shutil
import sys
import xml.etree.ElementTree as ET

import pytest

from codegen.cli import batch
from codegen.cli.main import parser
from tests.helpers import EXAMPLES
from tests.helpers import run_cli as run

needs_tools = pytest.mark.skipif(any(shutil.which(t) is None for t in ("avr-gcc", "simavr", "sdcc", "s51")),
                                 reason="needs gcc-avr, simavr, sdcc and s51 (scripts/setup.sh installs them)")


def jobs_folder(root):
    """Two AVR examples, an 8051 job (plotter-set-51's first line), a misspelt key (bad input) and the seed-51
    drawing set with jog keys: too big for flash, so streamed, which the 8051's streaming firmware refuses."""
    jobs = root / "jobs"
    (jobs / "sub").mkdir(parents=True)
    for name in ("line.yaml", "star.yaml"):
        shutil.copy(EXAMPLES / name, jobs / name)
    text = (EXAMPLES / "plotter-set-51.yaml").read_text()
    (jobs / "sub" / "line-51.yaml").write_text(text[:text.index("    - arc:")].replace("plotter-set-51", "line-51"))
    (jobs / "sub" / "bad-key.yaml").write_text((EXAMPLES / "line.yaml").read_text()
                                               .replace("max_accel: 2000, range", "max_acel: 2000, range", 1)
                                               .replace("name: line", "name: bad-key"))
    (jobs / "too-big-jog.yaml").write_text((EXAMPLES / "stream" / "plotter-set-seed51.yaml").read_text()
                                           .replace("  kinematics: cartesian", "  kinematics: cartesian\n"
                                                    "  jog: {speeds: [300]}")
                                           .replace("name: plotter-set-seed51", "name: too-big-jog"))
    return jobs


@needs_tools
def test_a_folder_verifies_in_parallel_with_a_table_and_a_junit_file(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the table names the jobs as found: jobs/...
    jobs_folder(tmp_path)
    code, out, err = run(capsys, "verify", "jobs", "--jobs", "2", "--junit", "r.xml", "--out", "out")
    assert code == 2, out + err  # a bad-input job outranks a failed one
    rows = {line.split()[0]: line for line in out.splitlines() if line.startswith("jobs/")}
    assert list(rows) == ["jobs/line.yaml", "jobs/star.yaml", "jobs/sub/bad-key.yaml", "jobs/sub/line-51.yaml",
                          "jobs/too-big-jog.yaml"]  # recursive, sorted
    assert rows["jobs/line.yaml"].split()[1:3] == ["avr", "PASS"]
    assert rows["jobs/sub/line-51.yaml"].split()[1:3] == ["mcs51", "PASS"]
    assert rows["jobs/sub/bad-key.yaml"].split()[2] == "ERROR" and "max_acel" in rows["jobs/sub/bad-key.yaml"]
    assert rows["jobs/too-big-jog.yaml"].split()[1:4] == ["mcs51", "stream*", "FAIL"]
    assert "no jog mode" in rows["jobs/too-big-jog.yaml"]
    assert "5 jobs: 3 passed, 1 failed, 1 bad input; 2 at a time" in out
    assert "stream*: too big for flash" in out
    assert err.count("[") == 5  # a progress line per job on stderr
    assert (tmp_path / "out" / "line" / "firmware.hex").is_file()  # --out: the jobs' parent folder
    assert (tmp_path / "out" / "line-51" / "firmware.hex").is_file()

    suites = ET.parse(tmp_path / "r.xml").getroot()
    assert suites.tag == "testsuites" and [s.tag for s in suites] == ["testsuite"]
    suite = suites[0]
    for counts in (suites.attrib, suite.attrib):
        assert (counts["tests"], counts["failures"], counts["errors"]) == ("5", "1", "1")
        assert float(counts["time"]) > 0
    cases = {c.get("name"): c for c in suite.iter("testcase")}
    assert set(cases) == set(rows)
    assert {c.get("classname") for c in cases.values()} == {"printer-codegen.verify"}
    line = cases["jobs/line.yaml"]
    assert line.find("failure") is None and line.find("error") is None
    props = {p.get("name"): p.get("value") for p in line.iter("property")}
    result = json.loads(run(capsys, "verify", tmp_path / "jobs" / "line.yaml", "--out", "out/line", "--json")[1])
    assert float(props["duration_s"]) == result["duration_s"]  # the same image again, reused
    assert int(props["motors.x.steps"]) == result["motors"]["x"]["steps"] == 7200
    assert float(props["max_path_error_mm"]) == result["max_path_error_mm"]
    assert "motors.y.max_timing_error_us" in props and "motors.x.steps: 7200" in line.find("system-out").text
    bad = cases["jobs/sub/bad-key.yaml"].find("error")
    assert bad.get("type") == "bad input" and "bad-key.yaml:8:46: error:" in bad.get("message")
    assert "^" in bad.text  # the whole diagnostic, caret and all
    failed = cases["jobs/too-big-jog.yaml"].find("failure")
    assert failed.get("type") == "build" and "no jog mode" in failed.get("message")
    assert "too big for flash, verified with --stream (job too-big-jog does not fit in flash" in failed.text


@needs_tools
def test_one_job_with_junit_keeps_its_out_folder(tmp_path, capsys):
    code, out, _ = run(capsys, "verify", EXAMPLES / "line.yaml", "--junit", tmp_path / "one.xml",
                       "--out", tmp_path / "b", "--quiet")
    assert code == 0 and "1 jobs: 1 passed, 0 failed, 0 bad input; 1 at a time" in out
    assert (tmp_path / "b" / "firmware.hex").is_file()  # --out is the job's own folder, as without --junit
    assert ET.parse(tmp_path / "one.xml").getroot()[0].get("tests") == "1"


def test_one_job_file_is_the_single_verify():
    p = parser()
    assert not batch.is_batch(p.parse_args(["verify", "a.yaml"]))
    assert batch.is_batch(p.parse_args(["verify", "a.yaml", "b.yaml"]))
    assert batch.is_batch(p.parse_args(["verify", "a.yaml", "--junit", "r.xml"]))
    assert batch.is_batch(p.parse_args(["verify", "a.yaml", "--jobs", "1"]))
    assert batch.is_batch(p.parse_args(["verify", str(EXAMPLES)]))
    assert p.parse_args(["build", "a.yaml"]).job == "a.yaml"  # the other verbs still take one job


@pytest.mark.parametrize("option", ["--trace", "--vcd", "--report"])
def test_one_file_options_are_refused_with_several_jobs(tmp_path, capsys, option):
    code, out, err = run(capsys, "verify", EXAMPLES / "line.yaml", EXAMPLES / "arc.yaml", option, tmp_path / "f")
    assert code == 2 and out == "" and f"{option}: error: writes one job's file" in err


def test_an_empty_folder_and_a_bad_count_are_usage_errors(tmp_path, capsys):
    code, _, err = run(capsys, "verify", tmp_path)
    assert code == 2 and "holds no *.yaml job file" in err
    with pytest.raises(SystemExit) as stop:
        parser().parse_args(["verify", "a.yaml", "--jobs", "0"])
    assert stop.value.code == 2


def test_every_verify_option_reaches_the_children():
    """A verify option added later must be passed on to each job (or handled by the batch): else a folder run
    would quietly verify without it."""
    verify = parser()._subparsers._group_actions[0].choices["verify"]
    handled = set(batch.VALUES) | set(batch.SWITCHES) | set(batch.ONE_JOB) | {
        "help", "job", "out", "json", "quiet", "fault", "resonance", "jobs", "junit"}
    assert {action.dest for action in verify._actions} <= handled


def test_child_flags_read_back_as_given():
    argv = ["--target", "mcs51", "--strict", "--stream", "--baud", "9600", "--hold", "1.25", "--override", "50",
            "--fault", "thermistor-open:bed@30", "--fault", "heater-dead@2.5", "--resonance", "x=48.2,0.07",
            "--resonance", "y=52"]
    given = parser().parse_args(["verify", "a.yaml", "b.yaml", *argv])
    flags = batch.child_flags(given)
    again = parser().parse_args(["verify", "a.yaml", *flags])
    for dest in ("target", "strict", "stream", "baud", "hold", "override", "fault", "resonance"):
        assert getattr(again, dest) == getattr(given, dest), dest


@pytest.mark.parametrize("code, stdout, stderr, expected", [
    (1, json.dumps({"pass": False, "problems": ["x: 3 steps late", "y: ends at 7"]}), "",
     ("FAIL", "verification", "x: 3 steps late")),
    (0, json.dumps({"pass": True, "problems": []}), "a.yaml:3:1: warning: skipped", ("PASS", "verification", None)),
    (2, "", "a.yaml:8:46: error: unknown key\n  x: 1\n  ^", ("ERROR", "bad input", "a.yaml:8:46: error: unknown key")),
    (1, "", "error: the image does not fit in flash", ("FAIL", "build", "the image does not fit in flash")),
    (-9, "", "", ("FAIL", "crash", "the child was killed by SIGKILL")),
    (1, "", "Traceback (most recent call last):\n  ...\nZeroDivisionError: division by zero",
     ("FAIL", "crash", "the child crashed (exit 1): ZeroDivisionError: division by zero")),
    (0, "not json", "", ("FAIL", "crash", "the child ended without a result (exit 0)")),
])
def test_a_childs_end_makes_its_verdict(code, stdout, stderr, expected):
    status, kind, problems, _ = batch._verdict(code, stdout, stderr)
    assert (status, kind, problems[0] if problems else None) == expected


def test_a_killed_child_is_a_failed_case_with_its_signal():
    code, stdout, stderr, _ = batch._child(
        [sys.executable, "-c", "import os, signal; print('{'); os.kill(os.getpid(), signal.SIGKILL)"], set())
    assert batch._verdict(code, stdout, stderr)[:3] == ("FAIL", "crash", ["the child was killed by SIGKILL"])
