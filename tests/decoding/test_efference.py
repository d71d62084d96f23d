"""The efference copy (issue 22): the grip the loop commanded, told to the decoder.

The gateway tells its decoder every grip command it puts on the bus
(`Decoder.note_grip_command`); `grasplink decode R/can.asc` reads them back from the hand's
RPDO in the log, so offline decoding gives what the gateway decoded live; the tracker
weighs a contact at the onset of a commanded grip rise as the grip's (`decoding/efference.py`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from grasplink.decoding import io
from grasplink.decoding.efference import (
    HAND_LAG_S,
    KINKS_LATE_IN_RISE,
    KINKS_PER_RISE,
    LATE_ONSET_S,
    ONSET_TIMING_S,
    GripCommands,
    HandFollow,
)
from grasplink.decoding.registry import make_decoder
from grasplink.errors import ConfigError
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation.slip_reporting import headline_figures
from grasplink.profiles.layouts import parse_layout

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "scenes" / "loop_headline.toml"
HEADLINE_STOP_S = 1.768  # the reflex stops the object (truth)
GRIP_CONTACT_S = 1.826  # the contact the reflex's grip rise makes


@pytest.fixture(scope="module")
def headline(tmp_path_factory) -> dict:
    """The headline loop run as `grasplink run` runs it: its can.asc, what the gateway's
    own decoder was told and decoded live, and the truth."""
    from grasplink.controllers import build_controllers
    from grasplink.evaluation import scenes as sc
    from grasplink.simulators.engine import Simulation
    from grasplink.simulators.recording import Recorder
    from grasplink.simulators.scene import load_scene

    folder = tmp_path_factory.mktemp("headline")
    scene = load_scene(SCENE)
    sim = Simulation(scene, Recorder(folder), controllers=build_controllers(scene))
    gateway = sim.controllers[0]
    live: list = []
    gateway.estimate_listeners.append(lambda t_us, estimate: live.append(estimate))
    sim.run()
    signals = sc.record_scene(SCENE, build_controllers, folder / "again")
    return {
        "log": folder / "can.asc",
        "gateway": gateway,
        "live": live,
        "rec": signals.can,
    }


def decode(log: Path, commands: bool) -> list:
    """`grasplink decode` of a CAN log, 3 samples at a time, with or without the commands."""
    t, x, stats = io.read_can_log(log)
    decoder = make_decoder("tracker", parse_layout("alpha0.1"), stats.rate_hz)
    if commands:
        io.read_grip_commands(log).feed(decoder)
    estimates, _ = ns.feed(decoder, t, x, 3)
    return estimates


def speed_at_rest(estimates: list) -> list[float]:
    """Update times with a speed 0.15 s or more into the headline's rest."""
    return [e.t_s for e in estimates if e.speed_mm_s and e.t_s >= HEADLINE_STOP_S + 0.15]


# -- the input and its guard ----------------------------------------------------------------
def tracker() -> object:
    return make_decoder("tracker", parse_layout("alpha0.1"), 400.0)


def test_bad_grip_commands_are_counted_and_named_never_kept():
    decoder = tracker()
    assert decoder.note_grip_command(1.0, 5.0)
    assert not decoder.note_grip_command(float("nan"), 6.0)
    assert not decoder.note_grip_command(1.1, math.inf)
    assert not decoder.note_grip_command(1.1, -1.0)  # a grip is no pull
    assert not decoder.note_grip_command(1.1, 1e9)  # beyond 0x2400's 100 N
    assert not decoder.note_grip_command(0.5, 6.0)  # before the previous command
    assert decoder.note_grip_command(1.0, 6.0)  # the same time: a second command, kept
    stats = decoder.grip_commands.stats
    assert (stats.accepted, stats.rejected_nonfinite, stats.rejected_range) == (2, 2, 2)
    assert stats.rejected_time == 1
    report = decoder.input_report()
    assert report is not None and "grip commands" in report and "0-100 N" in report, report
    assert "earlier than the previous command" in report, report
    assert len(decoder.grip_commands) == 2


@pytest.mark.parametrize("value", ["five", None, True, [1.0]])
def test_a_grip_command_that_is_no_number_is_a_clear_error(value):
    with pytest.raises(ValueError, match="grip command force must be a number"):
        tracker().note_grip_command(1.0, value)


def test_the_hand_follow_is_checked_against_the_hand_node():
    decoder = tracker()
    with pytest.raises(ConfigError, match="0x2404"):
        decoder.set_hand_follow(0.0)
    with pytest.raises(ConfigError, match="lag"):
        decoder.set_hand_follow(50.0, -1.0)
    decoder.set_hand_follow(20.0)
    assert decoder.grip_commands.follow == HandFollow(20.0, HAND_LAG_S)


