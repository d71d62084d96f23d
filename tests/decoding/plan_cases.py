"""Full-plan cases of the slip-reporting benchmark, decoded as its page decodes them.

The decoding tests pin each tracker rule on a case of `slip_reporting.FULL` named by kind,
seed (and variant, where a seed names several); this finds it and feeds it to a tracker
with a tuning, 3 samples at a time (`slip_reporting.CHUNK`), in one place.
"""

from __future__ import annotations

from dataclasses import replace

from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr


def plan_case(kind: str, seed: int, variant: str | None = None) -> sr.Case:
    """The full plan's case of this kind and seed (and variant): a tuned seed (index 0-2)
    or a held-out one (3 and up, `benchmarks/held_out_seeds.py`); the seed's tens digit
    is its index."""
    plan = replace(sr.FULL, seeds=1, first_seed=seed // 10 % 10)
    return next(
        c
        for c in sr.cases(plan)
        if c.kind == kind and c.seed == seed and (variant is None or c.variant == variant)
    )


def decode_case(
    kind: str, seed: int, tuning: dict, variant: str | None = None
) -> tuple[ns.Recorded, TrackerDecoder, list]:
    """(the recording, the tracker after it, its estimates) of that case under `tuning`."""
    rec = plan_case(kind, seed, variant).make()
    decoder = TrackerDecoder(rec.truth.layout_mm, rec.fs_hz, tuning=tuning)
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    return rec, decoder, estimates


def score_case(kind: str, seed: int, tuning: dict, variant: str | None = None) -> sr.CaseScore:
    """That case decoded under `tuning` (`decode_case`), scored as the page scores it."""
    rec, _, estimates = decode_case(kind, seed, tuning, variant)
    return sr.score(estimates, rec.truth)
