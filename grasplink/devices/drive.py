"""What the belt and hand share: a CiA 402 drive fed by an RPDO, ticking on its own clock.

The drive function (velocity ramp, grip-force loop) runs at a fixed control
rate; subclasses implement `control(dt_s)` (move the setpoint) and `report()`
(publish the actual value). Once the setpoint has settled the loop sleeps
until an input changes (RPDO, SDO write, NMT, safe state): a settled loop
would compute the same thing again, and virtual time should not pay for it.
When a simulator owns the actual value it calls `report()` after changing it.
Statusword changes publish through TPDOs of type 255.
"""

from __future__ import annotations

from grasplink.core.frames import Frame
from grasplink.core.nmt import NmtState
from grasplink.devices.app import AppServices, DeviceApp
from grasplink.devices.cia402 import DriveState, DriveStateMachine
from grasplink.devices.sampling import US_PER_S
from grasplink.devices.sdo_abort import AbortCode, SdoAbort
from grasplink.devices.store import Value
from grasplink.profiles import objects as obj

CONTROL_PERIOD_US = 5_000  # 200 Hz drive loop


class DriveApp(DeviceApp):
    supported_mode: int = 0
    # Objects whose change alters the demand and so wakes a sleeping loop.
    inputs: tuple[int, ...] = (obj.CONTROLWORD, obj.MODES_OF_OPERATION, obj.QUICK_STOP_OPTION)

    def __init__(self) -> None:
        self.drive = DriveStateMachine()
        self.internal_limit = False
        self.target_reached = True
        self._next_tick_us: int | None = 0
        self._last_tick_us = 0

    def attach(self, services: AppServices) -> None:
        super().attach(services)
        self.store.add_validator(obj.MODES_OF_OPERATION, self._validate_mode)
        self.store.add_listener(self._on_change, self.inputs)

    def _validate_mode(self, index: int, subindex: int, value: Value) -> None:
        mode = int(value)
        if mode != self.supported_mode:
            raise SdoAbort(
                AbortCode.INVALID_VALUE, f"mode {mode} not supported (only {self.supported_mode})"
            )

    @property
    def quick_stop_option(self) -> int:
        return int(self.store.get(obj.QUICK_STOP_OPTION))

    def _on_change(self, index: int, subindex: int, value: Value) -> None:
        if index == obj.CONTROLWORD:
            self.drive.apply(int(value), self.quick_stop_option)
            self._publish_status()
        elif index == obj.MODES_OF_OPERATION:
            self.store.set(obj.MODES_OF_OPERATION_DISPLAY, 0, int(value))
        self.wake(self.services.now_us())

    def on_rpdo(self, number: int, t_us: int) -> None:
        # Re-apply the controlword even when unchanged: a repeated command is a command.
        self.drive.apply(int(self.store.get(obj.CONTROLWORD)), self.quick_stop_option)
        self._publish_status()
        self.wake(t_us)

    def on_reset(self, t_us: int) -> None:
        self.drive.reset()
        self._next_tick_us = self._last_tick_us = t_us
        self.store.set(
            obj.MODES_OF_OPERATION_DISPLAY, 0, int(self.store.get(obj.MODES_OF_OPERATION))
        )
        self._publish_status()

    def enter_safe_state(self, t_us: int, reason: str) -> None:
        self.drive.quick_stop()
        self._publish_status()
        self.wake(t_us)

    def wake(self, t_us: int) -> None:
        """Resume the control loop (one period's step first: no catch-up after a sleep)."""
        if self._next_tick_us is None:
            self._next_tick_us = t_us
            self._last_tick_us = t_us - CONTROL_PERIOD_US

    def advance(self, t_us: int) -> list[Frame]:
        while self._next_tick_us is not None and self._next_tick_us <= t_us:
            dt_s = (self._next_tick_us - self._last_tick_us) / US_PER_S
            self._last_tick_us = self._next_tick_us
            self.control(dt_s)
            self.report()
            self._next_tick_us += CONTROL_PERIOD_US
            if self.settled():
                self._next_tick_us = None
        return []

    def next_deadline_us(self) -> int | None:
        return self._next_tick_us

    def publish_actual(self) -> None:
        """A simulator changed the actual value: publish it (this never wakes the loop)."""
        self.report()

    def control(self, dt_s: float) -> None:
        """Move the setpoint one control period towards the demand."""
        raise NotImplementedError

    def report(self) -> None:
        """Publish the actual value, target-reached and the statusword."""
        raise NotImplementedError

    def settled(self) -> bool:
        """True when another tick would change nothing."""
        raise NotImplementedError

    @property
    def enabled(self) -> bool:
        return self.drive.state == DriveState.OPERATION_ENABLED

    def _publish_status(self) -> None:
        word = self.drive.statusword(
            target_reached=self.target_reached, internal_limit=self.internal_limit
        )
        self.store.set(obj.STATUSWORD, 0, word)

    def on_state(self, state: NmtState, t_us: int) -> None:
        self._publish_status()
        self.wake(t_us)
