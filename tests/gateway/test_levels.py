"""Calibration tables: defaults are the thesis's belt levels, bad tables name table and entry."""

from __future__ import annotations

import math
from typing import Any, cast

import pytest

from grasplink.devices.belt import limit_belt_velocity
from grasplink.errors import ConfigError
from grasplink.gateway.levels import (
    SLIP_BELT_SURFACE_MM_S,
    Belt,
    LevelQuantizer,
    force_table,
    slip_table,
)
from grasplink.profiles import load_profile
from grasplink.profiles import objects as obj


def test_default_force_levels_are_the_thesis_force_belt_speeds():
    table = force_table()
    assert table.velocities_mrad_s == (3500, 5000, 6500, 8000)  # ch. 8.3.2
    assert [table.velocity_mrad_s(k) for k in range(1, 5)] == [3500, 5000, 6500, 8000]


def test_default_slip_levels_turn_the_slip_belt_at_the_thesis_surface_speeds():
    table = slip_table()
    assert table.velocities_mrad_s == (2000, 3700, 5300, 7000)  # ch. 8.3.2
    assert [table.velocity_mrad_s(k) for k in range(1, 5)] == [-2000, -3700, -5300, -7000]
    radius_mm = load_profile("belt", 0x20)[obj.BELT_EFFECTIVE_RADIUS_UM].default / 1000
    surface = [v / 1000 * radius_mm for v in table.velocities_mrad_s]
    for shown, thesis in zip(surface, SLIP_BELT_SURFACE_MM_S, strict=True):
        assert shown == pytest.approx(thesis, abs=2.0)  # 55, 100, 145, 190 mm/s


@pytest.mark.parametrize("table", [force_table(), slip_table()], ids=["force", "slip"])
def test_default_levels_pass_the_belt_node_without_being_limited(table):
    for level in range(1, table.levels + 1):
        velocity = table.velocity_mrad_s(level)
        assert limit_belt_velocity(velocity, obj.FORCE_BELT_MAX_MRAD_S) == (velocity, False)


def test_a_single_level_table_is_valid():
    table = force_table([(2.0, 4000)], hysteresis_n=0.5)
    assert table.levels == 1
    assert table.level_of(1.0) == 0 and table.level_of(50.0) == 1


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: force_table([]), r"force table: needs at least one level"),
        (lambda: force_table([(float(k), 1000 + k) for k in range(1, 10)]), r"force table: 9"),
        (lambda: force_table([(1.0, 3500), (1.0, 5000)]), r"force table entry 2: start 1"),
        (lambda: force_table([(5.0, 3500), (2.0, 5000)]), r"force table entry 2: start 2"),
        (lambda: force_table([(1.0, 5000), (10.0, 3500)]), r"force table entry 2: velocity"),
        (lambda: force_table([(1.0, 5000), (10.0, 5000)]), r"force table entry 2: velocity"),
        (lambda: force_table([(math.nan, 3500)]), r"force table entry 1: start"),
        (lambda: force_table([(1.0, 3500), (math.inf, 5000)]), r"force table entry 2: start"),
        (lambda: force_table([(1.0, math.inf)]), r"force table entry 1: velocity"),
        (lambda: force_table([(1.0, math.nan)]), r"force table entry 1: velocity"),
        (lambda: force_table([(1.0, 3500.5)]), r"force table entry 1: velocity must be a whole"),
        (lambda: force_table([(1.0, 3500), (10.0, 9000)]), r"force table entry 2: .*1\.\.8000"),
        (lambda: force_table([(1.0, -3500)]), r"force table entry 1: velocity -3500"),
        (lambda: force_table([(-1.0, 3500)]), r"force table entry 1: start"),
        (
            lambda: force_table(cast(Any, [(1.0, "fast")])),
            r"force table entry 1: velocity .* number",
        ),
        (lambda: force_table([(True, 3500)]), r"force table entry 1: start .* number"),
        (lambda: force_table([(1.0,)]), r"force table entry 1: expected"),
        (lambda: force_table(cast(Any, "1,3500")), r"force table: expected a list"),
        (lambda: force_table(hysteresis_n=-1.0), r"force table: hysteresis"),
        (lambda: force_table(hysteresis_n=math.nan), r"force table: hysteresis"),
        (lambda: force_table(hysteresis_n=10.0), r"force table: hysteresis 10 N .* gap"),
        (lambda: force_table([(0.4, 3500)], hysteresis_n=1.0), r"force table entry 1: start"),
        (lambda: slip_table([(0.0, 1500), (20.0, 5000)]), r"slip table entry 1: .*2000\.\.7400"),
        (lambda: slip_table([(0.0, 2000), (20.0, 8000)]), r"slip table entry 2: .*2000\.\.7400"),
        (lambda: slip_table([(5.0, 2000), (20.0, 5000)]), r"slip table entry 1: must start at 0"),
        (lambda: slip_table(hysteresis_mm_s=15.0), r"slip table: hysteresis 15 mm/s"),
    ],
)
def test_a_bad_table_is_a_config_error_naming_table_and_entry(build, message):
    with pytest.raises(ConfigError, match=message):
        build()


def test_quantizer_enters_a_level_above_the_band_and_leaves_it_below_the_band():
    q = LevelQuantizer(force_table())  # level 2 from 10 N, band 1 N: enter 10.5, leave < 9.5
    assert q.update(5.0) == 1
    assert q.update(10.4) == 1
    assert q.update(10.5) == 2
    assert q.update(9.6) == 2
    assert q.update(9.4) == 1


def test_quantizer_jumps_several_levels_in_one_step_both_ways():
    q = LevelQuantizer(force_table())
    assert q.update(0.0) == 0
    assert q.update(100.0) == 4
    assert q.update(0.2) == 0


def test_quantizer_places_the_first_value_at_its_nominal_level():
    q = LevelQuantizer(slip_table())
    assert q.level is None
    assert q.update(15.0) == 2  # no history: the nominal boundary, not the band edge
    q.reset()
    assert q.level is None


def test_tables_know_their_belt():
    assert force_table().belt == Belt.FORCE
    assert slip_table().belt == Belt.SLIP
