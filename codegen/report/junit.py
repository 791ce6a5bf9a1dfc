"""The JUnit XML of a `verify` run over many jobs (codegen/cli/batch.py): testsuites > testsuite > testcase, one
case per job, as Jenkins, GitLab, junitparser and the GitHub Actions reporters read it.

A case is a dict: `job` (its path, the case's name), `status` (PASS, FAIL or ERROR: bad input), `kind` (what
failed: verification, build, crash, bad input), `wall_s`, `problems` (the first is the failure's message),
`stderr` (the child's), `target`, `stream`, `note` and `result` (its `verify --json` object, or None). The figures
(durations, steps, timing and path error, sizes, the link's) go into the case's <properties>, as pytest's
record_property writes them, and again as `name: value` lines into <system-out> for readers that drop those."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

CLASSNAME = "printer-codegen.verify"
SUITE = "printer-codegen verify"
# XML 1.0 has no other characters: a compiler's colour escape in a child's stderr would make the file unreadable
_NOT_XML = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")


def clean(text: str) -> str:
    return _NOT_XML.sub("\ufffd", text)


def seconds(value: float) -> str:
    """JUnit's time: seconds with a decimal point, never an exponent."""
    return f"{max(value, 0.0):.3f}"


def figures(case: dict) -> list[tuple[str, str]]:
    """The case's figures as (name, value) pairs, in a fixed order; absent figures are left out."""
    pairs = [("wall_s", seconds(case["wall_s"]))]
    if case.get("target"):
        pairs.append(("target", case["target"]))
    pairs.append(("firmware", "stream" if case.get("stream") else "flash"))
    result = case.get("result") or {}
    for key in ("duration_s", "planned_duration_s", "max_path_error_mm", "path_limit_mm"):
        if result.get(key) is not None:
            pairs.append((key, str(result[key])))
    for name, motor in result.get("motors", {}).items():
        for key in ("steps", "final", "expected_final", "max_timing_error_us"):
            if motor.get(key) is not None:
                pairs.append((f"motors.{name}.{key}", str(motor[key])))
    for group, keys in (("image", ("flash_bytes", "ram_bytes", "table_bytes")),
                        ("link", ("baud", "bytes", "retransmits", "underruns", "min_ring_fill_bytes"))):
        for key in keys:
            if (result.get(group) or {}).get(key) is not None:
                pairs.append((f"{group}.{key}", str(result[group][key])))
    return pairs


def _case(suite: ET.Element, case: dict) -> None:
    element = ET.SubElement(suite, "testcase", classname=CLASSNAME, name=clean(case["job"]),
                            time=seconds(case["wall_s"]))
    pairs = figures(case)
    properties = ET.SubElement(element, "properties")
    for name, value in pairs:
        ET.SubElement(properties, "property", name=name, value=clean(value))
    note = [case["note"]] if case.get("note") else []
    stderr = case["stderr"].strip()
    told = case["status"] != "PASS" and case["kind"] != "verification"  # the child's stderr says why: all of it
    if case["status"] != "PASS":
        problems = case["problems"] or [f"{case['kind']} failed"]
        head = [] if told and all(p in stderr for p in problems) else problems  # not twice over
        text = "\n".join(head + note + ([stderr] if told else []))
        tag = "error" if case["status"] == "ERROR" else "failure"
        ET.SubElement(element, tag, message=clean(problems[0]), type=case["kind"]).text = clean(text)
    lines = [f"{case['status']} {case['job']}"] + note + [f"{n}: {v}" for n, v in pairs]
    ET.SubElement(element, "system-out").text = clean("\n".join(lines))
    if stderr and not told:  # warnings and notes of a job that ran
        ET.SubElement(element, "system-err").text = clean(stderr)


def junit_xml(cases: list[dict], total_s: float) -> bytes:
    """The whole file: `total_s` is the run's wall time (the jobs overlap, so it is not their sum)."""
    counts = {"tests": str(len(cases)),
              "failures": str(sum(c["status"] == "FAIL" for c in cases)),
              "errors": str(sum(c["status"] == "ERROR" for c in cases)),
              "time": seconds(total_s)}
    root = ET.Element("testsuites", name=SUITE, **counts)
    suite = ET.SubElement(root, "testsuite", name=SUITE, skipped="0", **counts)
    for case in cases:
        _case(suite, case)
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n"


def write_junit(path: Path, cases: list[dict], total_s: float) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(junit_xml(cases, total_s))
