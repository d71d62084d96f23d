"""The loop picture's decoded slip is the gateway's own (`loop_plot.replay_skin`)."""

from __future__ import annotations

from pathlib import Path

from grasplink.controllers import build_controllers
from grasplink.evaluation.loop_plot import replay_skin
from grasplink.simulators.engine import Simulation
from grasplink.simulators.recording import Recorder
from grasplink.simulators.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]


def test_replayed_skin_updates_are_the_ones_the_live_gateway_acted_on(tmp_path):
    """The headline loop raises the grip while the object slips: the live decoder was told
    those commands (its efference copy), so the replay must tell them too, or it decodes
    a different slip from the same frames."""
    scene = load_scene(ROOT / "scenes" / "loop_headline.toml")
    controllers = list(build_controllers(scene))
    (gateway,) = [c for c in controllers if hasattr(c, "estimate_listeners")]
    live = []
    gateway.estimate_listeners.append(lambda t_us, e: live.append(e.as_dict()))
    Simulation(scene, Recorder(tmp_path), controllers=controllers).run()
    nodes = {"node_id": scene.nodes["skin"].node_id}
    replayed = replay_skin(
        tmp_path / "can.asc",
        nodes,
        "alpha0.1",
        {"node_id": scene.nodes["hand"].node_id},
    )
    assert len(live) > 100
    assert [e.as_dict() for e in replayed] == live
