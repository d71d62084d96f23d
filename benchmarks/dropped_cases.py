"""Which cases drop the slip flag while the object slides, per setting, in one run.

`slip_reporting.score` counts an update as *slip dropped* when the truth moves, from its
run's 2nd ridge contact on, and the flag is down (`CaseScore.dropped_from2`). This lists
every case of the chosen kinds whose count differs between the shipped settings and any
`--try`, with the counts side by side, so a rule that holds the flag (e.g.
`TrackerDecoder.RESTART_CONFIRM_TWO`) shows which cases it costs and which it gives back;
then the pooled counts. Why a case drops: `dropped_causes.py`.

`--kinds` (default: every moving kind), `--seeds N` (the full plan's first N, default 1),
`--try NAME=VALUE[,...]` (repeatable) as in `tune_tracker_kinds.py`, `--cases SEED,...`.

Run: `.venv/bin/python benchmarks/dropped_cases.py --kinds stick-slip,rates-drops --try NAME=VALUE`.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import plan_cases


def main(argv: list[str] | None = None) -> int:
    plan_cases.compare_settings(
        __doc__, 1, "slip dropped updates",
        part=lambda score: score.dropped_from2, whole=lambda score: score.moving_from2,
        phrase="moving updates dropped", shown=lambda counts: len(set(counts)) > 1, argv=argv,
    )  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
