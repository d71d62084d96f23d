"""wearer.virtual: perception, reaction times, confusion, policy, scatter, chunking, hard cases."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from grasplink.controllers import simulation
from grasplink.core.params import SceneError
from grasplink.simulators.core import REGISTRY
from grasplink.simulators.effects.actuators import BeltMotor
from grasplink.simulators.effects.wearer import (
    FORCE_CONFUSION,
    FORCE_LEVELS_RAD_S,
    SLIP_CONFUSION,
    SLIP_LEVELS_MM_S,
    WearerVirtual,
)
from grasplink.simulators.harness import context, make, run, sample_times_us
from grasplink.simulators.recording import Recorder
from grasplink.simulators.scene import load_scene

TAP, SURFACE = "belt.tap_hz", "belt.surface_mm_s"
LEVEL, PERCEIVED = "wearer.level", "wearer.perceived_level"
IDENTITY = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]
# A wearer whose only randomness is the reaction time: every answer and contraction is exact.
EXACT = {"force_confusion": IDENTITY, "slip_confusion": IDENTITY, "scatter": [1.0]}


def tap_hz(rad_s: float, nubs: int = 6) -> float:
    return nubs * rad_s / (2 * math.pi)


def force(level: int) -> tuple[str, float]:
    return TAP, tap_hz(FORCE_LEVELS_RAD_S[level - 1])


def slip(level: int) -> tuple[str, float]:
    return SURFACE, SLIP_LEVELS_MM_S[level - 1]


def display(times_us: np.ndarray, segments) -> dict[str, np.ndarray]:
    """Belt signals from (start_s, end_s, (signal, value)) segments; nothing elsewhere."""
    t = times_us / 1e6
    out = {TAP: np.zeros(len(t)), SURFACE: np.zeros(len(t))}
    for start_s, end_s, (name, value) in segments:
        out[name][(t >= start_s) & (t < end_s)] = value
    return out


def wearer(seed: int = 1, rate_hz: int = 1000, **params) -> WearerVirtual:
    return make(WearerVirtual, context(seed=seed, rate_hz=rate_hz), **params)


def drive(times_us, inputs, seed=1, rate_hz=1000, chunk=None, **params):
    effect = wearer(seed, rate_hz, **params)
    return run([effect], times_us, inputs, chunk=chunk), effect


def steps(times_us: np.ndarray, values: np.ndarray) -> list[tuple[float, float]]:
    """(t_s, new value) at every change."""
    at = np.flatnonzero(np.diff(values)) + 1
    return [(times_us[i] / 1e6, float(values[i])) for i in at]


def rich_display(times_us: np.ndarray) -> dict[str, np.ndarray]:
    """Ramps, levels, a between-level display, flicker, NaN and negative values."""
    t = times_us / 1e6
    inputs = display(
        times_us,
        [
            (0.5, 3.0, force(2)),
            (3.0, 5.0, (SURFACE, 122.5)),
            (5.0, 6.5, slip(4)),
            (9.0, 14.0, force(4)),
        ],
    )
    ramp = (t >= 14.0) & (t < 15.0)
    inputs[TAP][ramp] = tap_hz(8.0) * (t[ramp] - 14.0)
    flicker = (t >= 15.0) & (t < 18.0)
    inputs[SURFACE][flicker] = np.where(np.floor(t[flicker] / 0.25) % 2 == 0, 100.0, 0.0)
    inputs[TAP][(t >= 18.0) & (t < 18.03)] = np.nan
    inputs[SURFACE][(t >= 18.5) & (t < 18.6)] = -5.0
    return inputs


# ---------------------------------------------------------------- registration and chunking


def test_the_virtual_wearer_is_a_physics_effect_from_belt_display_to_level():
    assert REGISTRY["wearer.virtual"] is WearerVirtual
    assert WearerVirtual.domain == "physics"
    assert set(WearerVirtual.inputs) == {TAP, SURFACE}
    assert WearerVirtual.outputs[0] == LEVEL
    assert WearerVirtual.summary


@pytest.mark.parametrize(
    "params",
    [{}, {"max_pending_cues": 2, "slip_repeat_s": 0.5, "idle_relax_s": 1.0}, {"min_cue_s": 0.0}],
    ids=["defaults", "tight-queue-fast-timers", "no-debounce"],
)
def test_chunked_stepping_equals_one_shot_exactly(params):
    times = sample_times_us(1000, 24.0)
    inputs = rich_display(times)
    whole, effect = drive(times, inputs, seed=7, **params)
    assert effect.counts["perceptions"] >= 8
    for chunk in (1, 7, 333, 1000):
        parts, chunked = drive(times, inputs, seed=7, chunk=chunk, **params)
        for name in (LEVEL, PERCEIVED):
            assert np.array_equal(parts[name], whole[name]), (name, chunk)
        assert chunked.counts == effect.counts


def test_behind_a_belt_motor_chunking_changes_nothing():
    times = sample_times_us(1000, 12.0)
    t = times / 1e6
    command = np.select([t < 1, t < 4, t < 7], [0.0, 6500.0, -5300.0], 8000.0)

    def chain(chunk=None):
        effects = [make(BeltMotor, context()), wearer(seed=3)]
        return run(effects, times, {"belt.command_mrad_s": command}, chunk=chunk)

    whole = chain()
    assert steps(times, whole[LEVEL]), "the slip belt at -5.3 rad/s must make the wearer contract"
    for chunk in (1, 50, 999):
        assert np.array_equal(chain(chunk)[LEVEL], whole[LEVEL])


def test_the_same_seed_gives_the_same_wearer_and_another_seed_another():
    times = sample_times_us(1000, 24.0)
    inputs = rich_display(times)
    first, _ = drive(times, inputs, seed=11)
    again, _ = drive(times, inputs, seed=11)
    other, _ = drive(times, inputs, seed=12)
    assert np.array_equal(first[LEVEL], again[LEVEL])
    assert np.array_equal(first[PERCEIVED], again[PERCEIVED])
    assert not np.array_equal(first[LEVEL], other[LEVEL])


# ---------------------------------------------------------------- reaction times


def alternating(times_us, period_s, first, second, count):
    """`first` and `second` displays, alternately, each for period_s."""
    return display(
        times_us,
        [(i * period_s, (i + 1) * period_s, (first, second)[i % 2]) for i in range(count)],
    )


@pytest.mark.parametrize("bounds", [(1.51, 1.75), (2.0, 2.5)])
def test_slip_reaction_times_lie_within_the_bounds_and_fill_them(bounds):
    """Slip and a high force alternate: each slip cue's e1 lands one reaction time after it."""
    period_s, count = 3.0, 160
    times = sample_times_us(1000, period_s * count)
    inputs = alternating(times, period_s, slip(1), force(4), count)
    params = EXACT | {"slip_repeat_s": 0, "relax_after_s": 0.1, "slip_reaction_s": list(bounds)}
    out, _ = drive(times, inputs, **params)
    landed = steps(times, out[LEVEL])
    assert [level for _, level in landed] == [1.0, 0.0] * (count // 2)  # the force relaxes it
    reactions = np.array([t - round(t / period_s - 0.5) * period_s for t, _ in landed[::2]])
    low, high = bounds
    assert np.all(reactions >= low) and np.all(reactions <= high + 0.001)  # landing on a sample
    # Uniform on [low, high]: the mean within 4 standard errors of the middle, the extremes used.
    span, cues = high - low, len(reactions)
    assert abs(reactions.mean() - (low + high) / 2) < 4 * span / math.sqrt(12 * cues)
    assert reactions.min() < low + 0.1 * span and reactions.max() > high - 0.1 * span


def test_force_cues_are_identified_after_the_chapter_8_time():
    """Force cues change what the wearer perceives, motor_delay_s before any contraction."""
    period_s, count = 2.0, 60
    times = sample_times_us(1000, period_s * count)
    inputs = alternating(times, period_s, force(1), force(4), count)
    out, _ = drive(times, inputs, **EXACT, motor_delay_s=0.05)
    identified = steps(times, out[PERCEIVED])
    assert [level for _, level in identified] == [1.0, 4.0] * (count // 2)
    reactions = np.array([t - round(t / period_s - 0.5) * period_s + 0.05 for t, _ in identified])
    assert np.all(reactions >= 0.9) and np.all(reactions <= 1.0 + 0.001)
    assert reactions.max() - reactions.min() > 0.08


def test_the_end_of_a_slip_display_is_noticed_after_a_slip_reaction_time():
    times = sample_times_us(1000, 6.0)
    out, _ = drive(times, display(times, [(0.0, 2.0, slip(2))]), **EXACT)
    (_, first), (end_s, last) = steps(times, out[PERCEIVED])
    assert (first, last) == (-2.0, 0.0)
    assert 2.0 + 1.51 - 0.1 <= end_s <= 2.0 + 1.75 - 0.1 + 0.001


def test_a_contraction_lands_motor_delay_after_the_decision():
    times = sample_times_us(1000, 5.0)
    inputs = display(times, [(0.5, 5.0, slip(3))])
    out, _ = drive(times, inputs, **EXACT, motor_delay_s=0.3, slip_repeat_s=0)
    [(decided_s, perceived)] = steps(times, out[PERCEIVED])
    [(landed_s, level)] = steps(times, out[LEVEL])
    assert (perceived, level) == (-3.0, 3.0)
    assert landed_s - decided_s == pytest.approx(0.3, abs=1e-9)


# ---------------------------------------------------------------- identification


def identification_counts(belt: str, shown_mm_s_or_hz, trials: int, seed: int) -> np.ndarray:
    """Show each display value (random order) 0.5 s, then nothing 0.5 s; count the answers."""
    rate_hz, trial_s = 100, 1.0
    shown = np.random.default_rng(seed).integers(0, len(shown_mm_s_or_hz), trials)
    times = sample_times_us(rate_hz, trials * trial_s + 3.0)
    name = SURFACE if belt == "slip" else TAP
    inputs = display(
        times,
        [
            (i * trial_s, i * trial_s + 0.5, (name, shown_mm_s_or_hz[k]))
            for i, k in enumerate(shown)
        ],
    )
    out, effect = drive(times, inputs, seed=seed, rate_hz=rate_hz, max_pending_cues=16)
    assert effect.counts["dropped_cues"] == 0
    # Slip answers come 1.41-1.65 s after the onset, force answers 0.8-0.9 s: read them before
    # the answer to the following "nothing" (0.5 s later) replaces them.
    read_s = 1.78 if belt == "slip" else 1.1
    at = np.searchsorted(times, (np.arange(trials) * trial_s + read_s) * 1e6)
    answered = np.abs(out[PERCEIVED][at]).astype(int)
    counts = np.zeros((len(shown_mm_s_or_hz), 4), dtype=int)
    np.add.at(counts, (shown, answered - 1), 1)
    return counts


def assert_rows_match(counts: np.ndarray, expected: np.ndarray) -> None:
    """Each cell is binomial: within 4.5 standard deviations of the sample size (+1/n rounding)."""
    for row_counts, row_p in zip(counts, expected, strict=True):
        n = row_counts.sum()
        assert n > 300
        share = row_counts / n
        tolerance = 4.5 * np.sqrt(row_p * (1 - row_p) / n) + 1 / n
        assert np.all(np.abs(share - row_p) <= tolerance), (share, row_p)
        assert np.all(row_counts[row_p == 0] == 0)


@pytest.mark.parametrize(
    ("belt", "values", "matrix"),
    [
        ("slip", SLIP_LEVELS_MM_S, SLIP_CONFUSION),
        ("force", [tap_hz(w) for w in FORCE_LEVELS_RAD_S], FORCE_CONFUSION),
    ],
)
def test_identification_over_many_cues_follows_the_confusion_matrix(belt, values, matrix):
    counts = identification_counts(belt, values, trials=2400, seed=5)
    assert_rows_match(counts, np.array(matrix))


def test_a_display_between_two_levels_blends_their_rows():
    halfway_mm_s = (SLIP_LEVELS_MM_S[1] + SLIP_LEVELS_MM_S[2]) / 2
    counts = identification_counts("slip", [halfway_mm_s], trials=1200, seed=9)
    expected = 0.5 * np.array(SLIP_CONFUSION[1]) + 0.5 * np.array(SLIP_CONFUSION[2])
    assert_rows_match(counts, expected[None, :])


def test_displays_beyond_the_table_are_read_as_its_end_levels():
    times = sample_times_us(1000, 8.0)
    inputs = display(times, [(0.0, 3.0, (SURFACE, 40.0)), (3.0, 8.0, (SURFACE, 250.0))])
    out, _ = drive(times, inputs, **EXACT, slip_step=0, slip_repeat_s=0)
    assert [v for _, v in steps(times, out[PERCEIVED])] == [-1.0, -4.0]


def test_the_default_matrices_keep_the_chapter_8_findings():
    for matrix in (FORCE_CONFUSION, SLIP_CONFUSION):
        m = np.array(matrix)
        assert np.allclose(m.sum(axis=1), 1.0) and np.all(m >= 0)
        assert np.all(np.argmax(m, axis=1) == np.arange(4))  # the shown level is the usual answer
        far = np.abs(np.subtract.outer(np.arange(4), np.arange(4))) >= 2
        assert np.all((m * far).sum(axis=1) < 0.05)  # two or more levels apart: > 95 % told apart


# ---------------------------------------------------------------- decision policy


def test_a_felt_slip_makes_the_wearer_contract_more_for_a_faster_slip():
    times = sample_times_us(1000, 4.0)
    landed = {}
    for level in (1, 2, 3, 4):
        out, _ = drive(times, display(times, [(0.2, 4.0, slip(level))]), **EXACT, slip_repeat_s=0)
        landed[level] = steps(times, out[LEVEL])
    assert {k: [v for _, v in s] for k, s in landed.items()} == {1: [1], 2: [2], 3: [3], 4: [4]}


def test_a_slip_felt_while_contracting_asks_for_one_level_more():
    """At e3 a slow slip (level 1) still means the grip is too weak: e4, not e1."""
    times = sample_times_us(1000, 10.0)
    inputs = display(times, [(0.0, 2.0, slip(3)), (4.0, 10.0, slip(1))])
    out, _ = drive(times, inputs, **EXACT, slip_repeat_s=0)
    assert [v for _, v in steps(times, out[LEVEL])] == [3.0, 4.0]


def test_a_slip_still_felt_raises_the_level_every_repeat_period_up_to_max_level():
    times = sample_times_us(1000, 12.0)
    out, _ = drive(times, display(times, [(0.0, 12.0, slip(1))]), **EXACT, slip_repeat_s=2.0)
    landed = steps(times, out[LEVEL])
    assert [v for _, v in landed] == [1.0, 2.0, 3.0, 4.0]  # max_level 4: e5 is never aimed at
    assert np.allclose(np.diff([t for t, _ in landed]), 2.0)


def test_a_wearer_trained_on_the_damped_task_adds_the_slip_level_to_the_level_held():
    """slip_response_adds: the speed measures the grip missing, so at e2 a level-2 slip
    asks for e4, and the next slow slip (level 1) for one more, e5."""
    times = sample_times_us(1000, 10.0)
    inputs = display(times, [(0.0, 2.0, slip(2)), (4.0, 10.0, slip(1))])
    out, _ = drive(
        times, inputs, **EXACT, slip_repeat_s=0, rest_level=2, max_level=5, slip_response_adds=True
    )
    assert [v for _, v in steps(times, out[LEVEL])] == [4.0, 5.0]


def test_an_added_response_never_lowers_the_aim_and_repeats_add_one_step():
    times = sample_times_us(1000, 12.0)
    inputs = display(times, [(0.0, 12.0, slip(3))])
    out, _ = drive(
        times,
        inputs,
        **EXACT,
        slip_repeat_s=3.0,
        rest_level=1,
        max_level=5,
        slip_response_adds=True,
    )
    landed = steps(times, out[LEVEL])
    assert [v for _, v in landed] == [4.0, 5.0]  # e1 + 3, then one step 3 s later, capped at e5
    assert np.isclose(landed[1][0] - landed[0][0], 3.0)


def test_the_slip_response_map_is_configurable():
    times = sample_times_us(1000, 4.0)
    inputs = display(times, [(0.0, 4.0, slip(1))])
    out, _ = drive(
        times, inputs, **EXACT, slip_repeat_s=0, slip_response_levels=[3, 3, 4, 5], max_level=5
    )
    assert [v for _, v in steps(times, out[LEVEL])] == [3.0]


def test_a_moderate_force_is_held():
    times = sample_times_us(1000, 30.0)
    inputs = display(times, [(0.0, 2.0, slip(2)), (2.0, 30.0, force(2))])
    out, _ = drive(times, inputs, **EXACT, slip_repeat_s=0)
    assert [v for _, v in steps(times, out[LEVEL])] == [2.0]
    assert out[LEVEL][-1] == 2.0


def test_a_high_force_without_slip_relaxes_one_level_per_period_to_rest():
    times = sample_times_us(1000, 20.0)
    inputs = display(times, [(0.0, 2.0, slip(4)), (2.0, 20.0, force(4))])
    out, _ = drive(times, inputs, **EXACT, slip_repeat_s=0, relax_after_s=3.0)
    landed = steps(times, out[LEVEL])
    assert [v for _, v in landed] == [4.0, 3.0, 2.0, 1.0, 0.0]
    assert np.allclose(np.diff([t for t, _ in landed[1:]]), 3.0)


def test_relaxing_stops_when_the_force_shown_drops_below_the_relax_level():
    times = sample_times_us(1000, 30.0)
    inputs = display(times, [(0.0, 2.0, slip(4)), (2.0, 6.0, force(4)), (6.0, 30.0, force(2))])
    out, _ = drive(times, inputs, **EXACT, slip_repeat_s=0, relax_after_s=3.0)
    assert [v for _, v in steps(times, out[LEVEL])] == [4.0, 3.0]


def test_full_relaxation_is_exact_even_with_scatter():
    times = sample_times_us(1000, 40.0)
    inputs = display(times, [(0.0, 2.0, slip(4)), (2.0, 40.0, force(4))])
    params = {"force_confusion": IDENTITY, "slip_confusion": IDENTITY, "slip_repeat_s": 0}
    out, effect = drive(times, inputs, seed=4, **params)
    assert effect.intended == 0 and out[LEVEL][-1] == 0.0


def test_nothing_felt_keeps_the_level_unless_idle_relaxing_is_asked():
    times = sample_times_us(1000, 30.0)
    inputs = display(times, [(0.0, 2.0, slip(3))])
    kept, _ = drive(times, inputs, **EXACT, slip_repeat_s=0)
    assert [v for _, v in steps(times, kept[LEVEL])] == [3.0]
    relaxed, _ = drive(times, inputs, **EXACT, slip_repeat_s=0, idle_relax_s=5.0)
    assert [v for _, v in steps(times, relaxed[LEVEL])] == [3.0, 2.0, 1.0, 0.0]


# ---------------------------------------------------------------- execution scatter


def test_the_produced_level_scatters_around_the_aim_as_configured():
    """Slip (aim e3) and a high force (relax to e2, the rest level) alternate; each lands off."""
    period_s, count = 2.2, 2400
    rate_hz = 100
    times = sample_times_us(rate_hz, period_s * count)
    inputs = alternating(times, period_s, slip(1), force(4), count)
    scatter = [0.1, 0.2, 0.4, 0.2, 0.1]
    params = {
        "force_confusion": IDENTITY,
        "slip_confusion": IDENTITY,
        "scatter": scatter,
        "slip_repeat_s": 0,
        "slip_response_levels": [3, 3, 3, 3],
        "rest_level": 2,
        "relax_after_s": 0.1,
    }
    out, effect = drive(times, inputs, rate_hz=rate_hz, **params)
    assert effect.counts["contractions"] == count
    # Slip contractions land 1.51-1.75 s into their segment, relaxations 1.0-1.1 s.
    at = np.searchsorted(times, (np.arange(count) * period_s + 2.0) * 1e6)
    aims = np.where(np.arange(count) % 2 == 0, 3, 2)
    offsets = out[LEVEL][at] - aims
    share = np.array([np.mean(offsets == d) for d in (-2, -1, 0, 1, 2)])
    p = np.array(scatter)
    assert np.all(np.abs(share - p) <= 4.5 * np.sqrt(p * (1 - p) / count) + 1 / count), share


# ---------------------------------------------------------------- hard cases


@pytest.mark.parametrize("rest_level", [0, 2])
def test_without_belt_motion_the_wearer_stays_at_its_rest_level(rest_level):
    times = sample_times_us(1000, 60.0)
    out, effect = drive(times, display(times, []), rest_level=rest_level, idle_relax_s=1.0)
    assert np.all(out[LEVEL] == rest_level) and np.all(out[PERCEIVED] == 0)
    assert effect.counts["cues"] == 0 and effect.counts["contractions"] == 0


def test_a_display_flickering_faster_than_the_reaction_is_perceived_serially_and_bounded():
    times = sample_times_us(1000, 20.0)
    inputs = alternating(times, 0.2, slip(2), (SURFACE, 0.0), 50)
    out, effect = drive(times, inputs, **EXACT, max_pending_cues=3)
    assert effect.counts["dropped_cues"] > 0
    assert len(effect._queue) <= 3
    assert out[LEVEL].max() >= 2  # it reacted to the slip bursts
    perceived = steps(times, out[PERCEIVED])
    assert perceived[0][0] >= 1.51 - 0.1  # nothing is identified before a reaction time
    assert {v for _, v in perceived} <= {-2.0, 0.0}


def test_a_display_flickering_faster_than_min_cue_is_never_identified():
    times = sample_times_us(1000, 10.0)
    inputs = alternating(times, 0.05, slip(3), (SURFACE, 0.0), 200)
    out, effect = drive(times, inputs, **EXACT)
    assert effect.counts["cues"] == 0 and effect.counts["brief_displays"] == 100
    assert np.all(out[LEVEL] == 0)


def test_a_slow_ramp_through_the_levels_makes_one_cue_per_level_reached():
    times = sample_times_us(1000, 10.0)
    t = times / 1e6
    inputs = {TAP: tap_hz(8.0) * np.clip(t / 4.0, 0, 1), SURFACE: np.zeros(len(t))}
    out, effect = drive(times, inputs, **EXACT)
    assert effect.counts["cues"] == 4
    assert [v for _, v in steps(times, out[PERCEIVED])] == [1.0, 2.0, 3.0, 4.0]


@pytest.mark.parametrize("bad", [np.nan, -3.0, np.inf])
def test_invalid_display_values_are_felt_as_nothing_and_counted(bad):
    times = sample_times_us(1000, 6.0)
    inputs = display(times, [(1.0, 6.0, slip(2))])
    inputs[TAP][:500] = bad
    inputs[SURFACE][2000:2003] = bad  # three samples inside the slip display
    out, effect = drive(times, inputs, **EXACT, slip_repeat_s=0)
    assert effect.counts["invalid_samples"] == 503
    assert effect.counts["cues"] == 1  # the 3 ms dropout is too brief to be a cue of its own
    assert [v for _, v in steps(times, out[PERCEIVED])] == [-2.0]
    assert np.all(np.isfinite(out[LEVEL]))


def test_both_belts_at_once_are_felt_as_slip():
    times = sample_times_us(1000, 4.0)
    inputs = display(times, [(0.0, 4.0, slip(3)), (0.0, 4.0, force(1))])
    out, _ = drive(times, inputs, **EXACT)
    assert [v for _, v in steps(times, out[PERCEIVED])] == [-3.0]


def test_the_force_levels_follow_the_nub_count():
    times = sample_times_us(1000, 3.0)
    inputs = display(times, [(0.0, 3.0, (TAP, tap_hz(6.5, nubs=4)))])
    out, _ = drive(times, inputs, **EXACT, nubs=4)
    assert [v for _, v in steps(times, out[PERCEIVED])] == [3.0]


@pytest.mark.parametrize(
    ("params", "key"),
    [
        ({"force_levels_rad_s": [3.5, 3.5, 6.5, 8.0]}, "force_levels_rad_s"),
        ({"slip_levels_mm_s": [55.0]}, "slip_levels_mm_s"),
        ({"slip_levels_mm_s": [55, -1, 145, 190]}, r"slip_levels_mm_s\[1\]"),
        ({"force_confusion": IDENTITY[:3]}, "force_confusion"),
        (
            {"force_confusion": [[0.5, 0.5, 0, 0], [0.5, 0.4, 0, 0], *IDENTITY[2:]]},
            r"force_confusion\[1\]",
        ),
        ({"slip_confusion": [[1.2, -0.2, 0, 0], *IDENTITY[1:]]}, r"slip_confusion\[0\]\[1\]"),
        ({"slip_confusion": [[1, 0, 0], *IDENTITY[1:]]}, r"slip_confusion\[0\]"),
        ({"scatter": [0.5, 0.5]}, "scatter"),
        ({"scatter": [0.2, 0.7, 0.2]}, "scatter"),
        ({"slip_reaction_s": [1.8, 1.5]}, "slip_reaction_s"),
        ({"force_reaction_s": [0.1, 0.3]}, "force_reaction_s"),
        ({"slip_reaction_s": [1.5, 90]}, r"slip_reaction_s\[1\]"),
        ({"motor_delay_s": -0.1}, "motor_delay_s"),
        ({"min_cue_s": 0.95}, "force_reaction_s"),
        ({"force_detect_hz": 4.0}, "force_detect_hz"),
        ({"slip_detect_mm_s": 60.0}, "slip_detect_mm_s"),
        ({"slip_response_levels": [1, 2, 3]}, "slip_response_levels"),
        ({"slip_response_levels": [2, 1, 3, 4]}, "slip_response_levels"),
        ({"slip_response_levels": [1, 2, 3, 5]}, r"slip_response_levels\[3\]"),
        ({"slip_response_levels": [1, 1.5, 3, 4]}, "slip_response_levels"),
        ({"max_level": 6}, "max_level"),
        ({"rest_level": 3, "max_level": 2}, "max_level"),
        ({"relax_force_level": 5}, "relax_force_level"),
        ({"relax_after_s": 0.01}, "relax_after_s"),
        ({"slip_repeat_s": -1}, "slip_repeat_s"),
        ({"max_pending_cues": 0}, "max_pending_cues"),
        ({"nubs": 0}, "nubs"),
        ({"typo_s": 1.0}, "typo_s"),
    ],
)
def test_bad_parameters_name_the_key(params, key):
    with pytest.raises(SceneError, match=rf"effect\.{key}"):
        wearer(**params)


# ---------------------------------------------------------------- the shipped demo scene


def test_the_demo_scene_wearer_contracts_against_slip_and_relaxes_under_high_force(tmp_path):
    scene = Path(__file__).resolve().parents[2] / "scenes" / "wearer_demo.toml"
    simulation(load_scene(scene), Recorder(tmp_path)).run()
    data = np.genfromtxt(tmp_path / "truth.csv", delimiter=",", names=True)
    times_us = np.round(data["t_s"] * 1e6)
    level, perceived = data["wearerlevel"], data["wearerperceived_level"]
    assert [v for _, v in steps(times_us, perceived)] == [2.0, -2.0, -4.0, 4.0, 0.0]
    landed = steps(times_us, level)
    assert [v for _, v in landed] == [2.0, 3.0, 4.0, 3.0, 2.0, 1.0]
    slip_shown_s = data["t_s"][np.argmax(data["beltsurface_mm_s"] >= 25.0)]
    assert 1.51 <= landed[0][0] - slip_shown_s <= 1.75 + 0.001
    assert np.allclose(np.diff([t for t, _ in landed[3:]]), 3.0)  # relaxing under a high force
    emg = np.genfromtxt(tmp_path / "emg.csv", delimiter=",", names=True)
    rectified = np.abs(emg["emgraw_uv"])
    at_rest = rectified[(emg["t_s"] > 0.5) & (emg["t_s"] < 3.5)].mean()
    at_e4 = rectified[(emg["t_s"] > 9.0) & (emg["t_s"] < 13.0)].mean()
    assert at_e4 > 10 * at_rest  # the EMG node measures the wearer's contraction
