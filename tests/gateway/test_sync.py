"""The gateway's SYNC producer, and a device's TPDO made synchronous by the description."""

from __future__ import annotations

import itertools
import re
import shutil

import pytest

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.core.frames import SYNC_COB_ID_DEFAULT, TPDO_BASES
from grasplink.core.nmt import NmtState
from grasplink.errors import ConfigError
from grasplink.gateway.config import parse_config
from grasplink.gateway.sync import SyncProducer
from grasplink.profiles import eds_path
from tests.gateway.test_bus_description import gateway_for, gripper


def test_sync_keeps_its_grid_and_skips_missed_periods_instead_of_bursting():
    sync = SyncProducer(10_000)
    sync.start(0)
    assert sync.advance(9_999) == []
    assert [f.can_id for f in sync.advance(10_000)] == [SYNC_COB_ID_DEFAULT]
    assert sync.advance(10_001) == []
    assert len(sync.advance(55_000)) == 1  # a stalled host: one SYNC, not four
    assert sync.next_deadline_us() == 60_000


def test_the_sync_counter_runs_1_to_its_overflow():
    sync = SyncProducer(1_000, counter_overflow=3)
    sync.start(0)
    counters = [sync.advance(t)[0].data[0] for t in range(1_000, 8_000, 1_000)]
    assert counters == [1, 2, 3, 1, 2, 3, 1]


@pytest.mark.parametrize(
    ("gateway", "needle"),
    [
        ({"sync_period_ms": 0.5}, "gateway.sync_period_ms: expected 0 (no SYNC) or 1..1000 ms"),
        ({"sync_period_ms": 2000}, "gateway.sync_period_ms: expected a number <= 1000"),
        ({"sync_counter_overflow": 1}, "gateway.sync_counter_overflow: expected 0"),
    ],
)
def test_a_bad_sync_setting_names_its_key(gateway, needle):
    with pytest.raises(ConfigError, match=re.escape(needle)):
        parse_config({"gateway": gateway}, "gw.toml")


def test_a_tpdo_made_synchronous_by_the_description_answers_every_sync(tmp_path):
    """The device's TPDO1 set to transmission type 1 in `[sdo]`: after the start, exactly
    one of its frames follows each SYNC."""
    vendor = tmp_path / "vendor" / "gripper.eds"
    vendor.parent.mkdir()
    shutil.copy(eds_path("hand"), vendor)
    gw = gateway_for(
        tmp_path,
        "[gateway]\nsync_period_ms = 10\n[nodes.gripper]\nnode_id = 0x30\n"
        'eds = "vendor/gripper.eds"\n[nodes.gripper.sdo]\n"1800sub2" = 1\n',
    )
    device = gripper(vendor)
    network = LockstepNetwork([gw, device])
    seen: list[tuple[int, int]] = []
    network.taps.append(lambda t_us, frame, sender: seen.append((t_us, frame.can_id)))
    network.start()
    network.run_until(1_000_000)
    assert device.state is NmtState.OPERATIONAL
    syncs = [t for t, can_id in seen if can_id == SYNC_COB_ID_DEFAULT]
    assert 99 <= len(syncs) <= 100
    tpdo1 = TPDO_BASES[0] + 0x30
    started = next(t for t, can_id in seen if can_id == tpdo1)
    cycles = [t for t in syncs if t >= started]
    per_cycle = [
        sum(1 for t, c in seen if c == tpdo1 and start <= t < end)
        for start, end in itertools.pairwise(cycles)
    ]
    assert len(per_cycle) > 50 and set(per_cycle) == {1}
