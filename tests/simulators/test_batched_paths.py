"""The batched fast paths give exactly what the per-sample and per-chunk paths give."""

from __future__ import annotations

import filecmp
import itertools
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.controllers import simulation
from grasplink.core.frames import Frame
from grasplink.devices.factory import build_node
from grasplink.devices.skin import CAL_FULL_SCALE_MN, CAL_ZERO, SCALAR_COUNTS_MAX, SkinApp
from grasplink.devices.sources import FunctionSource
from grasplink.profiles import objects as obj
from grasplink.simulators.bindings import SceneSource
from grasplink.simulators.core import SHORT_CHUNK_SAMPLES, independent_parts
from grasplink.simulators.effects.actuators import (
    BeltMotor,
    CrushLatch,
    FirstOrderLag,
    HandActuator,
)
from grasplink.simulators.effects.emg import sosfilt_compiled, sosfilt_floats
from grasplink.simulators.engine import Simulation
from grasplink.simulators.recording import Recorder
from grasplink.simulators.scene import load_scene, parse_scene

SKIN = 0x10
MS = 1000


def _hard_force(t_s: np.ndarray) -> np.ndarray:
    """At rest, a ramp far past full scale (saturation), NaN (reads 0 N), at rest again."""
    force = np.where(t_s < 0.2, 0.0, 1000.0 * (t_s - 0.2))
    force = np.where((t_s > 0.5) & (t_s < 0.52), np.nan, force)
    return np.where(t_s > 0.7, 0.0, force)


def _skin_frames(source, read_ahead: int, feed=None) -> tuple[list[tuple[int, Frame]], SkinApp]:
    app = SkinApp(source)
    app.read_ahead_samples = read_ahead
    net = LockstepNetwork([build_node("skin", SKIN, source, app)])
    sent: list[tuple[int, Frame]] = []
    net.taps.append(lambda t, frame, _origin: sent.append((t, frame)))
    net.start()
    net.inject(Frame(0x000, bytes([0x01, SKIN])))  # NMT start
    for t_end in range(10 * MS, 1000 * MS + 1, 10 * MS):
        if feed is not None:
            feed(t_end)
        net.run_until(t_end - 1)
    return sent, app


@pytest.mark.parametrize("read_ahead", [1, 7, 256])
def test_skin_node_converting_ahead_sends_the_frames_of_converting_per_packet(read_ahead):
    source = FunctionSource(_hard_force)
    per_packet, app_a = _skin_frames(source, 0)
    ahead, app_b = _skin_frames(source, read_ahead)
    assert ahead == per_packet
    assert app_b.saturated_samples == app_a.saturated_samples > 0


