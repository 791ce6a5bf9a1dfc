"""`verify JOB.yaml... | DIR [--jobs N] [--junit FILE.xml]` (CLI.md): many jobs verified in parallel, one summary
table, a JUnit file for CI. One job file without --jobs or --junit is main.py's single verify, not this.

Each job is a child process, `python -m codegen verify JOB --json --quiet` (CHILD) with this run's flags, at most
N at once; its JSON (stdout) and stderr make its case (codegen/report/junit.py). The rules, also in `verify --help`:
- a folder stands for every *.yaml under it, recursively, in sorted order; one that is not a job is a case of its
  own with the loader's error (bad input);
- every flag goes to every job; --out DIR with several jobs is their parent folder (DIR/<name>/); --trace, --vcd
  and --report write one job's file and are refused with several job files or a folder;
- a job whose flash image is refused as too big for flash, without --stream, is verified again with --stream (the
  machine's streaming firmware over machine.link; every job has a link, defaults filled): `stream*` in the table;
- the exit code is 2 if any job is bad input, else 1 if any failed (build, verification, a crashed child), else 0.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import yaml

from codegen.errors import Diagnostic, JobError, SourceRef

# `python -m codegen`, but with this codegen/ first on the path: -m would put the working folder first, and a
# checkout there would answer for an installed printer-codegen
CHILD = "import sys; sys.path[0] = sys.argv.pop(1); from codegen.cli.main import main; raise SystemExit(main())"
ROOT = Path(__file__).resolve().parents[2]  # the folder holding this codegen/
VALUES = {"target": "--target", "baud": "--baud", "hold": "--hold", "override": "--override"}
SWITCHES = {"strict": "--strict", "stream": "--stream"}
ONE_JOB = {"trace": "--trace", "vcd": "--vcd", "report": "--report"}  # a file per run: one job file only
# main.py's refusals of an image too big for its chip's flash (AVR, and the 8051's code memory)
TOO_BIG = re.compile(r"does not fit in (flash|code memory)")


def add_options(verify: argparse.ArgumentParser) -> None:
    group = verify.add_argument_group(
        "several jobs", "verify JOB.yaml... | DIR: each job in a process of its own, N at a time, then one table. "
        "A folder means every *.yaml under it (recursively, sorted; one that does not load is a bad-input case). "
        "Every flag applies to every job; --out DIR becomes the jobs' parent folder (DIR/<name>/); --trace, --vcd "
        "and --report take one job file only. A job too big for flash is verified again with --stream (marked "
        "stream* in the table). Exit 2 if any job is bad input, else 1 if any failed, else 0.")
    group.add_argument("--jobs", type=_count, metavar="N",
                       help=f"verify N jobs at once (default: every core, here {os.cpu_count()})")
    group.add_argument("--junit", metavar="FILE.xml", help="write a JUnit XML file, a test case per job")


def _count(text: str) -> int:
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"'{text}' is not a count of jobs (1 or more)")
    return int(text)


def is_batch(args) -> bool:
    return len(args.job) > 1 or args.jobs is not None or args.junit is not None or Path(args.job[0]).is_dir()


def _usage(option: str, message: str) -> JobError:
    return JobError([Diagnostic(SourceRef(option), message)])


def job_files(paths: list[str]) -> list[Path]:
    """The job files the paths name: a folder's *.yaml recursively and sorted; each file once, first place kept."""
    found, seen = [], set()
    for given in paths:
        path = Path(given)
        files = sorted(path.rglob("*.yaml")) if path.is_dir() else [path]
        if not files:
            raise _usage(given, "the folder holds no *.yaml job file")
        for job in files:
            if job.resolve() not in seen:
                seen.add(job.resolve())
                found.append(job)
    return found


