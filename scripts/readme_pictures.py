"""The README's pictures (docs/pictures/): each kind of user's first report page (`verify --report` or
`plan --report`), and from it the plots the README shows. Run from the repository's root after scripts/setup.sh:

    .venv/bin/python scripts/readme_pictures.py

Each page is written to build/readme/<kind>.html as well, whole, to look at in a browser."""

from __future__ import annotations

import base64
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAGES = Path("build") / "readme"
PICTURES = Path("docs") / "pictures"
# kind: the command after `printer-codegen`, and the plots of its page the README shows
KINDS = {
    "plotter": (["verify", "examples/gcode/plotter-svg.yaml"], ("path",)),
    "laser": (["verify", "examples/laser/power.yaml"], ("path",)),
    "printer": (["verify", "examples/printers/benchy-mini.yaml", "--stream"], ("path", "ring-fill")),
    "delta": (["verify", "examples/kossel-mini.yaml"], ("path", "motion")),
}
IMAGE = re.compile(r"<img data-plot='([a-z-]+)'[^>]*src='data:image/png;base64,([A-Za-z0-9+/=]+)'>")


def main() -> int:
    PAGES.mkdir(parents=True, exist_ok=True)
    PICTURES.mkdir(parents=True, exist_ok=True)
    for kind, (command, plots) in KINDS.items():
        page = PAGES / f"{kind}.html"
        cmd = [str(ROOT / ".venv" / "bin" / "printer-codegen"), *command, "--report", str(page), "--quiet"]
        print("$", " ".join(["printer-codegen", *command, "--report", str(page)]), flush=True)
        done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        print(done.stdout.splitlines()[0] if done.stdout else done.stderr.strip())
        if done.returncode != 0:
            return done.returncode
        images = dict(IMAGE.findall((ROOT / page).read_text(encoding="utf-8")))
        for plot in plots:
            out = ROOT / PICTURES / f"{kind}-{plot}.png"
            out.write_bytes(base64.b64decode(images[plot]))
            print(f"  {out.relative_to(ROOT)}: {out.stat().st_size} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
