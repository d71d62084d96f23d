"""Sans-IO controllers a scene can name, built by name where the layers meet.

A scene says `[controller] type = "scripted"` (the default) with the
controller's options beside it; the simulators never import a controller,
the caller builds it here and hands it to the engine. Modules are imported
on first use, so a controller whose module is missing fails only when asked
for, naming it. A controller class offers
`from_scene(options: Params, nodes: Mapping[str, Mapping[str, Any]])` — the
scene's nodes by kind with `node_id` and their settings (`layout`,
`sample_rate_hz`, ...) — and reads (and finishes) its options, so a
misspelt option is an error naming the key.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from grasplink.core.protocol import SansIoDevice
from grasplink.core.registry import load_class
from grasplink.errors import ConfigError

if TYPE_CHECKING:
    from grasplink.simulators.engine import Simulation
    from grasplink.simulators.recording import Recorder
    from grasplink.simulators.scene import Scene

#: name -> "module:Class"
CONTROLLERS: dict[str, str] = {
    "scripted": "grasplink.gateway.scripted:ScriptedMaster",
    "gateway": "grasplink.gateway.service:Gateway",
}


def controller_class(name: str) -> Any:
    """The class registered under `name` (imported now); ConfigError if unknown or missing."""
    return load_class("controller", CONTROLLERS, name, also_valid=("none",))


def build_controllers(scene: Scene) -> list[SansIoDevice]:
    """The participants a scene's `[controller]` asks for (none for `type = "none"`)."""
    spec = scene.controller
    if spec.name is None:
        if spec.options:
            raise spec.params().error(next(iter(spec.options)), 'no options with type = "none"')
        return []
    try:
        cls = controller_class(spec.name)
    except ConfigError as exc:
        raise spec.params().error("type", str(exc)) from None
    return [cls.from_scene(spec.params(), scene.node_settings())]


def simulation(scene: Scene, recorder: Recorder | None = None, **options: Any) -> Simulation:
    """A ready `Simulation` of `scene` with the controllers its `[controller]` names."""
    from grasplink.simulators.engine import Simulation

    return Simulation(scene, recorder, controllers=build_controllers(scene), **options)
