"""Shipped scenes through the skin node and the bus, read back as the gateway reads them.

`record_scene` runs a scene in the simulation engine with its nodes and its
controller (exactly as `grasplink run` does) into a folder, then reads the
skin signal twice:

- *CAN*: the skin node's TPDO1 frames from `can.asc`, through the gateway's
  CAN-log reader (`decoding.io.read_can_log` and its usability
  check, what `grasplink decode R/can.asc --skin LAYOUT` reads): quantised
  by the node's 12-bit ADC, three samples per PDO, stamped with the node's
  own timing;
- *CSV*: the float signal the node sampled, from `skin.csv` through the same
  module's CSV reader (what `grasplink decode R/skin.csv` reads).

Each comes with the ground truth at its own sample times (object position,
speed and slip state from `truth.csv`, slip state as a step) and the ridge
contacts the scene's `skin.ridge_contacts` effect made (tips excluded), so
`scoring.score` judges both the same way it judges synthesised signals.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from grasplink.core.protocol import SansIoDevice
from grasplink.decoding.io import CanStats, read_can_log, read_csv
from grasplink.errors import RecordingError
from grasplink.simulators import signals as sig
from grasplink.simulators.effects.skin import RidgeContacts
from grasplink.simulators.engine import Simulation
from grasplink.simulators.recording import DOMAIN_FILES, Recorder
from grasplink.simulators.scene import Scene, load_scene
from grasplink.simulators.synth import SkinRecording

#: Builds the sans-IO participants a scene's `[controller]` names (grasplink.controllers).
ControllerFactory = Callable[[Scene], Sequence[SansIoDevice]]


@dataclass
class SceneSignals:
    """One scene's skin signal as it went over CAN and as the node sampled it, with truth."""

    name: str  # the scene file's stem
    layout_mm: tuple[float, ...]
    can: SkinRecording
    csv: SkinRecording
    can_stats: CanStats


def skin_layout(scene: Scene) -> tuple[float, ...] | None:
    """The scene's skin layout, or None when it has no skin node to decode."""
    return scene.layout_mm if "skin" in scene.nodes else None


def record_scene(
    path: str | Path, controllers_for: ControllerFactory, out_dir: str | Path
) -> SceneSignals:
    """Run the scene into `out_dir` and read its skin signal back (CAN and CSV) with truth."""
    scene = load_scene(path)
    layout = skin_layout(scene)
    if layout is None:
        raise RecordingError(f"{path}: the scene has no skin node; nothing to decode")
    out = Path(out_dir)
    sim = Simulation(scene, Recorder(out), controllers=controllers_for(scene))
    sim.run()
    contacts = np.array(
        [
            c.time_s
            for effect in scene.effects
            if isinstance(effect, RidgeContacts)
            for c in effect.contacts
            if not c.tip
        ]
    )
    truth = read_columns(
        out / DOMAIN_FILES["physics"],
        (sig.OBJECT_POSITION_MM, sig.OBJECT_SPEED_MM_S, sig.OBJECT_SLIPPING),
    )
    spec = scene.nodes["skin"]
    log = out / "can.asc"
    t_can, f_can, stats = read_can_log(log, node_id=spec.node_id, fs_hz=spec.sample_rate_hz)
    stats.check_usable(str(log))
    t_csv, f_csv = read_csv(out / DOMAIN_FILES["skin"])
    return SceneSignals(
        name=Path(path).stem,
        layout_mm=layout,
        can=with_truth(t_can, f_can, truth, contacts, layout, stats.rate_hz),
        csv=with_truth(t_csv, f_csv, truth, contacts, layout, scene.rate_hz("skin")),
        can_stats=stats,
    )


def read_columns(path: Path, names: Sequence[str]) -> dict[str, np.ndarray]:
    """`t_s` and the named columns of a recording's CSV (header line, then numbers)."""
    try:
        with path.open() as handle:
            header = handle.readline().strip().split(",")
        table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError) as exc:
        raise RecordingError(f"{path}: cannot read ({exc})") from None
    missing = [n for n in ("t_s", *names) if n not in header]
    if missing:
        raise RecordingError(f"{path}: no column(s) {', '.join(missing)}")
    return {n: table[:, header.index(n)] for n in ("t_s", *names)}


def with_truth(
    t_s: np.ndarray,
    force_n: np.ndarray,
    truth: dict[str, np.ndarray],
    contacts_s: np.ndarray,
    layout_mm: tuple[float, ...],
    fs_hz: float,
) -> SkinRecording:
    """A signal with the truth at its own sample times (slip state held, not interpolated)."""
    t_truth = truth["t_s"]
    held = np.clip(np.searchsorted(t_truth, t_s, side="right") - 1, 0, len(t_truth) - 1)
    return SkinRecording(
        t_s=np.asarray(t_s, dtype=np.float64),
        force_n=np.asarray(force_n, dtype=np.float64),
        position_mm=np.interp(t_s, t_truth, truth[sig.OBJECT_POSITION_MM]),
        speed_mm_s=np.interp(t_s, t_truth, truth[sig.OBJECT_SPEED_MM_S]),
        slipping=truth[sig.OBJECT_SLIPPING][held],
        grip_n=np.full(len(t_s), np.nan),  # not needed to score slip decoding
        contact_times_s=contacts_s,
        layout_mm=layout_mm,
        fs_hz=round(fs_hz),
    )
