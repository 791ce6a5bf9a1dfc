"""codegen/report/junit.py on hand-made cases: the counts, the escaping, the times, the figures."""

import xml.etree.ElementTree as ET

from codegen.report.junit import CLASSNAME, junit_xml, seconds, write_junit

RESULT = {"pass": True, "target": "avr", "duration_s": 3.131761, "planned_duration_s": 3.131698,
          "max_path_error_mm": 0.00555, "path_limit_mm": 0.010839,
          "motors": {"a": {"steps": 61426, "final": 6400, "expected_final": 6400, "max_timing_error_us": 0.75},
                     "b": {"steps": 61426, "final": -6400, "expected_final": -6400, "max_timing_error_us": None}},
          "image": {"flash_bytes": 5282, "ram_bytes": 24, "table_bytes": 1896}, "problems": []}
NASTY = 'x "quoted" <tag> & \'apostrophe\'\nsecond line\tTab\x1b[31m red\x00'


def case(job, status="PASS", kind="verification", problems=(), stderr="", result=None, **more):
    return {"job": job, "status": status, "kind": kind, "wall_s": 1.5, "problems": list(problems), "stderr": stderr,
            "target": (result or {}).get("target"), "stream": False, "note": "", "result": result, **more}


def parsed(cases, total_s=12.0):
    return ET.fromstring(junit_xml(cases, total_s))


def test_testsuites_testsuite_testcase_with_counts():
    root = parsed([case("a.yaml", result=RESULT),
                   case("b.yaml", "FAIL", problems=["x: ends at 7", "y: late"], result={**RESULT, "pass": False}),
                   case("c.yaml", "ERROR", "bad input", ["c.yaml:1:1: error: no such file"],
                        stderr="c.yaml:1:1: error: no such file\n"),
                   case("d.yaml", "FAIL", "crash", ["the child was killed by SIGKILL"])], total_s=61.25)
    assert root.tag == "testsuites" and [child.tag for child in root] == ["testsuite"]
    for element in (root, root[0]):
        assert (element.get("tests"), element.get("failures"), element.get("errors")) == ("4", "2", "1")
        assert element.get("time") == "61.250"
    assert root[0].get("skipped") == "0"
    cases = root[0].findall("testcase")
    assert [c.get("name") for c in cases] == ["a.yaml", "b.yaml", "c.yaml", "d.yaml"]
    assert {c.get("classname") for c in cases} == {CLASSNAME} and {c.get("time") for c in cases} == {"1.500"}
    assert cases[0].find("failure") is None and cases[0].find("error") is None
    failure = cases[1].find("failure")
    assert failure.get("message") == "x: ends at 7" and failure.get("type") == "verification"
    assert failure.text == "x: ends at 7\ny: late"
    error = cases[2].find("error")
    assert error.get("type") == "bad input" and error.text == "c.yaml:1:1: error: no such file"  # not twice
    assert cases[2].find("system-err") is None  # the error's text is the child's stderr already
    assert cases[3].find("failure").get("message") == "the child was killed by SIGKILL"


def test_messages_are_escaped_and_read_back():
    root = parsed([case("we<ird> & \"name\".yaml", "FAIL", problems=[NASTY], stderr=NASTY + "\n")])
    testcase = root.find("testsuite/testcase")
    assert testcase.get("name") == 'we<ird> & "name".yaml'
    readable = NASTY.replace("\x1b", "\ufffd").replace("\x00", "\ufffd")  # not XML 1.0 characters
    assert testcase.find("failure").get("message") == readable  # newline and tab kept in the attribute
    assert testcase.find("failure").text == readable
    assert testcase.find("system-err").text == readable.strip()


def test_figures_as_properties_and_system_out():
    testcase = parsed([case("star.yaml", result=RESULT, stderr="star.yaml:3:1: warning: something\n")]).find(
        "testsuite/testcase")
    props = {p.get("name"): p.get("value") for p in testcase.find("properties")}
    assert props["duration_s"] == "3.131761" and props["planned_duration_s"] == "3.131698"
    assert props["motors.a.steps"] == "61426" and props["motors.b.final"] == "-6400"
    assert props["motors.a.max_timing_error_us"] == "0.75" and "motors.b.max_timing_error_us" not in props
    assert props["max_path_error_mm"] == "0.00555" and props["image.table_bytes"] == "1896"
    assert props["target"] == "avr" and props["firmware"] == "flash" and props["wall_s"] == "1.500"
    assert "duration_s: 3.131761" in testcase.find("system-out").text.splitlines()
    assert testcase.find("system-err").text == "star.yaml:3:1: warning: something"  # a passing job's warnings


def test_a_streamed_job_names_its_link():
    result = {**RESULT, "link": {"baud": 9600, "bytes": 8600, "retransmits": 0, "underruns": 0}}
    testcase = parsed([case("s.yaml", result=result, stream=True, note="too big for flash, verified with --stream")]
                      ).find("testsuite/testcase")
    props = {p.get("name"): p.get("value") for p in testcase.find("properties")}
    assert props["firmware"] == "stream" and props["link.bytes"] == "8600" and props["link.baud"] == "9600"
    assert "too big for flash" in testcase.find("system-out").text


def test_times_are_plain_decimals():
    assert seconds(0.0) == "0.000" and seconds(1e-7) == "0.000" and seconds(12345.6789) == "12345.679"
    assert seconds(-0.001) == "0.000"  # a clock step backwards never makes a negative time


def test_write_junit_writes_the_file(tmp_path):
    path = tmp_path / "ci" / "verify.xml"
    write_junit(path, [case("a.yaml", result=RESULT)], 2.0)
    text = path.read_text(encoding="utf-8")
    assert text.startswith("<?xml version='1.0' encoding='utf-8'?>")
    assert ET.parse(path).getroot().get("tests") == "1"
