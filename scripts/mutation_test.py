"""Mutation test of `verify`: small deliberate bugs (scripts/mutants.py), each applied to a copy of the repository
and run through `python -m codegen verify JOB --json --quiet` in that copy. A mutant is caught when verify exits 1
(or 2); a caught mutant's message names the fault when its first problem holds one of the mutant's words.

    python scripts/mutation_test.py [--jobs 2] [--only WORD ...] [--timeout 900]

Each job is first verified unchanged (a mutant of a job that fails already proves nothing). Prints a table
(mutant, caught, named, seconds, first problem) and the score; exit 0 whatever the score. The real tree is only
read: every mutant works in a temporary copy of codegen/, templates/, targets/, examples/ and tests/data/. Not part
of the test suite (minutes of simulation); tests/test_mutants_apply.py checks that the mutants still apply.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mutants import MUTANTS, Mutant  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
COPIED = ("codegen", "templates", "targets", "examples", "tests/data")
SKIPPED = shutil.ignore_patterns("__pycache__", "*.pyc", "build")
PROBLEM_CHARS = 150  # of the first problem in the table


@dataclass(frozen=True)
class Outcome:
    name: str
    exit_code: int
    first_problem: str
    seconds: float
    named: bool

    @property
    def caught(self) -> bool:
        return self.exit_code in (1, 2)


def copy_repository(dest: Path) -> None:
    """The parts of the repository that verify reads, into `dest` (which it creates)."""
    for part in COPIED:
        shutil.copytree(ROOT / part, dest / part, ignore=SKIPPED)


def apply(mutant: Mutant, root: Path) -> None:
    """The mutant's edit in the tree at `root`; ValueError unless its old text is there exactly once."""
    path = root / mutant.path
    text = path.read_text(encoding="utf-8")
    found = text.count(mutant.old)
    if found != 1:
        raise ValueError(f"{mutant.name}: its old text is in {mutant.path} {found} times, not once")
    path.write_text(text.replace(mutant.old, mutant.new), encoding="utf-8")


def first_problem(done: subprocess.CompletedProcess) -> str:
    """verify's first problem: from its JSON, else its error line (exit 2, a build error or a traceback)."""
    try:
        problems = json.loads(done.stdout).get("problems") or []
        if problems:
            return str(problems[0])
    except ValueError:
        pass
    lines = [line.strip() for line in done.stderr.splitlines() if line.strip()]
    at = next((k for k, line in enumerate(lines) if "error" in line.lower()), len(lines) - 1)
    if at < 0:
        return "(no message)"
    return " ".join(lines[at:at + 2]) if lines[at].endswith(":") else lines[at]  # a build error's reason follows


def verify(mutant: Mutant | None, job: str, flags: tuple[str, ...], timeout: float) -> tuple[int, str, float]:
    """(exit code, first problem, seconds) of verify on `job` in a copy of the repository with `mutant` applied
    (None: unchanged); a run past `timeout` seconds counts as exit 124."""
    with tempfile.TemporaryDirectory(prefix="mutant-") as tmp:
        root = Path(tmp) / "repo"
        copy_repository(root)
        if mutant is not None:
            apply(mutant, root)
        env = {**os.environ, "PYTHONPATH": str(root)}
        cmd = [sys.executable, "-m", "codegen", "verify", job, "--json", "--quiet", "--out", str(Path(tmp) / "out"),
               *flags]
        start = time.perf_counter()
        try:
            done = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return 124, f"verify ran past {timeout:.0f} s", time.perf_counter() - start
        return done.returncode, first_problem(done), time.perf_counter() - start


def run_mutant(mutant: Mutant, timeout: float) -> Outcome:
    code, problem, seconds = verify(mutant, mutant.job, mutant.flags, timeout)
    named = code in (1, 2) and any(word.lower() in problem.lower() for word in mutant.names)
    return Outcome(mutant.name, code, problem, seconds, named)


def baseline(mutants: list[Mutant], jobs: int, timeout: float) -> dict[tuple, str]:
    """Each (job, flags) the mutants use, verified unchanged: the ones that do not pass, with their problem."""
    runs = sorted({(m.job, m.flags) for m in mutants})
    with ThreadPoolExecutor(jobs) as pool:
        results = list(pool.map(lambda run: verify(None, *run, timeout), runs))
    return {run: f"exit {code}: {problem}" for run, (code, problem, _) in zip(runs, results) if code != 0}


def table(outcomes: list[Outcome]) -> str:
    rows = [f"{'mutant':48} {'caught':6} {'named':5} {'s':>6}  first problem"]
    for o in outcomes:
        caught = f"yes ({o.exit_code})" if o.caught else ("NO" if o.exit_code == 0 else f"?{o.exit_code}")
        rows.append(f"{o.name[:48]:48} {caught:6} {'yes' if o.named else '-':5} {o.seconds:6.1f}  "
                    f"{o.first_problem[:PROBLEM_CHARS] if o.caught else ''}")
    return "\n".join(rows)


def score(outcomes: list[Outcome]) -> str:
    caught = [o for o in outcomes if o.caught]
    named = sum(o.named for o in caught)
    total = len(outcomes)
    return (f"caught {len(caught)} of {total} ({100 * len(caught) / max(total, 1):.0f} %); "
            f"named {named} of {len(caught)} caught")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--jobs", type=int, default=2, help="mutants run at once (default 2)")
    parser.add_argument("--only", nargs="*", default=[], help="only the mutants whose name holds one of these words")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds one verify may take (default 900)")
    args = parser.parse_args(argv)
    mutants = [m for m in MUTANTS if not args.only or any(w.lower() in m.name.lower() for w in args.only)]
    failing = baseline(mutants, args.jobs, args.timeout)
    for (job, flags), problem in failing.items():
        print(f"baseline: {job} {' '.join(flags)} does not pass unchanged ({problem}); its mutants are left out")
    mutants = [m for m in mutants if (m.job, m.flags) not in failing]
    with ThreadPoolExecutor(args.jobs) as pool:
        outcomes = list(pool.map(lambda m: run_mutant(m, args.timeout), mutants))
    print(table(outcomes))
    firmware = [o for o, m in zip(outcomes, mutants) if m.path.startswith("templates/")]
    host = [o for o, m in zip(outcomes, mutants) if not m.path.startswith("templates/")]
    print(f"firmware templates: {score(firmware)}\nhost code: {score(host)}\nall: {score(outcomes)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
