"""A live gateway process masters several buses from one thread."""

from __future__ import annotations

import uuid

import pytest

from grasplink.bus import MultiRunner
from grasplink.errors import BusError
from grasplink.gateway.config import parse_config
from grasplink.gateway.live import LiveGateway
from tests.live import operational, wait_until


@pytest.mark.slow
def test_one_gateway_process_masters_three_buses_from_one_thread() -> None:
    urls = [f"virtual:live-{uuid.uuid4().hex[:12]}" for _ in range(3)]
    config = parse_config({}, "<test>")
    with LiveGateway(urls[0], config, with_nodes=True, more_buses=urls[1:]) as live:
        assert len(live.gateways) == 3 and live.gateway is live.gateways[0]
        assert any(isinstance(r, MultiRunner) and len(r.runners) == 3 for r in live._runners)
        wait_until(lambda: all(map(operational, live.gateways)), 20.0, "every node on every bus")
        lines = live.status_line().splitlines()
        assert [line.split("]")[0] for line in lines] == [f"[{u}" for u in urls]
        assert all("skin:operational" in line for line in lines)
        assert live.failure is None


def test_a_started_gateway_keeps_what_it_built_out_of_the_collectors_generations() -> None:
    import gc

    gc.unfreeze()
    url = f"virtual:live-gc-{uuid.uuid4().hex[:12]}"
    with LiveGateway(url, parse_config({}, "<test>")):
        # its object dictionaries and decoder tables are frozen: full collections in the
        # loop do not scan them
        assert gc.get_freeze_count() > 10_000


def test_a_bus_named_twice_is_refused_before_any_bus_opens() -> None:
    with pytest.raises(BusError, match="named twice"):
        LiveGateway("virtual:a", parse_config({}, "<test>"), more_buses=["virtual:a"])


@pytest.mark.slow
def test_gateway_command_takes_several_buses(capsys) -> None:
    from grasplink import cli

    urls = [f"virtual:cli-multi-{uuid.uuid4().hex[:12]}" for _ in range(2)]
    args = ["gateway", "--with-nodes", "--duration", "2"]
    assert cli.main([*args, "--bus", urls[0], "--bus", urls[1]]) == 0
    out = capsys.readouterr().out
    assert f"on {urls[0]}, {urls[1]} (" in out
    stopped = out[out.index("stopped: ") :]
    assert f"[{urls[0]}]" in stopped and f"[{urls[1]}]" in stopped


@pytest.mark.slow
def test_with_nodes_runs_a_vendors_device_from_its_file_beside_ours() -> None:
    """`grasplink gateway --with-nodes` and a described device: the stand-in is built from
    the device's own file (protocol only), and the gateway masters it live."""
    from pathlib import Path

    field = Path(__file__).resolve().parents[1] / "profiles" / "field"
    data = {"nodes": {"io": {"node_id": 0x35, "eds": str(field / "canopendemo_demoDevice.eds")}}}
    config = parse_config(data, "<test>")
    with LiveGateway(f"virtual:live-{uuid.uuid4().hex[:12]}", config, with_nodes=True) as live:
        wait_until(lambda: operational(live.gateway), 30.0, "our four nodes and the device")
        assert set(live.gateway.latest.nodes) == {"skin", "emg", "belt", "hand", "io"}
        assert live.failure is None


def test_the_status_line_says_what_a_gateway_behind_its_bus_skipped() -> None:
    from collections import Counter

    from grasplink.bus import RunnerStats
    from grasplink.gateway.live import behind_text

    assert behind_text(RunnerStats()) == ""  # kept up: nothing to say
    stats = RunnerStats(
        superseded=7, catch_ups=2, superseded_by_cob_id=Counter({0x191: 5, 0x2A1: 2})
    )
    assert behind_text(stats) == (
        " | behind the bus: 7 PDOs superseded in 2 catch-ups (most 0x191: 5)"
    )
