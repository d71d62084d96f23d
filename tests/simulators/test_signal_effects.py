"""Skin, noise and EMG effects: the thesis models, chunk invariance, determinism, errors."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from grasplink.core.params import SceneError
from grasplink.simulators import harness
from grasplink.simulators.core import EMG, SKIN, Endpoint, build_graph
from grasplink.simulators.effects import emg, noise, skin

SKIN_HZ, EMG_HZ = 400, 1500
ALPHA_01 = (19.0, 12.0, 5.0, 8.0, 4.0, 3.0, 33.0)  # table 5.1, alpha = 0.1
UNIFORM_4 = (4.0,) * 20
FIXED = {"rise_jitter": [1.0, 1.0], "alpha_n": [1.0, 1.0]}  # no random pulse parameters
K_THESIS = math.cos(math.radians(60)) / (
    math.sin(math.radians(60)) + 0.7813 * math.cos(math.radians(60))
)


def skin_ctx(layout=ALPHA_01, seed=1, rate_hz=SKIN_HZ):
    return harness.context(seed=seed, rate_hz=rate_hz, layout_mm=layout)


def slide(times_us, speed_mm_s, start_mm, grip_n=2.0, load_n=1.0, slipping=1.0):
    """Physics inputs of an object sliding at constant speed (consistent position/speed)."""
    t = times_us / 1e6
    n = len(t)
    return {
        "object.position_mm": start_mm + speed_mm_s * t,
        "object.speed_mm_s": np.full(n, float(speed_mm_s)),
        "hand.grip_n": np.full(n, grip_n),
        "load.force_n": np.full(n, load_n),
        "object.slipping": np.full(n, slipping),
        "skin.force_n": np.zeros(n),
    }


def rich_scene(times_us):
    """Forward slip with speed dips, a stop, then a reverse slip (edge switch), at 400 Hz."""
    t = times_us / 1e6
    speed = np.where(t < 2.5, 60 + 15 * np.sin(2 * np.pi * 1.3 * t), 0.0)
    speed = np.where(t >= 3.0, -45.0, speed)
    dt = np.diff(t, prepend=t[0])
    position = -15 + np.cumsum(speed * dt)
    reverse = t >= 3.0
    position[reverse] = position[reverse] - 90.0  # the leading edge is now the other edge
    n = len(t)
    return {
        "object.position_mm": position,
        "object.speed_mm_s": speed,
        "hand.grip_n": 3 + np.sin(t),
        "load.force_n": 1.5 + 0.2 * np.cos(3 * t),
        "object.slipping": (speed != 0).astype(float),
        "skin.force_n": 2 + np.sin(2 * np.pi * 0.7 * t) * 3,
        "emg.raw_uv": np.zeros(n),
        "wearer.level": np.clip(2.5 + 2.6 * np.sin(t), 0, 5),
    }


def run_one(kind, ctx, times_us, inputs, chunk=None, **params):
    effect = harness.make(kind, ctx, **params)
    return harness.run([effect], times_us, inputs, chunk=chunk), effect


def contacts_for(times_us, inputs, layout, **params):
    out, effect = run_one(skin.RidgeContacts, skin_ctx(layout), times_us, inputs, **params)
    return out["skin.force_n"], list(effect.contacts)


# -- chunked stepping equals one-shot stepping ---------------------------------------------

CHUNKED = [
    ("skin.fsr", skin.FsrForce, SKIN_HZ, {}),
    ("skin.ridge_contacts", skin.RidgeContacts, SKIN_HZ, {"tip_probability": 0.5}),
    (
        "skin.ridge_contacts fast",
        skin.RidgeContacts,
        SKIN_HZ,
        {"min_rise_s": 0.05, "tip_probability": 1.0},
    ),
    ("skin.hysteresis", skin.Hysteresis, SKIN_HZ, {"width_n": 0.5}),
    ("skin.saturation", skin.Saturation, SKIN_HZ, {"full_scale_n": 3.0}),
    ("skin.adc", skin.Adc, SKIN_HZ, {"bits": 8, "full_scale_n": 5.0}),
    ("noise.white", noise.WhiteNoise, SKIN_HZ, {"std": 0.3}),
    ("noise.white emg", noise.WhiteNoise, EMG_HZ, {"std": 3.0, "signal": "emg.raw_uv"}),
    ("noise.drift", noise.Drift, SKIN_HZ, {"std": 0.3, "corner_hz": 2.0, "offset": 0.1}),
    ("emg.surface", emg.SurfaceEmg, EMG_HZ, {}),
    ("emg.surface fatigue", emg.SurfaceEmg, EMG_HZ, {"fatigue_per_s": 0.2, "regulate_s": 0.1}),
    ("emg.surface unregulated", emg.SurfaceEmg, EMG_HZ, {"regulate_s": 0.0}),
]


@pytest.mark.parametrize(
    ("name", "kind", "rate_hz", "params"), CHUNKED, ids=[c[0] for c in CHUNKED]
)
def test_chunked_stepping_equals_one_shot_exactly(name, kind, rate_hz, params):
    times = harness.sample_times_us(rate_hz, 6.0)
    inputs = rich_scene(times)
    ctx = skin_ctx(rate_hz=rate_hz)
    whole, _ = run_one(kind, ctx, times, inputs, **params)
    for chunk in (1, 7, 400, 1499):
        parts, _ = run_one(kind, ctx, times, inputs, chunk=chunk, **params)
        for signal, values in whole.items():
            assert np.array_equal(values, parts[signal]), (name, chunk, signal)
            assert np.all(np.isfinite(values))


def test_the_rich_scene_makes_contacts_both_ways():
    times = harness.sample_times_us(SKIN_HZ, 6.0)
    _, contacts = contacts_for(times, rich_scene(times), ALPHA_01)
    directions = {c.direction for c in contacts}
    assert directions == {1, -1}


# -- skin.fsr (thesis ch. 4.3) -------------------------------------------------------------


def test_ridge_factor_is_the_thesis_k():
    assert skin.ridge_factor(0.7813, 60.0) == pytest.approx(K_THESIS, rel=1e-12)
    assert skin.ridge_factor(0.7813, 60.0) == pytest.approx(0.397875, abs=1e-6)


def test_fsr_reads_the_grip_share_over_the_skin_when_not_slipping():
    times = harness.sample_times_us(SKIN_HZ, 1.0)
    inputs = slide(times, 0.0, 45.0, grip_n=4.0, load_n=3.0, slipping=0.0)
    out, _ = run_one(skin.FsrForce, skin_ctx(), times, inputs)
    # object [-45, 45] over skin [0, 84]: half of the 90 mm object
    assert np.allclose(out["skin.force_n"], 4.0 * 45 / 90)


def test_fsr_share_follows_coverage_in_both_directions():
    fsr = harness.make(skin.FsrForce, skin_ctx(), object_length_mm=90.0)
    positions = np.array([-10.0, 0.0, 30.0, 84.0, 90.0, 120.0, 174.0, 200.0])
    forward = fsr.coverage(positions, np.ones(len(positions), bool))
    assert np.allclose(forward, [0, 0, 30 / 90, 84 / 90, 84 / 90, 54 / 90, 0, 0])
    reverse = fsr.coverage(positions, np.zeros(len(positions), bool))
    assert np.allclose(reverse, [80 / 90, 84 / 90, 54 / 90, 0, 0, 0, 0, 0])


def test_fsr_coverage_ramps_as_the_object_slides_on():
    times = harness.sample_times_us(SKIN_HZ, 3.0)
    inputs = slide(times, 40.0, -10.0, grip_n=9.0, slipping=0.0)
    out, _ = run_one(skin.FsrForce, skin_ctx(), times, inputs)
    front = inputs["object.position_mm"]
    expected = 9.0 * np.clip(np.minimum(front, 84.0) - np.maximum(front - 90, 0), 0, None) / 90
    assert np.allclose(out["skin.force_n"], expected)


def test_fsr_while_slipping_is_the_thesis_model():
    times = harness.sample_times_us(SKIN_HZ, 0.5)
    inputs = slide(times, 0.0, 60.0, grip_n=6.0, load_n=2.5, slipping=1.0)
    out, _ = run_one(skin.FsrForce, skin_ctx(), times, inputs)
    share = 60 / 90  # of the object over the sensor: grip and load act with this share
    expected = (1 - K_THESIS * 0.7813) * 6.0 * share + K_THESIS * 2.5 * share
    assert np.allclose(out["skin.force_n"], expected)


def test_fsr_keeps_the_direction_while_the_object_stands():
    times = harness.sample_times_us(SKIN_HZ, 1.0)
    inputs = slide(times, 0.0, 30.0, grip_n=9.0, slipping=0.0)
    inputs["object.speed_mm_s"][:10] = -5.0  # moved in reverse, then stopped
    out, _ = run_one(skin.FsrForce, skin_ctx(), times, inputs)
    assert np.allclose(out["skin.force_n"][10:], 9.0 * 54 / 90)  # reverse cover [30, 120]


# -- skin.ridge_contacts (thesis ch. 5.3.1, 5.4.2) -----------------------------------------


def test_contacts_come_when_the_edge_reaches_each_ridge_with_sub_sample_timing():
    times = harness.sample_times_us(SKIN_HZ, 3.0)
    inputs = slide(times, 33.0, -1.234)
    _, contacts = contacts_for(times, inputs, ALPHA_01, **FIXED)
    ridges = skin.ridge_positions_mm(ALPHA_01)
    assert [c.ridge for c in contacts] == list(range(len(ridges)))
    assert np.allclose([c.time_s for c in contacts], (ridges + 1.234) / 33.0, atol=1e-9)


@pytest.mark.parametrize("chunk", [1, 2, None])
@pytest.mark.parametrize("speed_mm_s", [25.0, -25.0])
def test_a_sample_landing_on_a_ridge_makes_its_contact_in_that_chunk(chunk, speed_mm_s):
    """A point is crossed when the edge reaches it (x0 < x <= x1 forward, x1 < x <= x0 in
    reverse): a sample exactly on a ridge makes the contact with that sample, however the
    samples are chunked, also when a chunk's whole travel ends or starts on the ridge
    (the chunk that travels to a ridge crosses it, the next one from it does not)."""
    ridges = skin.ridge_positions_mm(ALPHA_01)
    times = harness.sample_times_us(SKIN_HZ, 0.1)  # 2.5 mm: no other ridge
    step_mm = abs(speed_mm_s) / SKIN_HZ  # 1/16 mm: ridges, steps and positions exact
    ridge = ridges[2] if speed_mm_s > 0 else ridges[5]
    start_mm = ridge - np.sign(speed_mm_s) * 13 * step_mm
    inputs = slide(times, speed_mm_s, start_mm)
    inputs["object.position_mm"] = start_mm + np.sign(speed_mm_s) * step_mm * np.arange(len(times))
    assert ridge in inputs["object.position_mm"]
    _, contacts = contacts_for(times, inputs, ALPHA_01, **FIXED)
    if chunk is not None:
        _, effect = run_one(skin.RidgeContacts, skin_ctx(), times, inputs, chunk, **FIXED)
        assert list(effect.contacts) == contacts
    assert [c.ridge for c in contacts] == [2 if speed_mm_s > 0 else 5]
    assert contacts[0].time_s == times[13] / 1e6


def test_reverse_contacts_meet_the_ridges_from_the_last_one():
    times = harness.sample_times_us(SKIN_HZ, 3.0)
    inputs = slide(times, -40.0, 90.0)
    _, contacts = contacts_for(times, inputs, ALPHA_01, **FIXED)
    ridges = skin.ridge_positions_mm(ALPHA_01)
    assert [c.ridge for c in contacts] == list(range(len(ridges)))[::-1]
    assert all(c.direction == -1 for c in contacts)
    assert np.allclose([c.time_s for c in contacts], (90.0 - ridges[::-1]) / 40.0, atol=1e-9)
    # the last ridge is met first (after the lead-in); ridge i then follows spacing i
    heights = {c.ridge: c.alpha_n for c in contacts}
    assert heights[7] == pytest.approx(1 - math.exp(-20 / 10))
    assert heights[6] == pytest.approx(1 - math.exp(-33 / 10))


@pytest.mark.parametrize("speed_mm_s", [12.0, 20.0, 40.0])
def test_uniform_skin_contact_rate_and_spectral_peak_are_v_over_d(speed_mm_s):
    times = harness.sample_times_us(SKIN_HZ, 84.0 / speed_mm_s)
    inputs = slide(times, speed_mm_s, -2.0)
    ctx = skin_ctx(UNIFORM_4)
    effects = [harness.make(skin.FsrForce, ctx), harness.make(skin.RidgeContacts, ctx)]
    out = harness.run(effects, times, inputs)["skin.force_n"]
    contact_times = effects[1].contact_times_s
    assert len(contact_times) == 21
    assert np.allclose(np.diff(contact_times), 4.0 / speed_mm_s)

    on_skin = (inputs["object.position_mm"] >= 0) & (inputs["object.position_mm"] <= 80)
    window = out[on_skin]
    t = times[on_skin] / 1e6
    window = window - np.polyval(np.polyfit(t, window, 1), t)  # the slow coverage ramp
    spectrum = np.abs(np.fft.rfft(window * np.hanning(len(window)), n=16 * len(window)))
    freqs = np.fft.rfftfreq(16 * len(window), 1 / SKIN_HZ)
    band = (freqs >= 1.0) & (freqs <= 20.0)
    peak_hz = freqs[band][np.argmax(spectrum[band])]
    assert peak_hz == pytest.approx(speed_mm_s / 4.0, rel=0.03)


def test_pulse_peaks_at_alpha_one_over_beta_after_the_contact():
    times = np.arange(0, 800_000, 50, dtype=np.int64)  # 20 kHz to see the shape
    inputs = slide(times, 50.0, -1.0)
    out, contacts = contacts_for(times, inputs, (30.0,), **FIXED)
    first = contacts[0]
    rise_s = 2.5 / (2 * 50.0)
    alpha = 1 - math.exp(-20 / 10)  # lead-in 20 mm, spacing scale 10 mm
    assert first.rise_s == pytest.approx(rise_s)
    assert first.alpha_n == pytest.approx(alpha)
    before_next = times / 1e6 < contacts[1].time_s
    peak = np.argmax(out[before_next])
    assert out[peak] == pytest.approx(alpha, abs=1e-6)
    assert times[peak] / 1e6 - first.time_s == pytest.approx(rise_s, abs=1e-4)
    assert np.all(out[times / 1e6 < first.time_s] == 0)


def test_pulse_rise_starts_from_the_previous_pulse_and_reaches_alpha():
    times = np.arange(0, 7_000_000, 100, dtype=np.int64)
    layout = (20.0, 3.0, 20.0, 3.0, 20.0)
    out, contacts = contacts_for(times, slide(times, 10.0, -1.0), layout, **FIXED)
    t = times / 1e6
    for previous, contact in itertools.pairwise(contacts):
        start = np.searchsorted(t, contact.time_s)
        # continuous across the contact: the new segment starts where the old one is
        assert out[start] == pytest.approx(out[start - 1], abs=2e-3)
        at_peak = np.argmin(np.abs(t - (contact.time_s + contact.rise_s)))
        assert out[at_peak] == pytest.approx(contact.alpha_n, abs=1e-4)
        assert previous.time_s < contact.time_s


def test_heights_are_larger_after_larger_spacings():
    times = harness.sample_times_us(SKIN_HZ, 8.0)
    layout = (20.0, 3.0, 20.0, 3.0, 20.0)
    _, contacts = contacts_for(times, slide(times, 10.0, -1.0), layout)
    heights = [c.alpha_n for c in contacts]
    after_large = [heights[i] for i in (1, 3, 5)]
    after_small = [heights[i] for i in (2, 4)]
    assert min(after_large) > 2 * max(after_small)
    assert all(0.8 * 0.86 <= h <= 1.2 * 0.87 for h in after_large)  # alpha draws [0.8, 1.2]


def test_pulse_width_follows_speed_within_its_limits():
    times = harness.sample_times_us(SKIN_HZ, 3.0)
    for speed, expected in ((5.0, 0.2), (25.0, 0.05), (2000.0, 0.002)):
        duration = harness.sample_times_us(SKIN_HZ, min(3.0, 90.0 / speed + 0.1))
        _, contacts = contacts_for(duration, slide(duration, speed, -1.0), ALPHA_01, **FIXED)
        assert contacts
        assert all(c.rise_s == pytest.approx(expected) for c in contacts)
    _, jittered = contacts_for(times, slide(times, 25.0, -1.0), ALPHA_01)
    assert all(0.9 * 0.05 <= c.rise_s <= 1.1 * 0.05 for c in jittered)
    assert len({c.rise_s for c in jittered}) == len(jittered)


def test_fast_slips_merge_pulses_continuously_and_finitely():
    layout = (3.0,) * 28
    dense = np.arange(0, 50_000, 10, dtype=np.int64)  # 100 kHz
    out, contacts = contacts_for(dense, slide(dense, 2000.0, -1.0), layout, **FIXED)
    assert len(contacts) == 29
    assert np.all(np.isfinite(out))
    assert out.max() <= 1.0 and out.min() >= 0.0
    # contacts every 1.5 ms inside a 2 ms rise: no jumps, the train stays high
    assert np.max(np.abs(np.diff(out))) < 0.02
    t = dense / 1e6
    middle = (t > contacts[3].time_s) & (t < contacts[-1].time_s)
    assert out[middle].min() > 0.1
    coarse = harness.sample_times_us(SKIN_HZ, 0.05)
    out400, contacts400 = contacts_for(coarse, slide(coarse, 2000.0, -1.0), layout, **FIXED)
    assert len(contacts400) == 29 and np.all(np.isfinite(out400))


def test_zero_speed_makes_no_contacts_and_no_nan():
    times = harness.sample_times_us(SKIN_HZ, 2.0)
    for start in (0.0, 19.0, 10.0):  # on the first ridge, on the second, between
        inputs = slide(times, 0.0, start)
        inputs["skin.force_n"] = np.full(len(times), 1.25)
        out, contacts = contacts_for(times, inputs, ALPHA_01)
        assert contacts == []
        assert np.array_equal(out, inputs["skin.force_n"])


def test_a_reversal_jump_of_the_leading_edge_is_not_a_contact():
    times = harness.sample_times_us(SKIN_HZ, 1.0)
    inputs = slide(times, 20.0, 20.0)
    half = len(times) // 2
    inputs["object.speed_mm_s"][half:] = -20.0
    inputs["object.position_mm"][half:] = inputs["object.position_mm"][half - 1] - 90.0
    _, contacts = contacts_for(times, inputs, ALPHA_01, **FIXED)
    assert contacts == []  # from 20 to 30 mm between ridges, then jumping back to -60 mm
    # the same through a standing sample that still reports the forward edge
    inputs["object.speed_mm_s"][half] = 0.0
    inputs["object.position_mm"][half] = inputs["object.position_mm"][half - 1]
    _, contacts = contacts_for(times, inputs, ALPHA_01, **FIXED)
    assert contacts == []


def test_tip_contacts_come_only_when_asked():
    times = harness.sample_times_us(SKIN_HZ, 5.0)
    layout = (20.0, 3.0, 20.0)
    inputs = slide(times, 10.0, -1.0)
    _, plain = contacts_for(times, inputs, layout)
    assert not any(c.tip for c in plain)
    _, tipped = contacts_for(times, inputs, layout, tip_probability=1.0, **FIXED)
    tips = [c for c in tipped if c.tip]
    assert [c.ridge for c in tips] == [0, 2]  # into the two 20 mm spacings, not the 3 mm one
    assert np.allclose([c.time_s for c in tips], (np.array([0.0, 23.0]) + 5.0 + 1.0) / 10.0)
    ridge_alpha = {c.ridge: c.alpha_n for c in tipped if not c.tip}
    assert tips[0].alpha_n == pytest.approx(0.4 * ridge_alpha[0])
    assert len([c for c in tipped if not c.tip]) == 4


def test_tip_probability_thins_the_tip_contacts():
    times = harness.sample_times_us(SKIN_HZ, 9.0)
    layout = (20.0,) * 4
    counts = []
    for seed in range(40):
        _, effect = run_one(
            skin.RidgeContacts,
            skin_ctx(layout, seed=seed),
            times,
            slide(times, 10.0, -1.0),
            tip_probability=0.5,
        )
        counts.append(sum(c.tip for c in effect.contacts))
    assert 0.35 < np.mean(counts) / 4 < 0.65


def test_a_run_ending_mid_pulse_carries_on_seamlessly():
    times = harness.sample_times_us(SKIN_HZ, 2.0)
    inputs = slide(times, 10.0, -1.0)
    whole, _ = run_one(skin.RidgeContacts, skin_ctx(), times, inputs)
    effect = harness.make(skin.RidgeContacts, skin_ctx())
    cut = int(0.15 * SKIN_HZ)  # first contact at 0.1 s, peak at 0.225 s
    first = harness.run([effect], times[:cut], {k: v[:cut] for k, v in inputs.items()})
    assert 0 < first["skin.force_n"][-1] < max(c.alpha_n for c in effect.contacts)
    rest = harness.run([effect], times[cut:], {k: v[cut:] for k, v in inputs.items()})
    assert np.array_equal(
        np.concatenate([first["skin.force_n"], rest["skin.force_n"]]), whole["skin.force_n"]
    )


def test_the_contact_record_is_bounded():
    layout = (1.0,) * 1500
    times = harness.sample_times_us(SKIN_HZ, 16.0)
    _, effect = run_one(
        skin.RidgeContacts, skin_ctx(layout), times, slide(times, 100.0, -1.0), **FIXED
    )
    assert len(effect.contacts) == skin.CONTACT_RECORD
    assert effect.contacts[-1].ridge == 1500


# -- sensor non-idealities -----------------------------------------------------------------


def test_saturation_clips_to_the_fsr_range():
    times = harness.sample_times_us(SKIN_HZ, 1.0)
    force = np.linspace(-5, 150, len(times))
    out, _ = run_one(skin.Saturation, skin_ctx(), times, {"skin.force_n": force})
    assert np.array_equal(out["skin.force_n"], np.clip(force, 0, 98.067))


def test_adc_quantises_to_its_levels():
    times = harness.sample_times_us(SKIN_HZ, 25.0)
    force = np.linspace(-5, 120, len(times))
    out, _ = run_one(skin.Adc, skin_ctx(), times, {"skin.force_n": force})
    values = out["skin.force_n"]
    step = 98.067 / 4095
    assert np.allclose(values / step, np.round(values / step), atol=1e-9)
    assert np.all(np.abs(values - np.clip(force, 0, 98.067)) <= step / 2 + 1e-12)
    assert values.min() == 0 and values.max() == pytest.approx(98.067)
    small, _ = run_one(
        skin.Adc, skin_ctx(), times, {"skin.force_n": force}, bits=3, full_scale_n=7.0
    )
    assert np.allclose(np.unique(small["skin.force_n"]), np.arange(8.0))


def test_hysteresis_loop_is_width_wide_and_unloads_to_zero():
    times = harness.sample_times_us(SKIN_HZ, 2.0)
    up = np.linspace(0, 10, len(times) // 2)
    force = np.concatenate([up, up[::-1]])
    out, _ = run_one(skin.Hysteresis, skin_ctx(), times, {"skin.force_n": force}, width_n=0.4)
    y = out["skin.force_n"]
    rising, falling = y[: len(up)], y[len(up) :][::-1]
    middle = (up > 1) & (up < 9)
    assert np.allclose(rising[middle], up[middle] - 0.2)
    assert np.allclose(falling[middle], up[middle] + 0.2)
    assert np.allclose(falling[middle] - rising[middle], 0.4)
    assert y[0] == 0 and y[-1] == 0
    assert np.all(np.abs(y - force) <= 0.2 + 1e-12)


# -- noise ---------------------------------------------------------------------------------


def test_noise_steps_in_the_domain_of_its_signal():
    ctx = skin_ctx()
    on_skin = harness.make(noise.WhiteNoise, ctx, std=0.1)
    on_emg = harness.make(noise.Drift, ctx, signal="emg.raw_uv", std=2.0)
    assert (on_skin.kind, on_skin.domain, on_skin.inputs) == (
        "noise.white",
        SKIN,
        ("skin.force_n",),
    )
    assert (on_emg.kind, on_emg.domain, on_emg.outputs) == ("noise.drift", EMG, ("emg.raw_uv",))
    assert isinstance(on_emg, noise.Drift) and type(on_emg).domain == EMG
    assert type(harness.make(noise.Drift, ctx, signal="emg.raw_uv")) is type(on_emg)


def test_modifiers_run_in_scene_order_after_the_producer():
    ctx = harness.Context("test", 1, {"physics": 1000, SKIN: SKIN_HZ, EMG: EMG_HZ}, ALPHA_01)
    effects = [
        harness.make(skin.Adc, ctx),
        harness.make(noise.WhiteNoise, ctx),
        harness.make(skin.RidgeContacts, ctx),
        harness.make(skin.FsrForce, ctx),
        harness.make(emg.SurfaceEmg, ctx),
        harness.make(noise.WhiteNoise, ctx, signal="emg.raw_uv"),
    ]
    physics = Endpoint(
        "physics",
        writes=(
            "object.position_mm",
            "object.speed_mm_s",
            "object.slipping",
            "hand.grip_n",
            "load.force_n",
            "wearer.level",
        ),
    )
    ordered, domain_of = build_graph(effects, [physics], "test")
    kinds = [e.kind for e in ordered]
    assert kinds.index("skin.fsr") < kinds.index("skin.adc")
    assert domain_of["emg.raw_uv"] == EMG
    assert kinds.index("emg.surface") < kinds.index("noise.white", kinds.index("emg.surface"))


def test_white_noise_has_the_asked_std_and_no_memory():
    times = harness.sample_times_us(SKIN_HZ, 250.0)
    out, _ = run_one(
        noise.WhiteNoise, skin_ctx(), times, {"skin.force_n": np.full(len(times), 3.0)}, std=0.5
    )
    added = out["skin.force_n"] - 3.0
    assert np.std(added) == pytest.approx(0.5, rel=0.01)
    assert abs(np.mean(added)) < 0.01
    assert abs(np.corrcoef(added[:-1], added[1:])[0, 1]) < 0.01


def test_drift_has_the_asked_std_and_only_low_frequencies():
    times = harness.sample_times_us(SKIN_HZ, 3000.0)
    out, _ = run_one(
        noise.Drift,
        skin_ctx(),
        times,
        {"skin.force_n": np.zeros(len(times))},
        std=0.3,
        corner_hz=0.5,
        offset=1.0,
    )
    drift = out["skin.force_n"]
    assert np.mean(drift) == pytest.approx(1.0, abs=0.03)
    assert np.std(drift) == pytest.approx(0.3, rel=0.05)
    power = np.abs(np.fft.rfft(drift - drift.mean())) ** 2
    freqs = np.fft.rfftfreq(len(drift), 1 / SKIN_HZ)
    assert power[freqs > 5.0].sum() / power.sum() < 1e-3
    assert power[freqs < 0.5].sum() / power.sum() > 0.5


def test_drift_is_stationary_from_the_first_sample():
    times = harness.sample_times_us(SKIN_HZ, 0.01)
    firsts = []
    for seed in range(1500):
        out, _ = run_one(
            noise.Drift, skin_ctx(seed=seed), times, {"skin.force_n": np.zeros(len(times))}, std=0.3
        )
        firsts.append(out["skin.force_n"][0])
    assert np.std(firsts) == pytest.approx(0.3, rel=0.06)


def test_stationary_variance_matches_a_long_impulse_response():
    from scipy import signal as sp

    sos = sp.butter(2, 0.5, "lowpass", fs=400, output="sos")
    _, variance = noise.stationary_state(sos[0])
    impulse = np.zeros(200_000)
    impulse[0] = 1
    assert variance == pytest.approx(np.sum(sp.sosfilt(sos, impulse) ** 2), rel=1e-9)


# -- determinism ---------------------------------------------------------------------------


class NoRandomness(harness.Context):
    def rng(self, effect_key):
        raise AssertionError(f"{effect_key} used the rng")


def test_skin_signal_without_noise_is_exactly_deterministic():
    times = harness.sample_times_us(SKIN_HZ, 6.0)
    inputs = rich_scene(times)
    outputs = []
    for seed in (1, 2):
        ctx = skin_ctx(seed=seed)
        effects = [harness.make(skin.FsrForce, ctx), harness.make(skin.RidgeContacts, ctx, **FIXED)]
        outputs.append(harness.run(effects, times, inputs)["skin.force_n"])
    assert np.array_equal(*outputs)
    assert np.any(outputs[0] != 0)


def test_effects_without_randomness_never_touch_the_rng():
    times = harness.sample_times_us(SKIN_HZ, 6.0)
    ctx = NoRandomness("test", 1, {SKIN: SKIN_HZ, EMG: EMG_HZ, "physics": SKIN_HZ}, ALPHA_01)
    effects = [
        harness.make(skin.FsrForce, ctx),
        harness.make(skin.RidgeContacts, ctx, **FIXED),
        harness.make(noise.WhiteNoise, ctx, std=0.0),
        harness.make(noise.Drift, ctx, std=0.0, offset=0.5),
        harness.make(skin.Hysteresis, ctx),
        harness.make(skin.Saturation, ctx),
        harness.make(skin.Adc, ctx),
    ]
    out = harness.run(effects, times, rich_scene(times))["skin.force_n"]
    assert np.all(np.isfinite(out))


def test_random_effects_change_with_the_seed():
    times = harness.sample_times_us(SKIN_HZ, 6.0)
    inputs = rich_scene(times)
    a, _ = run_one(skin.RidgeContacts, skin_ctx(seed=1), times, inputs)
    b, _ = run_one(skin.RidgeContacts, skin_ctx(seed=2), times, inputs)
    assert not np.array_equal(a["skin.force_n"], b["skin.force_n"])


def test_two_noise_streams_on_one_signal_are_independent():
    times = harness.sample_times_us(SKIN_HZ, 50.0)
    ctx = skin_ctx()
    zeros = {"skin.force_n": np.zeros(len(times))}
    a, _ = run_one(noise.WhiteNoise, ctx, times, zeros, std=1.0)
    b, _ = run_one(noise.WhiteNoise, ctx, times, zeros, std=1.0, stream="second")
    assert abs(np.corrcoef(a["skin.force_n"], b["skin.force_n"])[0, 1]) < 0.03


# -- emg.surface (thesis ch. 2.3) ----------------------------------------------------------


def emg_run(level, duration_s=1.0, seed=1, chunk=None, **params):
    times = harness.sample_times_us(EMG_HZ, duration_s)
    levels = np.broadcast_to(np.asarray(level, float), times.shape).copy()
    out, effect = run_one(
        emg.SurfaceEmg,
        harness.context(seed=seed, rate_hz=EMG_HZ),
        times,
        {"wearer.level": levels},
        chunk=chunk,
        **params,
    )
    return out["emg.raw_uv"], effect


@pytest.mark.parametrize("level", [0, 1, 2, 3, 4, 5])
def test_emg_rectified_mean_is_the_level_target_within_5_percent(level):
    targets = [10.0, 50 + 0.5 * 112.5, 50 + 1.5 * 112.5, 50 + 2.5 * 112.5, 50 + 3.5 * 112.5, 625.0]
    for seed in range(5):
        raw, _ = emg_run(level, seed=seed)
        assert np.mean(np.abs(raw)) == pytest.approx(targets[level], rel=0.05)


def test_emg_fractional_levels_interpolate():
    raw, effect = emg_run(2.5)
    assert np.mean(np.abs(raw)) == pytest.approx(275.0, rel=0.05)
    assert np.allclose(effect.targets_uv, [10, 106.25, 218.75, 331.25, 443.75, 625])


def test_emg_amplitude_reads_nan_as_rest_and_infinities_as_the_end_levels():
    """A level the wearer model cannot tell (NaN) is rest; beyond the levels (however far,
    infinities too) the end levels hold: `sigma_uv` as np.interp of nan_to_num's levels."""
    _, effect = emg_run(0, duration_s=0.01)
    level = np.array([np.nan, np.inf, -np.inf, 1e308, -1e308, -0.0, 2.5, 7.0])
    got = effect.sigma_uv(level)
    ends = np.interp(np.nan_to_num(level, nan=0.0), np.arange(6), effect.targets_uv)
    assert got.tobytes() == (ends * math.sqrt(math.pi / 2)).tobytes()
    assert got[0] == got[5] == effect.targets_uv[0] * math.sqrt(math.pi / 2)
    assert got[1] == got[3] == got[7] == effect.targets_uv[-1] * math.sqrt(math.pi / 2)


