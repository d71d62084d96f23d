"""Haptic belt node: one motor, two belts, chosen by the sign of the velocity.

Positive velocity turns the force belt (grip force as tap frequency, at
most 8 rad/s); negative turns the slip belt (slip speed as belt surface
speed, 2.0-7.4 rad/s). A tooth washer and ratchet make the two mutually
exclusive, so a sign change always passes through standstill. Targets out
of range are limited and flagged with statusword bit 11 (internal limit).
"""

from __future__ import annotations

import math

from grasplink.devices.cia402 import DriveState
from grasplink.devices.drive import DriveApp
from grasplink.profiles import objects as obj

ACTIVE_NONE, ACTIVE_FORCE, ACTIVE_SLIP = 0, 1, 2
MHZ_PER_HZ = 1000
STANDSTILL_MRAD_S = 1.0
UM_PER_MM = 1000


def limit_belt_velocity(target_mrad_s: int, max_mrad_s: int) -> tuple[int, bool]:
    """The velocity the belt can display for a target, and whether it was limited."""
    if target_mrad_s > 0:
        limited = min(target_mrad_s, obj.FORCE_BELT_MAX_MRAD_S, max_mrad_s)
    elif target_mrad_s < 0:
        magnitude = min(-target_mrad_s, obj.SLIP_BELT_MAX_MRAD_S, max_mrad_s)
        limited = -max(magnitude, obj.SLIP_BELT_MIN_MRAD_S)
    else:
        limited = 0
    return limited, limited != target_mrad_s


class BeltApp(DriveApp):
    supported_mode = obj.MODE_PROFILE_VELOCITY
    inputs = (
        *DriveApp.inputs,
        obj.BELT_TARGET_VELOCITY_MRAD_S,
        obj.BELT_MAX_PROFILE_VELOCITY_MRAD_S,
        obj.BELT_PROFILE_ACCELERATION,
        obj.BELT_PROFILE_DECELERATION,
        obj.BELT_QUICK_STOP_DECELERATION,
    )

    def __init__(self, *, external_motor: bool = False) -> None:
        """`external_motor`: the actual velocity is measured (`measure_velocity`), as from a
        real motor's encoder or a motor simulator; otherwise the motor follows the ramp exactly.
        """
        super().__init__()
        self.setpoint_mrad_s = 0.0  # the profile ramp's output: what the motor is asked for
        self._demand = 0.0
        self.velocity_mrad_s = 0.0  # actual motor velocity
        self.external_motor = external_motor

    def measure_velocity(self, velocity_mrad_s: float) -> None:
        """The external motor's actual velocity: publish it."""
        self.velocity_mrad_s = velocity_mrad_s
        self.publish_actual()

    def on_reset(self, t_us: int) -> None:
        self.setpoint_mrad_s = 0.0
        if not self.external_motor:
            self.velocity_mrad_s = 0.0
        super().on_reset(t_us)
        self._publish_display()

    def demand_mrad_s(self) -> int:
        """What the drive asks of the motor now, after limits and state."""
        if not self.enabled:
            self.internal_limit = False
            return 0
        target = int(self.store.get(obj.BELT_TARGET_VELOCITY_MRAD_S))
        limited, self.internal_limit = limit_belt_velocity(
            target, int(self.store.get(obj.BELT_MAX_PROFILE_VELOCITY_MRAD_S))
        )
        return limited

    def control(self, dt_s: float) -> None:
        """Ramp the velocity setpoint; without a motor simulator the motor follows it exactly."""
        demand = self.demand_mrad_s()
        self._demand = demand
        setpoint = self.setpoint_mrad_s
        if self.drive.state == DriveState.QUICK_STOP_ACTIVE:
            rate = int(self.store.get(obj.BELT_QUICK_STOP_DECELERATION))
        elif abs(demand) > abs(setpoint) and demand * setpoint >= 0:
            rate = int(self.store.get(obj.BELT_PROFILE_ACCELERATION))
        else:
            rate = int(self.store.get(obj.BELT_PROFILE_DECELERATION))
        if self.drive.state in (DriveState.SWITCH_ON_DISABLED, DriveState.FAULT):
            setpoint = 0.0  # voltage off: the motor stops driving the belt
        else:
            step = rate * dt_s
            setpoint += max(-step, min(step, demand - setpoint))
        self.setpoint_mrad_s = setpoint
        if not self.external_motor:
            self.velocity_mrad_s = setpoint

    def report(self) -> None:
        if abs(self.velocity_mrad_s) < STANDSTILL_MRAD_S and self.setpoint_mrad_s == 0.0:
            self.drive.standstill_reached(self.quick_stop_option)
        self.target_reached = abs(self._demand - self.velocity_mrad_s) < STANDSTILL_MRAD_S
        self.store.set(obj.BELT_VELOCITY_ACTUAL_MRAD_S, 0, round(self.velocity_mrad_s))
        self._publish_display()
        self._publish_status()

    def settled(self) -> bool:
        return (
            self.setpoint_mrad_s == self._demand
            and self.drive.state != DriveState.QUICK_STOP_ACTIVE
            and (self.external_motor or self.velocity_mrad_s == self.setpoint_mrad_s)
        )

    def _publish_display(self) -> None:
        omega_rad_s = abs(self.velocity_mrad_s) / 1000.0
        nubs = int(self.store.get(obj.BELT_NUB_COUNT))
        radius_mm = int(self.store.get(obj.BELT_EFFECTIVE_RADIUS_UM)) / UM_PER_MM
        if self.velocity_mrad_s > 0:
            active = ACTIVE_FORCE
            tap_mhz = round(nubs * omega_rad_s / (2 * math.pi) * MHZ_PER_HZ)
            surface_mm_s = 0
        elif self.velocity_mrad_s < 0:
            active, tap_mhz = ACTIVE_SLIP, 0
            surface_mm_s = round(omega_rad_s * radius_mm)
        else:
            active, tap_mhz, surface_mm_s = ACTIVE_NONE, 0, 0
        self.store.set(obj.BELT_ACTIVE, 0, active)
        self.store.set(obj.BELT_TAP_FREQUENCY_MHZ, 0, tap_mhz)
        self.store.set(obj.BELT_SURFACE_SPEED_MM_S, 0, min(surface_mm_s, 0xFFFF))
