"""The surfaces digest: one short hash of everything the gateway's surfaces say about a
fixed virtual-time run, to tell whether a change left them byte for byte as they were.

    .venv/bin/python benchmarks/check_surfaces_unchanged.py [TREE] [--seconds S]

TREE is a checkout (default: this one; e.g. `git worktree add /tmp/base REV`), run in its
own interpreter. The run: scenes/loop_headline.toml (gateway, skin, EMG, belt, hand, the
slip the reflex stops) in lock-step virtual time, with what else a gateway meets on the
way: EMCYs from the belt at 1.5 and 1.75 s (reset at 2.5 s), the feedback mode changed at
2 s, a restart of the hand at 3 s (provisioning, starting, back to operational), the
hand's power lost at 4 s and back at 4.8 s (lost, then provisioned again).
Every 50 ms the gateway's snapshot goes through every surface, and the digest covers:

- the JSON tree's messages (topic, payload, QoS, retain), from its first connection on;
- the Sparkplug session's messages as sent (topic and payload after `finalize`, so the
  metrics' names, aliases, types, values and `seq`), births first;
- the Modbus input and holding register images;
- whether telemetry would skip the snapshot as nothing new (`same_report`);
- the gateway's status line.

The gateway's loop latency is the one value measured on the wall clock: it is set to a
fixed sequence before each snapshot (the same in every tree), so its encoding is covered
and the digest does not depend on the machine's speed. Wall-clock times in the messages
are the snapshot's virtual time plus a fixed epoch. Prints the digest (the first 16 hex
digits of SHA-256) and what it covers; two trees agree when their digests are equal.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from tree_script import last_json, run_in_tree

# Run inside TREE's interpreter: only names both sides of a change have (the snapshot
# may be a dict or a typed object; every surface takes what that tree's gateway makes).
COLLECT = r'''
import hashlib, json, sys, tomllib
from pathlib import Path

from grasplink.controllers import simulation
from grasplink.core.frames import EMCY_BASE, Frame
from grasplink.gateway.commands import Command
from grasplink.gateway.live import status_of
from grasplink.simulators.scene import parse_scene
from grasplink.surfaces.modbus.registers import register_map, settings_of
from grasplink.surfaces.telemetry.buffer import Sample
from grasplink.surfaces.telemetry.json_tree import JsonTree
from grasplink.surfaces.telemetry.protocol import same_report
from grasplink.surfaces.telemetry.sparkplug import SparkplugSession

tree, seconds = Path(sys.argv[1]), float(sys.argv[2])
EPOCH_MS = 1_700_000_000_000
TICK_US = 50_000
COMMANDS = {
    2_000_000: Command("feedback_mode", "slip_speed"),
    3_000_000: Command("restart_node", "hand"),
}
EMCY = {
    1_500_000: bytes([0x30, 0x81, 0x11, 0, 0, 0, 0, 0]),  # 8130h: a heartbeat it watches
    1_750_000: bytes([0xAB, 0x50, 0x01, 0, 0, 0, 0, 0]),  # 50ABh: not a code it declares
    2_500_000: bytes(8),  # error reset
}
EXTRA = {
    "controls": {"reflex_enabled": True, "reflex_threshold_mm_s": 30.0,
                 "emg_e_min_uv": 20.0, "emg_e_max_uv": 400.0},
    "telemetry": {"snapshots_dropped": 0, "buffer_dropped_messages": 0},
}

rmap = register_map()
tree_proto, session = JsonTree("gw"), SparkplugSession("group", "gw")
digest = hashlib.sha256()
counts = {"snapshots": 0, "json": 0, "sparkplug": 0, "skipped": 0}


def add(label, data):
    digest.update(label.encode() + b"\0" + data + b"\0")


class WithCommands:
    """The gateway on the network, executing commands handed to it at its next advance."""

    def __init__(self, gateway):
        self.gateway, self.node_id, self.pending = gateway, gateway.node_id, []

    def start(self, t_us):
        return self.gateway.start(t_us)

    def receive(self, frame, t_us):
        return self.gateway.receive(frame, t_us)

    def advance(self, t_us):
        frames = []
        for command in self.pending:
            result, sent = self.gateway.execute(command, t_us)
            add("command", repr(result).encode())
            frames += sent
        self.pending = []
        return frames + self.gateway.advance(t_us)

    def next_deadline_us(self):
        due = self.gateway.next_deadline_us()
        if self.pending:
            return self.gateway.now_us if due is None else min(due, self.gateway.now_us)
        return due


text = (tree / "scenes" / "loop_headline.toml").read_text() + """
[[effects]]
type = "bus.faults"
power_loss = [{ node = "hand", at_s = 4.0, restore_s = 4.8 }]
"""
sim = simulation(parse_scene(tomllib.loads(text), "loop_headline.toml"))
gateway = sim.controllers[0]
commander = WithCommands(gateway)
sim.network.devices[sim.network.devices.index(gateway)] = commander
sim.network.start()


def sent(messages, finalize):
    out = []
    for message in messages:
        message = finalize(message) if finalize else message
        if message is not None:
            out.append(message)
    return out


previous = None
t_us = 0
end_us = round(seconds * 1e6)
connected = False
while t_us < end_us:
    t_us += TICK_US
    sim.step(t_us)
    if t_us in COMMANDS:
        commander.pending.append(COMMANDS[t_us])
    if t_us in EMCY:  # from the belt
        belt = gateway.by_kind["belt"].node_id
        sim.network.inject(Frame(EMCY_BASE + belt, EMCY[t_us]))
    tick = t_us // TICK_US
    gateway.loop_latency_us.clear()
    latencies = (float(50 + (tick * 7 + k * 13) % 400) for k in range(1 + tick % 5))
    gateway.loop_latency_us.extend(latencies)
    snap = gateway.snapshot()
    gateway.latest = snap
    counts["snapshots"] += 1
    ts_ms = EPOCH_MS + t_us // 1000
    sample = Sample(ts_ms, snap)
    if not connected:
        session.prime(sample, EXTRA)
        session.will(ts_ms)
        first, after = tree_proto.on_connect(ts_ms)
        births, _ = session.on_connect(ts_ms)
        for m in first + after:
            add("json", m.topic.encode() + m.payload + bytes([m.qos, m.retain]))
        for m in sent(births, session.finalize):
            add("sparkplug", m.topic.encode() + m.payload)
        connected = True
    skip = previous is not None and same_report(previous, snap)
    counts["skipped"] += skip
    add("same_report", b"1" if skip else b"0")
    previous = snap
    for m in tree_proto.update([sample], EXTRA):
        counts["json"] += 1
        add("json", m.topic.encode() + m.payload + bytes([m.qos, m.retain]))
    for m in sent(session.update([sample], EXTRA), session.finalize):
        counts["sparkplug"] += 1
        add("sparkplug", m.topic.encode() + m.payload)
    inputs = rmap.encode_inputs(snap)
    holding = rmap.encode_holding(settings_of(gateway))
    add("modbus", json.dumps([inputs, holding]).encode())
    add("status", status_of(gateway).encode())
print(json.dumps({"digest": digest.hexdigest()[:16], **counts}))
'''


def collect(tree: Path, seconds: float) -> dict[str, object]:
    """Run the scenario in `tree`'s own interpreter; its digest and counts."""
    out = run_in_tree(tree, COLLECT, str(tree), str(seconds), what="the scenario")
    return last_json(out)  # type: ignore[no-any-return]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tree", type=Path, nargs="?", default=Path(__file__).resolve().parents[1])
    parser.add_argument("--seconds", type=float, default=6.0, help="virtual time to run")
    args = parser.parse_args()
    result = collect(args.tree.resolve(), args.seconds)
    print(
        f"surfaces {result['digest']} ({result['snapshots']} snapshots: "
        f"{result['json']} JSON messages, {result['sparkplug']} Sparkplug messages, "
        f"{result['skipped']} skippable; Modbus images and status lines)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
