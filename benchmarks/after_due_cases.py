"""Which cases give a speed after a stop's report was due, per setting, in one run.

`slip_reporting.score` counts, per stop, the updates later than its observable moment
plus `CLEAR_WITHIN_S` (the stop's report due) and before its end, and those of them
carrying a speed above 0 (*speed after due*: target 0). This lists every case of the
chosen kinds where any setting gives such a speed: the count under the shipped settings
and under each `--try`, so a change aimed at those cases shows what it clears and what it
brings, case by case, beside the pooled share.

`--kinds` (default: every moving kind), `--seeds N` (the full plan's first N, default 3),
`--try NAME=VALUE[,...]` (repeatable) as in `tune_tracker_kinds.py`, `--cases SEED,...`
only those cases (a setting that only withholds speeds, `TrackerDecoder.OVERDUE_SPEED`,
brings none to a case the shipped settings keep clear, so the cases these list say all
of it; the pooled share is then of those cases' updates).

Run: `.venv/bin/python benchmarks/after_due_cases.py --seeds 3 --try NAME=VALUE`.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import plan_cases


def main(argv: list[str] | None = None) -> int:
    plan_cases.compare_settings(
        __doc__, 3, "after-due speed updates",
        part=lambda score: score.after_observable_speed,
        whole=lambda score: score.after_observable,
        phrase="updates after due carry a speed", shown=any, argv=argv,
    )  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
