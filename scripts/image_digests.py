"""Prints a SHA-256 for every file that `build` writes for each example, on each target and as a stream.

Run it before and after a change that must not change behaviour (a refactoring) and diff the two outputs:
    python scripts/image_digests.py > before.txt   ...   python scripts/image_digests.py > after.txt
A build that fails is listed with its exit code, so a refusal that changes shows up too.
"""

import argparse
import hashlib
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# report.json holds wall-clock figures of the build itself; everything else must be byte-identical.
VOLATILE = {"report.json"}


def variants(job: Path) -> list[list[str]]:
    """The builds a user can ask of this example: each target its board allows, and the streaming firmware."""
    text = job.read_text()
    if "printers/" in job.as_posix():
        return [["--stream"]]
    if "target: mcs51" in text:
        return [["--target", "mcs51"], ["--target", "mcs51", "--stream"]]
    return [["--target", "avr"], ["--target", "avr", "--stream"], ["--target", "mcs51"]]


def build(job: Path, flags: list[str], scratch: Path) -> list[str]:
    out = scratch / (job.relative_to(ROOT).as_posix().replace("/", "_") + "_".join(flags).replace("-", ""))
    # `python -m codegen` in the checkout: the sources and templates of this tree, not an installed copy.
    cli = [sys.executable, "-m", "codegen"]
    done = subprocess.run([*cli, "build", str(job), *flags, "--out", str(out)], cwd=ROOT, capture_output=True,
                          text=True)
    label = f"{job.relative_to(ROOT)} {' '.join(flags)}"
    lines = [f"{label}: exit {done.returncode}"]
    if done.returncode:
        stderr = done.stderr.replace(str(scratch), "SCRATCH").replace(str(ROOT), "ROOT")
        lines += [f"{label}: {line}" for line in stderr.splitlines()]
    if out.is_dir():
        for path in sorted(p for p in out.rglob("*") if p.is_file() and p.name not in VOLATILE):
            digest = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
            lines.append(f"{label}: {path.relative_to(out)} {digest}")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    jobs = sorted((ROOT / "examples").rglob("*.yaml"))
    with tempfile.TemporaryDirectory() as scratch, ThreadPoolExecutor(args.jobs) as pool:
        tasks = [pool.submit(build, job, flags, Path(scratch)) for job in jobs for flags in variants(job)]
        for task in tasks:
            print("\n".join(task.result()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
