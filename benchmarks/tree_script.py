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
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


def _command(tree: Path, script: str, folder: str, args: tuple[str, ...]) -> list[str]:
    """The child's command line: `script` saved in `folder`, run with `tree` first on the
    path and `args` as its `sys.argv[1:]`."""
    path = Path(folder) / "script.py"
    path.write_text(script)
    prelude = f"import sys; sys.path.insert(0, {str(tree)!r}); "
    return [sys.executable, "-c", prelude + f"exec(open({str(path)!r}).read())", *args]


def run_in_tree(tree: Path, script: str, *args: str, what: str) -> str:
    """`script`'s stdout, run with `tree`'s grasplink; exits naming `what` if it fails."""
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run(
            _command(tree, script, tmp, args), check=False, cwd=tmp, capture_output=True,
            text=True,
        )  # fmt: skip
    if out.returncode:
        raise SystemExit(f"{what} failed in {tree}:\n{out.stderr}")
    return out.stdout


@contextmanager
def served_in_tree(tree: Path, script: str, *args: str) -> Iterator[subprocess.Popen[str]]:
    """`script` running with `tree`'s grasplink as a child that stays up (its stdin and
    stdout are pipes, text lines): a timing asks it round after round, so each round
    costs neither an interpreter's start nor its imports and compiled kernels."""
    with tempfile.TemporaryDirectory() as tmp:
        child = subprocess.Popen(
            _command(tree, script, tmp, args), cwd=tmp, stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            yield child
        finally:
            assert child.stdin is not None
            child.stdin.close()
            child.wait()


def ask(child: subprocess.Popen[str], line: str | None, *, what: str) -> str:
    """One line sent to a served script (None: nothing sent, its next line read), its one
    line of answer; exits naming `what` if the child ended instead."""
    assert child.stdin is not None and child.stdout is not None
    if line is not None:
        child.stdin.write(line + "\n")
        child.stdin.flush()
    answer = child.stdout.readline()
    if not answer:
        raise SystemExit(f"{what}: the child ended (exit code {child.wait()})")
    return answer.strip()


def last_json(stdout: str) -> Any:
    """The JSON a script printed last (what came before it is its log)."""
    return json.loads(stdout.strip().splitlines()[-1])
