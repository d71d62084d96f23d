"""Hand (grip actuator) node: a CiA 402 drive whose target is grip force.

The grip-force loop slews the actual force towards the target at the
configured rate, never above the crush limit or the maximum force (a
limited target sets statusword bit 11). When the master is lost the hand
holds the grip it has: dropping an object is worse than keeping it.
"""

from __future__ import annotations

from grasplink.core.nmt import NmtState
from grasplink.devices.drive import DriveApp
from grasplink.profiles import objects as obj


class HandApp(DriveApp):
    supported_mode = obj.MODE_GRIP_FORCE
    inputs = (
        *DriveApp.inputs,
        obj.HAND_TARGET_GRIP_MN,
        obj.HAND_CRUSH_LIMIT_MN,
        obj.HAND_GRIP_RATE_MN_S,
    )

    def __init__(self, *, external_actuator: bool = False, initial_grip_mn: float = 0.0) -> None:
        """`external_actuator`: the actual grip is measured (`measure_grip`), as from a real
        force sensor or an actuator simulator; `initial_grip_mn`: the grip the hand boots
        holding (an object already in the hand).
        """
        super().__init__()
        self.setpoint_mn = 0.0  # the rate-limited grip command
        self._demand = 0.0
        self.grip_mn = initial_grip_mn  # actual grip force
        self.external_actuator = external_actuator
        self.holding = False

    def measure_grip(self, grip_mn: float) -> None:
        """The external actuator's actual grip: publish it."""
        self.grip_mn = grip_mn
        self.publish_actual()

    def on_reset(self, t_us: int) -> None:
        # A reset does not open the hand: an external (real) actuator keeps its grip
        # and the drive holds it until commanded otherwise.
        if self.external_actuator:
            self.setpoint_mn = self.grip_mn
        else:
            self.setpoint_mn = self.grip_mn = 0.0
        self.holding = False
        super().on_reset(t_us)
        self.store.set(obj.HAND_ACTUAL_GRIP_MN, 0, round(self.grip_mn))  # what it holds

    def on_state(self, state: NmtState, t_us: int) -> None:
        if state == NmtState.OPERATIONAL:
            self.holding = False  # the master is back and restarted us
        super().on_state(state, t_us)

    def enter_safe_state(self, t_us: int, reason: str) -> None:
        self.holding = True  # keep the drive enabled and the grip where it is
        self._publish_status()

    def demand_mn(self) -> float:
        if self.holding or not self.enabled:
            self.internal_limit = False
            self.setpoint_mn = self.grip_mn  # hold what the hand has, resume from there
            return self.grip_mn
        target = int(self.store.get(obj.HAND_TARGET_GRIP_MN))
        ceiling = min(
            int(self.store.get(obj.HAND_CRUSH_LIMIT_MN)), int(self.store.get(obj.HAND_MAX_GRIP_MN))
        )
        self.internal_limit = target > ceiling
        return float(min(target, ceiling))

    def control(self, dt_s: float) -> None:
        """Slew the grip setpoint; without an actuator simulator the grip follows it exactly."""
        demand = self.demand_mn()
        self._demand = demand
        step = int(self.store.get(obj.HAND_GRIP_RATE_MN_S)) * dt_s
        self.setpoint_mn += max(-step, min(step, demand - self.setpoint_mn))
        if not self.external_actuator:
            self.grip_mn = self.setpoint_mn

    def report(self) -> None:
        self.target_reached = abs(self._demand - self.grip_mn) < 1.0
        self.store.set(obj.HAND_ACTUAL_GRIP_MN, 0, round(self.grip_mn))
        self._publish_status()

    def settled(self) -> bool:
        return self.setpoint_mn == self._demand and (
            self.external_actuator or self.grip_mn == self.setpoint_mn
        )
