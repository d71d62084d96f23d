"""Run a script in another checkout's own interpreter (the base of a before/after check).

Each tree's `grasplink` has the same module names, so a comparison runs each tree in a
child interpreter whose path starts with that tree; the script is Python source, its
arguments reach it as `sys.argv[1:]`, and it runs in a scratch folder.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any


def run_in_tree(tree: Path, script: str, *args: str, what: str) -> str:
    """`script`'s stdout, run with `tree`'s grasplink; exits naming `what` if it fails."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "script.py"
        path.write_text(script)
        prelude = f"import sys; sys.path.insert(0, {str(tree)!r}); "
        out = subprocess.run(
            [sys.executable, "-c", prelude + f"exec(open({str(path)!r}).read())", *args],
            check=False, cwd=tmp, capture_output=True, text=True,
        )  # fmt: skip
    if out.returncode:
        raise SystemExit(f"{what} failed in {tree}:\n{out.stderr}")
    return out.stdout


def last_json(stdout: str) -> Any:
    """The JSON a script printed last (what came before it is its log)."""
    return json.loads(stdout.strip().splitlines()[-1])