def test_unregulated_emg_is_a_stationary_gaussian_with_the_target_mean():
    raw, _ = emg_run(3, duration_s=30.0, regulate_s=0.0)
    sigma = 331.25 * math.sqrt(math.pi / 2)
    assert np.mean(np.abs(raw)) == pytest.approx(331.25, rel=0.02)
    assert np.std(raw) == pytest.approx(sigma, rel=0.02)
    kurtosis = np.mean(raw**4) / np.mean(raw**2) ** 2
    assert kurtosis == pytest.approx(3.0, abs=0.15)


@pytest.mark.parametrize("regulate_s", [0.25, 0.0])
def test_emg_power_lies_in_its_band(regulate_s):
    raw, _ = emg_run(2, duration_s=20.0, regulate_s=regulate_s)
    power = np.abs(np.fft.rfft(raw)) ** 2
    freqs = np.fft.rfftfreq(len(raw), 1 / EMG_HZ)
    inside = (freqs >= 20) & (freqs <= 450)
    assert power[inside].sum() / power.sum() > 0.9
    assert power[freqs < 10].sum() / power.sum() < 0.01


def test_emg_amplitude_follows_a_level_step_with_the_onset_time_constant():
    step = np.where(np.arange(3000) < 1500, 4.0, 1.0)
    raw_step, _ = emg_run(step, duration_s=2.0)
    raw_four, _ = emg_run(4.0, duration_s=2.0)
    ratio = raw_step / raw_four  # the same noise: the ratio is the amplitude envelope
    t_after = np.arange(1500) / EMG_HZ
    low = 106.25 / 443.75
    expected = low + (1 - low) * np.exp(-(t_after + 1 / EMG_HZ) / 0.05)
    assert np.allclose(ratio[:1500], 1.0)
    assert np.allclose(ratio[1500:], expected, rtol=0.01)


