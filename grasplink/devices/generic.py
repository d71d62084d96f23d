"""A vendor's CiA 402 drive from its file: the device state machine and a plain drive.

A node built from any EDS (`factory.build_from_file`) whose file has a controlword
(6040h) and a statusword (6041h) runs the CiA 402 state machine our belt and hand
share, and moves each actual value its file has towards its target while operation
is enabled: torque (6071h -> 6077h), velocity (60FFh -> 606Ch), position (607Ah ->
6064h), a first-order lag of `TIME_CONSTANT_S`. That is enough for a master to bring
it up, command it and read it back; it models no motor. Objects CiA 402 makes
optional (quick stop option 605Ah, modes 6060h/6061h) are used where the file has
them; any mode of operation is accepted (the lag does not depend on it). An actual
value a simulation measures (`measured`: a scene's actuator drives the grip) is set by
`measure` instead of the lag, as a real drive reads its sensor.
"""

from __future__ import annotations

import math

import canopen

from grasplink.devices.drive import DriveApp
from grasplink.devices.store import Value
from grasplink.profiles import objects as obj
from grasplink.profiles import variable_limits

#: (target, actual) pairs a drive may have, CiA 402
TARGET_ACTUAL = ((0x6071, 0x6077), (0x60FF, 0x606C), (0x607A, 0x6064))
TIME_CONSTANT_S = 0.05
QUICK_STOP_DEFAULT = 2  # CiA 402: slow down on the quick-stop ramp, then switch on disabled


def is_drive(od: canopen.ObjectDictionary) -> bool:
    return obj.CONTROLWORD in od and obj.STATUSWORD in od


class GenericDriveApp(DriveApp):
    """See module docstring."""

    def __init__(
        self, od: canopen.ObjectDictionary, measured: frozenset[int] = frozenset()
    ) -> None:
        super().__init__()
        self.measured = measured
        self.pairs = tuple((t, a) for t, a in TARGET_ACTUAL if t in od and a in od)
        self.inputs = (
            *(i for i in DriveApp.inputs if i in od),
            *(target for target, _ in self.pairs),
        )
        self.actual: dict[int, float] = {}

    def measure(self, index: int, value: float) -> None:
        """The actual value `index` as measured (a `measured` one), held at its object's
        range as the drive's own reading would be."""
        low, high = variable_limits(self.store.entry(index).var)
        self.actual[index] = min(max(value, low), high)

    def _validate_mode(self, index: int, subindex: int, value: Value) -> None:
        """Any mode: the lag is the same in each (see module docstring)."""

    @property
    def quick_stop_option(self) -> int:
        if not self.store.has(obj.QUICK_STOP_OPTION):
            return QUICK_STOP_DEFAULT
        return int(self.store.get(obj.QUICK_STOP_OPTION))

    def on_reset(self, t_us: int) -> None:
        self.drive.reset()
        self.actual = {a: float(self.store.get(a)) for _, a in self.pairs}
        if self.store.has(obj.MODES_OF_OPERATION) and self.store.has(
            obj.MODES_OF_OPERATION_DISPLAY
        ):
            mode = int(self.store.get(obj.MODES_OF_OPERATION))
            self.store.set(obj.MODES_OF_OPERATION_DISPLAY, 0, mode)
        self.wake(t_us)
        self._publish_status()

    def _on_change(self, index: int, subindex: int, value: Value) -> None:
        if index == obj.MODES_OF_OPERATION and not self.store.has(obj.MODES_OF_OPERATION_DISPLAY):
            self.wake(self.services.now_us())
            return
        super()._on_change(index, subindex, value)

    def control(self, dt_s: float) -> None:
        if not self.enabled:
            return
        step = 1.0 - math.exp(-dt_s / TIME_CONSTANT_S)
        for target, actual in self.pairs:
            if actual in self.measured:
                continue
            goal = float(self.store.get(target))
            now = self.actual.get(actual, 0.0)
            self.actual[actual] = goal if abs(goal - now) < 0.5 else now + (goal - now) * step

    def report(self) -> None:
        reached = True
        for target, actual in self.pairs:
            value = self.actual.get(actual, 0.0)
            reached &= abs(float(self.store.get(target)) - value) < 0.5
            entry = self.store.entry(actual)
            integer = entry.var.data_type in canopen.objectdictionary.datatypes.INTEGER_TYPES
            self.store.set(actual, 0, round(value) if integer else value)
        self.target_reached = reached
        self._publish_status()

    def settled(self) -> bool:
        return not self.enabled or self.target_reached