def test_the_default_lag_is_the_hand_actuators():
    """The window's lag is the hand actuator's (the `hand.actuator` effect's default)."""
    from grasplink.simulators.effects.actuators import HandActuator
    from grasplink.simulators.harness import context, make

    actuator = make(HandActuator, context(seed=1, rate_hz=1000, layout_mm=(10.0,)))
    assert actuator.lag.time_constant_s == HAND_LAG_S
    assert HandFollow.default().rate_n_s == 50.0  # the hand EDS's 0x2404 default


def test_a_change_is_the_commands_whose_windows_run_into_a_time():
    commands = GripCommands(HandFollow(50.0, 0.1))
    assert commands.change_at(1.0) is None
    commands.note(0.1, 5.0, 1e9)  # the grip held at start: no change
    assert commands.change_at(1.0) is None
    for k in range(13):  # a slew-limited ramp 5 -> 11.5 N, a step each 10 ms
        commands.note(1.70 + 0.01 * k, 5.5 + 0.5 * k, 1e9)
    assert commands.change_at(1.69) is None  # before it: only commands before count
    change = commands.change_at(1.826)
    assert change is not None and change.start_s == pytest.approx(1.70)
    assert change.from_n == 5.0 and change.change_n == pytest.approx(6.5)  # 1.82 s: 11.5 N
    assert change.window_s == pytest.approx(0.12 + 0.5 / 50 + 3 * 0.1)
    assert commands.change_at(2.5) is None  # settled
    # the rise's contacts come at its onset: within a lag (and the detector's timing) of
    # its first command, one per rise (benchmarks/grip_ramp_contacts.py)
    rise = commands.rise_at(1.826)
    assert rise is not None and rise.start_s == pytest.approx(1.70)
    assert rise.from_n == 5.0 and rise.change_n == pytest.approx(6.5)
    assert rise.window_s == pytest.approx(HAND_LAG_S + ONSET_TIMING_S)
    # a contact whose slope jump the grip cannot make is seldom the grip's
    gentle = commands.contact_rate_per_s(1.826, 6.0, 2.0)
    steep = commands.contact_rate_per_s(1.826, 60.0, 2.0)
    assert gentle == pytest.approx(KINKS_PER_RISE / rise.window_s) and steep < 0.05 * gentle
    # just past the onset a long rise's level bends again now and then (up to a lag plus
    # LATE_ONSET_S after its first command: grip_long_rise_contacts.py), below the onset's
    # rate; later in the rise, while the grip still moves, no more than clutter
    assert commands.change_at(1.90) is not None and commands.rise_at(1.90) is None
    late = commands.contact_rate_per_s(1.90, 6.0, 2.0)
    span = LATE_ONSET_S - ONSET_TIMING_S
    assert late == pytest.approx(KINKS_LATE_IN_RISE / span) and late < gentle
    assert commands.change_at(2.0) is not None and commands.contact_rate_per_s(2.0, 6.0, 2.0) == 0


def test_a_wearers_stepped_contraction_is_charged_late_in_each_runs_onset():
    """The loop benchmark's crush (20 mm/s, seed 8, reflex on; the slip-speed rows): the
    gateway raised a released grip 0.5 N every 10 ms, 0 -> 11 N, held 0.2 s, on to 20 N
    (its CAN log); the level bent 0.201 s into the first run and 0.157 s into the second,
    past their onsets. Taken for ridges at rest, they fired the reflex onto a 20 N grip and
    crushed the object (`benchmarks/loop_trial_outcomes.py`: crushed with no charge past
    the onset). Held-object rises bend there, 0.15-0.23 s into a run, and no later
    (`benchmarks/grip_long_rise_contacts.py`)."""
    commands = GripCommands(HandFollow(50.0, 0.1))
    commands.note(0.1, 5.0, 1e9)
    for k in range(10):  # released: 5 -> 0 N
        commands.note(4.24 + 0.01 * k, 4.5 - 0.5 * k, 1e9)
    for k in range(22):  # 0.5 -> 11 N
        commands.note(4.47 + 0.01 * k, 0.5 + 0.5 * k, 1e9)
    for k in range(18):  # 11.5 -> 20 N, a 0.04 s gap inside the run
        commands.note(4.88 + 0.01 * k + (0.03 if k >= 6 else 0.0), 11.5 + 0.5 * k, 1e9)
    assert commands.rise_at(4.671) is None and commands.rise_at(5.037) is None  # past onsets
    for t_s in (4.671, 5.037):  # the crush trial's late bends: the grip's, likely
        assert commands.contact_rate_per_s(t_s, 8.0, 8.0) > 1.0
    assert commands.contact_rate_per_s(4.80, 8.0, 8.0) == 0.0  # 0.33 s into the first run
    assert commands.contact_rate_per_s(4.45, 8.0, 8.0) == 0.0  # the fall before it