def test_emg_fatigue_raises_amplitude_and_lowers_frequency():
    raw, _ = emg_run(4.0, duration_s=10.0, fatigue_per_s=0.1)
    fresh, late = raw[:1500], raw[-1500:]
    # f = 0.1 / s x 9.5 s at level 4: amplitude x 1.95, spectrum compressed to 0.51
    assert np.mean(np.abs(late)) == pytest.approx(443.75 * 1.95, rel=0.06)
    assert np.mean(np.abs(fresh)) == pytest.approx(443.75 * 1.05, rel=0.06)

    def median_hz(x):
        power = np.abs(np.fft.rfft(x)) ** 2
        cumulative = np.cumsum(power) / power.sum()
        return np.fft.rfftfreq(len(x), 1 / EMG_HZ)[np.searchsorted(cumulative, 0.5)]

    assert median_hz(late) < 0.65 * median_hz(fresh)
    rested, _ = emg_run(4.0, duration_s=10.0)
    assert np.mean(np.abs(rested[-1500:])) == pytest.approx(443.75, rel=0.05)


def test_emg_without_fatigue_ignores_the_fatigue_machinery():
    a, _ = emg_run(3.0, duration_s=2.0)
    b, _ = emg_run(3.0, duration_s=2.0, fatigue_per_s=0.0)
    assert np.array_equal(a, b)