def test_skin_node_converts_ahead_only_samples_the_scene_has_made_final():
    """Fed chunk by chunk as a scene feeds it: never a held value instead of a later one."""

    def run(read_ahead: int) -> list[tuple[int, Frame]]:
        source = SceneSource(400)

        def feed(t_end_us: int) -> None:  # the skin domain's samples of (t - 10 ms, t)
            start = -(-(t_end_us - 10 * MS) * 400 // 1_000_000)
            index = np.arange(start, -(-t_end_us * 400 // 1_000_000))
            times = index * 1_000_000 // 400
            source.append(times, _hard_force(times / 1e6))

        return _skin_frames(source, read_ahead, feed)[0]

    assert run(256) == run(0)


def _record(path: Path, out: Path, *, per_chunk: bool) -> Simulation:
    sim = simulation(load_scene(path), Recorder(out))
    if per_chunk:
        sim.step_us = sim.scene.chunk_us
    sim.run()
    return sim


def test_scene_without_node_commands_runs_in_long_steps_with_the_same_recording(tmp_path):
    path = Path(__file__).resolve().parents[2] / "scenes" / "slip_alpha0.1_60mm_s_forward.toml"
    long = _record(path, tmp_path / "long", per_chunk=False)
    _record(path, tmp_path / "chunked", per_chunk=True)
    assert not long.coupled and long.step_us > long.scene.chunk_us
    names = sorted(p.name for p in (tmp_path / "long").iterdir())
    _, mismatch, errors = filecmp.cmpfiles(
        tmp_path / "long", tmp_path / "chunked", names, shallow=False
    )
    assert names and mismatch == [] and errors == []


def test_scene_with_an_actuator_keeps_its_chunk():
    path = Path(__file__).resolve().parents[2] / "scenes" / "headline_slip.toml"
    sim = simulation(load_scene(path))
    assert sim.coupled and sim.step_us == sim.scene.chunk_us


def _loop_scene(duration_s: float, name: str = "loop_headline"):
    """A shipped scene cut short (loop_headline's first command ramps: 1.67-2.4 s)."""
    path = Path(__file__).resolve().parents[2] / "scenes" / f"{name}.toml"
    data = tomllib.loads(path.read_text())
    data["scene"]["duration_s"] = duration_s
    return parse_scene(data, str(path))


@pytest.mark.parametrize(
    ("name", "duration_s"), [("loop_headline", 2.5), ("loop_headline", 6.0), ("headline_slip", 1.5)]
)  # 10 and 50 ms chunks; loop_headline whole: the grip ramps -15, -15, -30 mN from 4 s
def test_closed_loop_physics_running_ahead_records_what_chunk_by_chunk_records(
    tmp_path, name, duration_s
):
    """Commands that change at chunk ends roll the run-ahead back: same files, byte for byte."""
    ahead = simulation(_loop_scene(duration_s, name), Recorder(tmp_path / "ahead"))
    chunked = simulation(_loop_scene(duration_s, name), Recorder(tmp_path / "chunked"))
    chunked.run_ahead_us = 0
    ahead.run()
    chunked.run()
    assert ahead.rollbacks > 0 and chunked.rollbacks == 0
    assert ahead.effect_steps < chunked.effect_steps  # it did run ahead
    names = sorted(p.name for p in (tmp_path / "ahead").iterdir())
    _, mismatch, errors = filecmp.cmpfiles(
        tmp_path / "ahead", tmp_path / "chunked", names, shallow=False
    )
    assert names and mismatch == [] and errors == []


def test_the_hand_and_the_belt_parts_run_ahead_each_as_its_commands_hold(monkeypatch):
    """loop_headline splits into the hand's part (grip, object, skin) and the belt's (belt,
    wearer, EMG): each runs ahead as its own commands allow (its first 2.5 s: the belt
    ramps longer than the hand), as one they stepped together, as often as the two ramps
    together forced."""
    sim = simulation(_loop_scene(2.5))
    parts = [sorted(e.kind for d in p.effects.values() for e in d) for p in sim.parts]
    assert [p.command_nodes for p in sim.parts] == [["hand"], ["belt"]]
    assert parts[1] == ["belt.motor", "emg.surface", "wearer.virtual"]
    steps: dict[str, int] = {}
    for cls in (HandActuator, BeltMotor):
        step = cls.step

        def counted(self, io, _step=step):
            steps[self.kind] = steps.get(self.kind, 0) + 1
            _step(self, io)

        monkeypatch.setattr(cls, "step", counted)
    sim.run()
    assert sim.rollbacks > 0
    # (the hand's commands follow the decoded slip: 34 before the tail kinks, s22; the
    # belt's too: 59 before the gateway told its decoder its grip commands, s23 - the
    # speed a braking track showed at rest from 1.91 s drove the belt; 33 and 61 before
    # their ramps' steps were continued, s24 `trends`: the ramps run ahead too; the belt's
    # 50 before a slip onto the empty skin entered at an end, s25 `arrival`; 42 before the
    # slip was flagged from its arrival onto the unloaded sensor, s26 `arrival_flag`: the
    # belt runs from 1.2 s, not 1.7; 28 and 67 before the bend at 1.496 s was read as no
    # ridge, s27 `told_rise`: the decoder shows the slip's range, 39.7-69 mm/s, no speed)
    assert steps == {"hand.actuator": 27, "belt.motor": 48}


def test_effects_sharing_no_signal_split_into_parts_with_their_commands():
    scene = _loop_scene(1.0)
    parts = independent_parts(scene.ordered, scene.endpoints)
    kinds = [[e.kind for e in effects] for effects, _ in parts]
    assert [[e.node for e in endpoints] for _, endpoints in parts] == [["hand"], ["belt"]]
    assert kinds[0][:2] == ["hand.actuator", "load.scripted"]  # load meets the grip in skin.fsr
    assert sorted(kinds[0] + kinds[1]) == sorted(e.kind for e in scene.ordered)
    alone = independent_parts([e for e in scene.ordered if e.kind == "noise.white"], [])
    assert [[e.kind for e in effects] for effects, _ in alone] == [["noise.white"]]


def test_a_run_stopped_mid_run_ahead_ends_at_the_chunk_it_was_stopped_in():
    """A loop trial stops at a chunk end (a drop): physics run ahead past it is not seen."""
    seen: list[int] = []
    sim = simulation(_loop_scene(1.0))
    sim.run(progress=lambda t_us, _end: seen.append(t_us), should_stop=lambda: len(seen) == 37)
    assert sim.t_us == 37 * sim.scene.chunk_us == seen[-1]
    assert seen == [k * sim.scene.chunk_us for k in range(1, 38)]


class _PlainSource:
    """A source that does not say which samples are final: read as the node asks."""

    def __init__(self) -> None:
        self.asked: list[int] = []

    def samples(self, t0_us: int, start_index: int, count: int, rate_hz: int) -> np.ndarray:
        self.asked.append(count)
        index = np.arange(start_index, start_index + count)
        return _hard_force((t0_us + index * 1_000_000 // rate_hz) / 1e6)


def test_skin_node_reads_a_source_without_final_samples_packet_by_packet():
    plain = _PlainSource()
    frames, _ = _skin_frames(plain, 256)
    assert frames == _skin_frames(FunctionSource(_hard_force), 0)[0]
    assert set(plain.asked) == {3}  # samples per PDO: never ahead of the packet


@pytest.mark.parametrize("initial", [0.0, 5.0])
def test_first_order_lag_steps_short_chunks_in_floats_as_lfilter_steps_long_ones(initial):
    """Chunks of 1-20 samples (floats) against one-shot (lfilter): the same bits, through
    a first sample, an uneven interval, a zero target, a huge one and a NaN."""
    times = np.concatenate([np.arange(0, 40_000, 1000), 40_500 + np.arange(0, 60_000, 1000)])
    target = np.full(len(times), 7.5)
    target[10:20] = 0.0
    target[30:35] = 1e12
    target[60] = np.nan
    target[61:] = -3.0
    one_shot = FirstOrderLag(0.05, initial).step(times, target)
    assert len(times) > SHORT_CHUNK_SAMPLES  # the one-shot run is lfilter's
    lag = FirstOrderLag(0.05, initial)
    bounds = [0, 1, 4, 5, 25, 31, 40, 41, 59, 62, 80, len(times)]
    chunked = np.concatenate(
        [lag.step(times[a:b], target[a:b]) for a, b in itertools.pairwise(bounds)]
    )
    assert chunked.tobytes() == one_shot.tobytes()
    assert np.isnan(chunked[60:]).all() and np.isfinite(chunked[:60]).all()


def test_crush_latch_latches_at_the_first_sample_over_the_limit_whatever_the_chunks():
    grip = np.array([1.0, np.nan, 24.9, 25.0, 25.1, 3.0, np.nan, 0.0])
    latch = CrushLatch(25.0)
    chunks = [latch.step(grip[a:b]) for a, b in ((0, 0), (0, 3), (3, 4), (4, 6), (6, 8))]
    assert np.concatenate(chunks).tolist() == [0, 0, 0, 0, 1, 1, 1, 1]
    assert CrushLatch(None).step(grip).tolist() == [0.0] * len(grip)


def test_one_section_filter_in_floats_gives_sosfilts_bits():
    """The EMG onset filter's short-chunk path: signed zeros, NaN and a settled start too."""
    a = 1.0 - np.exp(-1.0 / (1500 * 0.05))
    sos = np.array([[a, 0.0, 0.0, 1.0, a - 1.0, 0.0]])
    x = np.array([0.0, 0.0, 5.0, 1e9, -3.0, 0.0, 7.0, np.nan, 2.0])
    for zi in (np.zeros((1, 2)), signal.sosfilt_zi(sos) * 4.0, np.array([[-0.0, 0.0]])):
        for stop in (3, 7, len(x)):  # a NaN poisons the state from then on, in both
            want, want_z = signal.sosfilt(sos, x[:stop], zi=zi)
            got, got_z = sosfilt_floats(sos, x[:stop], zi)
            assert got.tobytes() == want.tobytes() and got_z.tobytes() == want_z.tobytes()


def test_compiled_sections_give_sosfilts_bits_and_leave_the_state_given():
    """The EMG's long chunks and noise blocks: the onset filter's one section and a
    band-pass of several, on strided columns, through signed zeros, NaN, infinities and
    huge values; sosfilt's output and final state bit for bit, the state given unchanged."""
    a = 1.0 - np.exp(-1.0 / (1500 * 0.05))
    one = np.array([[a, 0.0, 0.0, 1.0, a - 1.0, 0.0]])
    band = signal.butter(4, [20.0, 450.0], btype="bandpass", fs=1500.0, output="sos")
    rng = np.random.default_rng(11)
    draws = rng.standard_normal((500, 3))
    draws[[7, 90], 1] = -0.0
    draws[200, 2] = 1e300
    draws[300, 2] = np.inf
    draws[400, 0] = np.nan
    for sos in (one, band):
        for zi in (np.zeros((len(sos), 2)), rng.normal(size=(len(sos), 2))):
            for column, stop in itertools.product(range(3), (1, 65, 500)):
                x = draws[:stop, column]  # a strided view, as the noise bank's columns
                given = zi.copy()
                want, want_z = signal.sosfilt(sos, x, zi=zi)
                got, got_z = sosfilt_compiled(sos, x, zi)
                assert got.tobytes() == want.tobytes(), (len(sos), column, stop)
                assert got_z.tobytes() == want_z.tobytes(), (len(sos), column, stop)
                assert zi.tobytes() == given.tobytes()


def test_scene_source_holds_the_last_capacity_samples_as_concatenating_would():
    """Chunks of 0 to more than the ring's capacity, through many wraps of its buffers."""
    source = SceneSource(100)  # capacity 200
    rng = np.random.default_rng(3)
    all_times, all_values, t = np.zeros(0, np.int64), np.zeros(0), 0
    for count in [*rng.integers(0, 40, 200), 250, 3, 199, 200, 201, 0, 7]:
        times = np.arange(t, t + count * 10_000, 10_000, dtype=np.int64)
        values = rng.normal(size=count)
        t += count * 10_000
        source.append(times, values)
        all_times = np.concatenate([all_times, times])[-source.capacity :]
        all_values = np.concatenate([all_values, values])[-source.capacity :]
        assert np.array_equal(source.times_us, all_times)
        assert np.array_equal(source.values, all_values)
        assert source.final_until_us() == (int(all_times[-1]) if len(all_times) else -1)


@pytest.mark.parametrize("rate_hz", [400, 1500])
def test_scene_source_samples_are_np_interp_over_the_whole_ring_bit_for_bit(rate_hz):
    """A node's samples, interpolated over the held samples about them only, are those
    interpolating over the whole ring gives: on the scene's grid (read as the held samples
    themselves, `SceneSource._held`) and off it (a node reset mid-scene), before the
    ring's first sample, held past its last, at exact sample times, next to NaN and
    infinite samples and signed zeros."""
    source = SceneSource(rate_hz)
    rng = np.random.default_rng(5)
    count = 3 * source.capacity
    times = np.arange(count, dtype=np.int64) * 1_000_000 // rate_hz
    values = rng.normal(size=count)
    values[rng.integers(0, count, 40)] = np.nan
    values[rng.integers(0, count, 20)] = np.inf
    values[rng.integers(0, count, 20)] = -0.0
    checked = 0
    for end in range(10, count, 7):
        source.append(times[end - 7 : end], values[end - 7 : end])
        held_t, held_v = source.times_us, source.values
        for t0_us, first, n in (
            (0, end - 12, 12),  # on the grid: exact sample times
            (0, end - 1, 1),
            (137, end - 20, 9),  # off it, between held samples
            (137, end - 9, 9),  # the last one held past the ring's end
            (0, max(0, end - source.capacity - 4), 6),  # starting before the ring
        ):
            if first < 0:
                continue
            index = np.arange(first, first + n, dtype=np.int64)
            at = t0_us + index * 1_000_000 // rate_hz
            if at[-1] >= held_t[-1] + source.period_us:
                continue
            got = source.samples(t0_us, first, n, rate_hz)
            want = np.interp(at, held_t, held_v)
            assert got.tobytes() == want.tobytes(), (end, t0_us, first)
            checked += 1
    assert checked > 1000


@pytest.mark.parametrize("calibration", [None, (12, 1000)])
def test_skin_counts_of_a_few_samples_in_floats_are_to_counts_ints(calibration):
    """`SkinApp.counts_list` (Python floats up to SCALAR_COUNTS_MAX samples, numpy past it)
    gives `to_counts`' ints: NaN (0 N), +-inf, +-1e300, signed zeros, ties of round
    half to even, both ends of the scale and every count between (fails with round half
    up, or with the infinities left to `round`)."""
    app = SkinApp()
    build_node("skin", SKIN, None, app)
    if calibration is not None:  # another zero and full-scale force: ties elsewhere
        zero, scale_mn = calibration
        app.store.set(obj.SKIN_FSR_CALIBRATION, CAL_ZERO, zero)
        app.store.set(obj.SKIN_FSR_CALIBRATION, CAL_FULL_SCALE_MN, scale_mn)
    zero, full, mn_per_count = app.calibration()
    n_per_count = mn_per_count / 1000.0
    ties = (np.arange(-3, full + 3) + 0.5 - zero) * n_per_count  # x.5 counts, about
    special = [np.nan, np.inf, -np.inf, 1e300, -1e300, 0.0, -0.0, 5e-324, -5e-324]
    rng = np.random.default_rng(11)
    forces = np.concatenate(
        [special, ties, np.nextafter(ties, np.inf), np.nextafter(ties, -np.inf)]
    )
    forces = np.concatenate([forces, rng.uniform(-1, 1.2, 500) * full * n_per_count])
    rng.shuffle(forces)
    for size in (1, 4, 6, SCALAR_COUNTS_MAX, SCALAR_COUNTS_MAX + 1):
        for i in range(0, len(forces), size):
            chunk = forces[i : i + size]
            assert app.counts_list(chunk) == app.to_counts(chunk).tolist(), chunk