def test_a_grip_fall_makes_no_contact_and_a_new_rise_a_new_onset():
    """A fall turns the level down (no onset of a rise: none in 128 measured falls); a rise
    commanded again after the grip held a while bends the level up anew."""
    commands = GripCommands(HandFollow(50.0, 0.1))
    commands.note(0.0, 8.0, 1e9)
    for k in range(6):  # 8 -> 5 N, a step each 10 ms
        commands.note(1.0 + 0.01 * k, 7.5 - 0.5 * k, 1e9)
    assert commands.change_at(1.06) is not None  # the grip moves ...
    assert commands.rise_at(1.06) is None  # ... but down
    assert commands.contact_rate_per_s(1.06, 3.0, 1.0) == 0.0
    commands.note(1.5, 5.5, 1e9)  # a rise after the grip held: its own onset
    commands.note(1.51, 6.0, 1e9)
    rise = commands.rise_at(1.55)
    assert rise is not None and rise.start_s == 1.5 and rise.change_n == pytest.approx(1.0)
    assert commands.contact_rate_per_s(1.55, 3.0, 1.0) > 0.0
    commands.note(1.8, 6.5, 1e9)  # raised again more than a lag later: a new onset
    rise = commands.rise_at(1.85)
    assert rise is not None and rise.start_s == 1.8 and rise.from_n == 6.0


# -- the tracker ----------------------------------------------------------------------------
def test_commands_that_weigh_no_contact_change_nothing():
    """A command in no contact's window (the grip held at start, or a change after the last
    contact) leaves every output bit for bit as without it."""
    rec = ns.Signal("accelerating", *ns.VARIANTS["accelerating"][0], "alpha0.1", False, 3).make()
    plain, _ = ns.feed(make_decoder("tracker", rec.truth.layout_mm, rec.fs_hz), rec.t_s,
                       rec.force_n, 3)  # fmt: skip
    told = make_decoder("tracker", rec.truth.layout_mm, rec.fs_hz)
    told.note_grip_command(0.0, 5.0)
    told.note_grip_command(float(rec.t_s[-1]) + 1.0, 8.0)
    again, _ = ns.feed(told, rec.t_s, rec.force_n, 3)
    assert [e.as_dict() for e in again] == [e.as_dict() for e in plain]


def test_the_headline_grip_rise_carries_no_speed_into_the_rest_told_or_not(headline):
    """Until s27, without the commands a braking track through the reflex's grip contact
    (1.826 s) showed 24 -> 8 mm/s from 1.91 to 2.08 s, the object at rest since 1.768 s;
    told the commands, the tracker took that contact for the grip. Since s27 the live
    decoder reads the bend at 1.496 s as no ridge (`told_rise`), shows the slip's range
    and no speed, and the reflex's grip rise differs: the headline shows no speed at rest
    told or not, and must stay so."""
    log = headline["log"]
    assert not speed_at_rest(decode(log, commands=False))
    assert not speed_at_rest(decode(log, commands=True))


@pytest.fixture(scope="module")
def least_force(tmp_path_factory) -> dict:
    """loop_least_force run as `grasplink run` runs it: the wearer raises the grip twice
    while the object slides (3.38 s, 4.59 s) and it stops at 4.805 s."""
    from grasplink.controllers import build_controllers
    from grasplink.evaluation import scenes as sc

    folder = tmp_path_factory.mktemp("least_force")
    signals = sc.record_scene(ROOT / "scenes" / "loop_least_force.toml", build_controllers, folder)
    return {"log": folder / "can.asc", "rec": signals.can}