# -- bad parameters ------------------------------------------------------------------------

BAD = [
    (skin.FsrForce, {"object_length_mm": 0}, "object_length_mm"),
    (skin.FsrForce, {"ridge_angle_deg": 120}, "ridge_angle_deg"),
    (skin.FsrForce, {"mu": "high"}, "mu"),
    (skin.RidgeContacts, {"alpha_n": [1.2, 0.8]}, "alpha_n"),
    (skin.RidgeContacts, {"alpha_n": [1.0, 1.1, 1.2]}, "alpha_n"),
    (skin.RidgeContacts, {"rise_jitter": [0.0, 1.0]}, "rise_jitter[0]"),
    (skin.RidgeContacts, {"min_rise_s": 0.1, "max_rise_s": 0.05}, "max_rise_s"),
    (skin.RidgeContacts, {"tip_probability": 1.5}, "tip_probability"),
    (skin.RidgeContacts, {"spacing_scale_mm": 0}, "spacing_scale_mm"),
    (skin.RidgeContacts, {"ridge_sides_mm": 2.5}, "ridge_sides_mm"),
    (skin.Hysteresis, {"width_n": -0.1}, "width_n"),
    (skin.Saturation, {"full_scale_n": 0}, "full_scale_n"),
    (skin.Adc, {"bits": 12.5}, "bits"),
    (skin.Adc, {"bits": 0}, "bits"),
    (noise.WhiteNoise, {"signal": "object.speed_mm_s"}, "signal"),
    (noise.WhiteNoise, {"std": -1}, "std"),
    (noise.Drift, {"corner_hz": 250}, "corner_hz"),
    (noise.Drift, {"corner_hz": 0}, "corner_hz"),
    (emg.SurfaceEmg, {"band_hz": [450, 20]}, "band_hz"),
    (emg.SurfaceEmg, {"band_hz": [20, 800]}, "band_hz"),
    (emg.SurfaceEmg, {"e_min_uv": 500, "e_max_uv": 50}, "e_max_uv"),
    (emg.SurfaceEmg, {"onset_s": -1}, "onset_s"),
    (emg.SurfaceEmg, {"regulate_s": 0.0001}, "regulate_s"),
]


@pytest.mark.parametrize(("kind", "params", "key"), BAD, ids=[f"{b[0].kind}-{b[2]}" for b in BAD])
def test_bad_parameters_name_the_key(kind, params, key):
    rate = EMG_HZ if kind is emg.SurfaceEmg else SKIN_HZ
    with pytest.raises(SceneError) as caught:
        harness.make(kind, skin_ctx(rate_hz=rate), **params)
    assert caught.value.key == f"effect.{key}"


@pytest.mark.parametrize("kind", [skin.FsrForce, skin.RidgeContacts])
def test_skin_geometry_effects_need_a_layout(kind):
    with pytest.raises(SceneError, match="needs a skin layout"):
        harness.make(kind, harness.context(rate_hz=SKIN_HZ))