def job_keys(job: Path) -> tuple[str, str | None]:
    """The job's `name:` (its output folder's; default the file's stem) and `target:`, for the table and the
    folders; the child judges the file itself."""
    try:
        data = yaml.safe_load(job.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        data = None
    data = data if isinstance(data, dict) else {}
    name, target = data.get("name"), data.get("target")
    return (str(name) if name not in (None, "") else job.stem), (str(target) if target else None)


def child_flags(args) -> list[str]:
    """The flags every child gets: this run's verify options but --out (per job), --jobs and --junit."""
    flags = []
    for dest, flag in VALUES.items():
        if getattr(args, dest) is not None:
            flags += [flag, str(getattr(args, dest))]
    flags += [flag for dest, flag in SWITCHES.items() if getattr(args, dest)]
    for name, heater, at_s in args.fault:  # parsed by fault_spec: written back in its form
        flags += ["--fault", f"{name}{':' + heater if heater else ''}@{at_s!r}"]
    for r in args.resonance:  # parsed by resonance_option: likewise
        flags += ["--resonance", f"{r.name}={r.freq!r},{r.damping!r}"]
    for dest, flag in ONE_JOB.items():
        if getattr(args, dest):
            flags += [flag, getattr(args, dest)]
    return flags


def _child(argv: list[str], running: set) -> tuple[int, str, str, float]:
    """One child to its end: exit code (negative: the signal that killed it), stdout, stderr, wall seconds."""
    began = time.monotonic()
    with subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                          text=True, errors="replace") as child:
        running.add(child)
        try:
            out, err = child.communicate()
        finally:
            running.discard(child)
    return child.returncode, out, err, time.monotonic() - began


def _json(stdout: str) -> dict | None:
    try:
        result = json.loads(stdout)
    except ValueError:
        return None
    return result if isinstance(result, dict) and "pass" in result else None


def _error_lines(stderr: str) -> list[str]:
    lines = [line.removeprefix("error: ") for line in stderr.splitlines() if re.search(r"(^|: )error: ", line)]
    return lines or [line for line in stderr.splitlines() if line.strip()][-1:]


def _verdict(code: int, stdout: str, stderr: str) -> tuple[str, str, list[str], dict | None]:
    """status (PASS, FAIL, ERROR), what failed, the problems (first one first) and the verify JSON, if any."""
    result = _json(stdout)
    if code in (0, 1) and result is not None:
        passed = code == 0 and result["pass"]
        return ("PASS" if passed else "FAIL"), "verification", list(result.get("problems") or []), result
    if code == 2:
        return "ERROR", "bad input", _error_lines(stderr) or ["bad input (exit 2)"], None
    if code < 0:
        return "FAIL", "crash", [f"the child was killed by {signal.Signals(-code).name}"], None
    if code == 1 and "Traceback (most recent call last)" not in stderr:
        return "FAIL", "build", _error_lines(stderr) or ["the build failed (exit 1)"], None
    what = "crashed" if "Traceback (most recent call last)" in stderr else "ended without a result"
    last = [line for line in stderr.splitlines() if line.strip()][-1:]
    return "FAIL", "crash", [f"the child {what} (exit {code})" + (f": {last[0]}" if last else "")], None


@dataclass(frozen=True)
class Job:
    path: Path
    target: str | None  # --target, or the file's `target:`, for the table until the child tells
    out: Path | None  # --out for the child; None: its default, build/<name>/
    folder: Path  # where it builds: jobs with one folder take turns


def jobs_of(args, several: bool) -> list[Job]:
    jobs = []
    for path in job_files(args.job):
        name, target = job_keys(path)
        out = (Path(args.out) / name if several else Path(args.out)) if args.out else None
        jobs.append(Job(path, args.target or target, out, (out or Path("build") / name).resolve()))
    return jobs


def verify_one(job: Job, flags: list[str], running: set) -> dict:
    """One job's case: verified as a flash image, or streamed where the flash image is too big."""
    command = [sys.executable, "-c", CHILD, str(ROOT), "verify", str(job.path), "--json", "--quiet", *flags]
    code, stdout, stderr, wall = _child(command + (["--out", str(job.out)] if job.out else []), running)
    note, stream = "", "--stream" in flags
    if code == 1 and not stream and _json(stdout) is None and TOO_BIG.search(stderr):
        note = f"too big for flash, verified with --stream ({_error_lines(stderr)[0]})"
        stream = True
        code, stdout, stderr, more = _child(
            command + ["--stream"] + (["--out", str(job.out / "stream")] if job.out else []), running)
        wall += more
    status, kind, problems, result = _verdict(code, stdout, stderr)
    return {"job": str(job.path), "status": status, "kind": kind, "exit_code": code, "wall_s": wall,
            "target": (result or {}).get("target", job.target), "stream": stream, "auto_stream": bool(note),
            "note": note, "problems": problems, "stderr": stderr, "result": result}