def test_told_the_wearers_grip_rise_the_tracker_shows_no_speed_at_rest(least_force):
    """Where the commands matter: the wearer's grip rise at 4.59-4.74 s bends the level at
    4.62 s while the object slows to its stop (4.805 s). Untold, the tracker takes that bend
    for a ridge and shows 38-39 mm/s until 5.13 s, the object at rest; told, it weighs the
    bend as the grip's and shows no speed at rest."""
    log, rec = least_force["log"], least_force["rec"]
    stops = [s for s in ns.motion(rec).stops if s[1] - s[0] > 1.0]
    assert stops, "the scene's object no longer comes to rest"
    rest_from_s, rest_until_s = stops[0][0] + 0.15, stops[0][1]

    def at_rest(estimates: list) -> list[float]:
        return [e.t_s for e in estimates if e.speed_mm_s and rest_from_s <= e.t_s < rest_until_s]

    assert len(at_rest(decode(log, commands=False))) > 10  # the contrast
    assert not at_rest(decode(log, commands=True))


def test_the_headline_keeps_its_speed_while_it_slides(headline):
    """The commands weigh only contacts in a commanded change's window: the speed before
    the reflex raised the grip (1.70 s) is what it was."""
    log = headline["log"]
    plain = [e for e in decode(log, commands=False) if e.t_s < 1.70]
    told = [e for e in decode(log, commands=True) if e.t_s < 1.70]
    assert [e.as_dict() for e in told] == [e.as_dict() for e in plain]
    figures = headline_figures(decode(log, commands=True), headline["rec"])
    assert figures["last_ok"] is not False and figures["rest_ok"], figures


def test_a_grip_rise_mid_slide_keeps_the_sliding_levels_ramp_hold(monkeypatch):
    """The loop raises the grip while the object still slides on (loop case 163201: alpha0.7,
    30 mm/s the far end first, the grip 5 -> 8.8 N over the last 0.6 s before the stop): the
    level ramps on past the grip's share, so told the commands the ramp hold keeps the flag
    as untold; the grip alone taking the ramp dropped it in 121 of 201 sliding updates
    (untold 62)."""
    from dataclasses import replace

    from grasplink.decoding.tracker import TrackerDecoder
    from grasplink.evaluation import slip_reporting as sr

    plan = replace(sr.FULL, seeds=1)
    (case,) = [c for c in sr.cases(plan) if c.kind == "loop" and c.seed == 163201]
    monkeypatch.setattr(TrackerDecoder, "RAMP_GRIP_SHARE", 1.0)
    configs = {"told": {}, "untold": {"grip_commands": False}}
    scores = sr.case_job(case, "tracker", configs, False)["scores"]
    monkeypatch.setattr(TrackerDecoder, "RAMP_GRIP_SHARE", 0.0)
    grip = sr.case_job(case, "tracker", {"told": {}}, False)["scores"]["told"]
    assert grip.dropped_from2 > scores["untold"].dropped_from2 + 20  # the contrast
    assert scores["told"].dropped_from2 <= scores["untold"].dropped_from2


# -- the gateway and the CAN log ------------------------------------------------------------
def test_the_gateway_tells_its_decoder_every_grip_command_it_sends(headline):
    """The live decoder was told what the hand's RPDO carried, when it went on the bus."""
    run = headline
    told = run["gateway"].decoder.grip_commands
    logged = io.read_grip_commands(run["log"])
    assert len(logged.t_s) > 10 and logged.rate_n_s == 50.0
    assert told._t == logged.t_s.tolist() and told._f == logged.force_n.tolist()
    assert told.follow.rate_n_s == 50.0


def test_decoding_the_log_gives_what_the_gateway_decoded_live(headline):
    run = headline
    offline = decode(run["log"], commands=True)
    live = run["live"]
    assert [e.as_dict() for e in live] == [e.as_dict() for e in offline[: len(live)]]


def test_grasplink_decode_feeds_the_logs_grip_commands(headline, capsys):
    from grasplink import cli

    log = headline["log"]
    assert cli.main(["decode", str(log), "--skin", "alpha0.1"]) == 0
    captured = capsys.readouterr()
    assert "grip commands fed to the decoder (grip rate 50 N/s)" in captured.err
    speeds = [line for line in captured.out.splitlines() if '"speed_mm_s": null' not in line]
    assert cli.main(["decode", str(log), "--skin", "alpha0.1", "--no-grip-commands"]) == 0
    plain = capsys.readouterr()
    assert "grip commands" not in plain.err
    assert captured.out != plain.out and len(speeds) > 0


def test_a_log_without_a_hand_gives_no_commands(tmp_path):
    import can

    path = tmp_path / "skin.asc"
    with can.Logger(str(path)) as logger:
        logger.on_message_received(can.Message(arbitration_id=0x190, data=bytes(8), timestamp=0))
    got = io.read_grip_commands(path)
    assert len(got.t_s) == 0 and got.frames == 0 and got.rate_n_s is None
    assert np.array_equal(got.force_n, np.zeros(0))
