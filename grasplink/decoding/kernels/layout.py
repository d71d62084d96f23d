"""Where each field sits in the arrays the kernels and their Python callers share: every
column layout, defined here once (the kernels, the decoders and the numpy reference code
in the tests read these names; none numbers a column by hand).

A layout is a tuple of (name, width) pairs; `columns` turns it into each field's first
column (an int) or, for a field wider than one, its slice, and the total width. numba
freezes module-level ints into the code it compiles and caches the result keyed on the
kernel's own source file: after changing a layout here, clear the kernels' cache
(`grasplink/decoding/kernels/__pycache__`) or touch the kernels, or they keep the old one.
"""

from __future__ import annotations

__all__ = ["columns", "one", "p_at"]


def columns(layout: tuple[tuple[str, int], ...]) -> tuple[dict[str, int | slice], int]:
    """Each field's column (one wide: an int; wider: a slice) and the layout's width."""
    at: dict[str, int | slice] = {}
    start = 0
    for name, width in layout:
        at[name] = start if width == 1 else slice(start, start + width)
        start += width
    return at, start


# ------------------------------------------------------------------ the tracker's bank
IDS = 6  # recent contact ids a track remembers (pulse evidence, merging)
# a track's floats: P (4 x 4 covariance, row-major), X = (s, v, a, d), dip memory m, score,
# timing sigma, stop time (NaN: slipping), time of its last contact, and the speed it had
# before it last restarted (0: never restarted; `kernels.posterior.agrees`)
BANK_FLOATS = (
    ("P", 16), ("s", 1), ("v", 1), ("a", 1), ("d", 1), ("m", 1), ("score", 1), ("sig", 1),
    ("stop", 1), ("t", 1), ("before", 1),
)  # fmt: skip
# ... and ints: direction, first contact id, the last IDS contact ids, motion model,
# contacts assigned, ridge of the last contact, contacts since it last (re)started
BANK_INTS = (
    ("dirn", 1), ("first", 1), ("ids", IDS), ("model", 1), ("n", 1), ("ridge", 1), ("run", 1),
)  # fmt: skip
F_COLS, F_WIDTH = columns(BANK_FLOATS)
I_COLS, I_WIDTH = columns(BANK_INTS)


def one(cols: dict[str, int | slice], name: str) -> int:
    """The column of a one-wide field (numba takes it as a constant)."""
    at = cols[name]
    assert isinstance(at, int), name
    return at


F_S, F_V, F_A, F_D, F_M, F_SCORE, F_SIG, F_STOP, F_T, F_BEFORE = (
    one(F_COLS, name) for name in ("s", "v", "a", "d", "m", "score", "sig", "stop", "t", "before")
)
I_DIRN, I_FIRST, I_MODEL, I_N, I_RIDGE, I_RUN = (
    one(I_COLS, name) for name in ("dirn", "first", "model", "n", "ridge", "run")
)
_IDS_AT = I_COLS["ids"]
assert isinstance(_IDS_AT, slice)
I_IDS, I_LAST = _IDS_AT.start, _IDS_AT.stop - 1  # the first and the last contact id
STEADY, CHANGING = 0, 1  # the motion models (the `model` column)


def p_at(row: int, col: int) -> int:
    """The column of covariance entry P[row, col] (P row-major in the first 16)."""
    return 4 * row + col


# covariance entries the kernels write
P00, P01, P10, P11, P12, P13 = (
    p_at(0, 0),
    p_at(0, 1),
    p_at(1, 0),
    p_at(1, 1),
    p_at(1, 2),
    p_at(1, 3),
)
P21, P22, P31, P33 = p_at(2, 1), p_at(2, 2), p_at(3, 1), p_at(3, 3)

# ------------------------------------------------------------------ the contact detector
# a hinge channel's int state (`detector.hinges`, a row per channel): width, slopes held,
# next centre, |hinge| entries of the block, next centre to test, centre of row 0, rows
# held, centres waiting for their block's noise (those after the last row, in the
# bank's `wait`), and the block whose noise is `noise[channel]` (-1: none known, or
# blocks waiting for one)
CHANNEL_COLUMNS = (
    "width", "held", "next_n", "abs_n", "next_test", "z_start", "size", "wait_n",
    "noise_block",
)  # fmt: skip
(
    CH_W, CH_HELD, CH_NEXT_N, CH_ABS_N, CH_NEXT_TEST, CH_Z_START, CH_SIZE, CH_WAIT_N,
    CH_NOISE_BLOCK,
) = range(len(CHANNEL_COLUMNS))  # fmt: skip
# a waiting centre's rows (`wait[channel]`): its hinge (N/sample) and the slope after it
WAIT_ROWS = ("hinge", "after")
WAIT_HINGE, WAIT_AFTER = range(len(WAIT_ROWS))
# a hinge channel's rows by centre: z (hinge in noise units), hinge (N/sample), the slope
# after it, and the sample that told the noise
CHANNEL_ROWS = ("z", "hinge", "after", "ready")
ROW_Z, ROW_HINGE, ROW_AFTER, ROW_READY = range(len(CHANNEL_ROWS))
# a step-probe scale's int state (`detector.step_probe`): width, differences held, centre
# of the first, next centre to test
SCALE_COLUMNS = ("width", "size", "start", "next")
S_W, S_SIZE, S_START, S_NEXT = range(len(SCALE_COLUMNS))
# a pulse watch's level to the hold (`detector.watch.Watch.held`): level - base, with an
# earlier tail's fall out, and with the rising trend out too
WATCH_ROWS = ("plain", "levels", "detrended")
HELD_PLAIN, HELD_LEVELS, HELD_DETRENDED = range(len(WATCH_ROWS))