def run_all(jobs: list[Job], flags: list[str], workers: int, quiet: bool) -> list[dict]:
    """Every job's case, in the jobs' order; at most `workers` children at once. Jobs that build into the same
    folder (one name) take turns; Ctrl-C ends the running children and leaves the rest unstarted."""
    from concurrent.futures import ThreadPoolExecutor, as_completed  # here: main.py's parser imports this module

    running: set = set()
    locks = {job.folder: threading.Lock() for job in jobs}

    def one(job: Job) -> dict:
        with locks[job.folder]:
            return verify_one(job, flags, running)

    pool = ThreadPoolExecutor(workers)
    futures = [pool.submit(one, job) for job in jobs]
    try:
        for done, future in enumerate(as_completed(futures), 1):
            case = future.result()
            if not quiet:  # a line per finished job on stderr: a long CI log shows it is moving
                print(f"[{done}/{len(jobs)}] {case['status']} {case['job']} ({case['wall_s']:.1f} s)", file=sys.stderr,
                      flush=True)
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        for child in list(running):
            child.terminate()
        raise
    pool.shutdown()
    return [future.result() for future in futures]


def _cell(value) -> str:
    return "-" if value is None else f"{value:.4f}"


def table(cases: list[dict], workers: int, total_s: float) -> str:
    """The summary: a row per job, then the counts; `stream*` marks a job streamed because it was too big."""
    header = ("job", "target", "result", "simulated s", "planned s", "wall s", "first problem")
    rows = [header]
    for case in cases:
        result = case["result"] or {}
        target = (case["target"] or "-") + (" stream" if case["stream"] else "") + ("*" if case["auto_stream"] else "")
        problem = case["problems"][0].splitlines()[0] if case["status"] != "PASS" and case["problems"] else ""
        rows.append((case["job"], target, case["status"], _cell(result.get("duration_s")),
                     _cell(result.get("planned_duration_s")), f"{case['wall_s']:.1f}", problem))
    widths = [max(len(row[i]) for row in rows) for i in range(len(header) - 1)]
    right = (False, False, False, True, True, True)
    lines = ["  ".join([(c.rjust(w) if r else c.ljust(w)) for c, w, r in zip(row, widths, right)] + [row[-1]]).rstrip()
             for row in rows]
    count = {s: sum(c["status"] == s for c in cases) for s in ("PASS", "FAIL", "ERROR")}
    lines.append(f"{len(cases)} jobs: {count['PASS']} passed, {count['FAIL']} failed, {count['ERROR']} bad input; "
                 f"{workers} at a time, {total_s:.1f} s")
    if any(c["auto_stream"] for c in cases):
        lines.append("stream*: too big for flash, verified with --stream (the machine's streaming firmware over "
                     "machine.link)")
    return "\n".join(lines)


def cmd_verify_many(args) -> int:
    several = len(args.job) > 1 or Path(args.job[0]).is_dir()
    for dest, flag in ONE_JOB.items():
        if several and getattr(args, dest):
            raise _usage(flag, "writes one job's file: give one job file, or leave it out with several jobs")
    jobs = jobs_of(args, several)
    workers = min(args.jobs or os.cpu_count() or 1, len(jobs))
    began = time.monotonic()
    cases = run_all(jobs, child_flags(args), workers, args.quiet)
    total_s = time.monotonic() - began
    if args.junit:
        from codegen.report.junit import write_junit  # xml.etree: imported only here
        write_junit(Path(args.junit), cases, total_s)
    if args.json:
        print(json.dumps({"pass": all(c["status"] == "PASS" for c in cases), "jobs": cases}, indent=2))
    else:
        print(table(cases, workers, total_s))
    statuses = {c["status"] for c in cases}
    return 2 if "ERROR" in statuses else 1 if "FAIL" in statuses else 0
