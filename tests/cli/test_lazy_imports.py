"""`plan`, the command users run most, starts without what only verify, build --stream, stream, tune and a batch
verify need: the simulators' harnesses, jinja2 (the firmware's templates) and the modules that pull them in (issue
29: `import codegen.cli.main` took 0.6 s, half of it theirs). main.py and the verbs' modules it imports for the
parser import them in the functions that use them."""

import json
import subprocess
import sys

from tests.helpers import ROOT

# each a module plan does not need, and its submodules
NOT_FOR_PLAN = ("codegen.cli.stream", "codegen.verify.bounded", "codegen.verify.compare", "codegen.verify.heaters",
                "codegen.verify.hold", "codegen.verify.waveform", "codegen.sim", "codegen.firmware.render",
                "codegen.firmware.avr.image", "codegen.firmware.avr.tune", "codegen.pipeline.streaming",
                "codegen.report.junit", "jinja2")
# in a process of its own (this one has imported everything): the parser built, the plan run, the modules loaded
CHILD = """
import contextlib, io, json, sys
sys.path.insert(0, sys.argv[1])
from codegen.cli.main import main, parser
parser().format_help()
with contextlib.redirect_stdout(io.StringIO()):
    code = main(["plan", sys.argv[2], "--quiet"])
print(json.dumps({"code": code, "modules": sorted(sys.modules)}))
"""


def test_plan_imports_neither_the_simulators_nor_the_firmware_templates():
    done = subprocess.run([sys.executable, "-c", CHILD, str(ROOT), str(ROOT / "examples" / "line.yaml")],
                          capture_output=True, text=True, timeout=60, check=True)
    child = json.loads(done.stdout)
    assert child["code"] == 0
    assert [name for name in child["modules"] if name.startswith(tuple(f"{m}." for m in NOT_FOR_PLAN))
            or name in NOT_FOR_PLAN] == []
