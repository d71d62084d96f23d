"""CiA 402 power drive state machine (controlword 6040h -> statusword 6041h).

Shared by the belt (profile velocity) and the hand (grip force). The drive
function itself (what "operation enabled" does) stays in each application.
"""

from __future__ import annotations

from enum import Enum


class DriveState(Enum):
    NOT_READY_TO_SWITCH_ON = 0x0000
    SWITCH_ON_DISABLED = 0x0040
    READY_TO_SWITCH_ON = 0x0021
    SWITCHED_ON = 0x0023
    OPERATION_ENABLED = 0x0027
    QUICK_STOP_ACTIVE = 0x0007
    FAULT_REACTION_ACTIVE = 0x000F
    FAULT = 0x0008


SW_VOLTAGE_ENABLED = 1 << 4
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11
CW_FAULT_RESET = 1 << 7


def _command(controlword: int) -> str | None:
    """Decode the device-control command (CiA 402 table 'command coding')."""
    if controlword & 0x82 == 0x00:
        return "disable_voltage"
    if controlword & 0x86 == 0x02:
        return "quick_stop"
    if controlword & 0x87 == 0x06:
        return "shutdown"
    if controlword & 0x8F == 0x07:
        return "switch_on"  # also "disable operation" from OPERATION_ENABLED
    if controlword & 0x8F == 0x0F:
        return "enable_operation"
    return None


_TRANSITIONS: dict[tuple[DriveState, str], DriveState] = {
    (DriveState.SWITCH_ON_DISABLED, "shutdown"): DriveState.READY_TO_SWITCH_ON,
    (DriveState.READY_TO_SWITCH_ON, "switch_on"): DriveState.SWITCHED_ON,
    (DriveState.READY_TO_SWITCH_ON, "enable_operation"): DriveState.OPERATION_ENABLED,
    (DriveState.READY_TO_SWITCH_ON, "disable_voltage"): DriveState.SWITCH_ON_DISABLED,
    (DriveState.READY_TO_SWITCH_ON, "quick_stop"): DriveState.SWITCH_ON_DISABLED,
    (DriveState.SWITCHED_ON, "enable_operation"): DriveState.OPERATION_ENABLED,
    (DriveState.SWITCHED_ON, "shutdown"): DriveState.READY_TO_SWITCH_ON,
    (DriveState.SWITCHED_ON, "disable_voltage"): DriveState.SWITCH_ON_DISABLED,
    (DriveState.SWITCHED_ON, "quick_stop"): DriveState.SWITCH_ON_DISABLED,
    (DriveState.OPERATION_ENABLED, "switch_on"): DriveState.SWITCHED_ON,
    (DriveState.OPERATION_ENABLED, "shutdown"): DriveState.READY_TO_SWITCH_ON,
    (DriveState.OPERATION_ENABLED, "disable_voltage"): DriveState.SWITCH_ON_DISABLED,
    (DriveState.OPERATION_ENABLED, "quick_stop"): DriveState.QUICK_STOP_ACTIVE,
    (DriveState.QUICK_STOP_ACTIVE, "disable_voltage"): DriveState.SWITCH_ON_DISABLED,
}


class DriveStateMachine:
    """Applies controlwords; the application reports standstill and faults."""

    def __init__(self) -> None:
        self.state = DriveState.SWITCH_ON_DISABLED  # NOT_READY passes at once after init
        self._last_controlword = 0

    def reset(self) -> None:
        self.state = DriveState.SWITCH_ON_DISABLED
        self._last_controlword = 0

    def apply(self, controlword: int, quick_stop_option: int) -> DriveState:
        rising_fault_reset = controlword & CW_FAULT_RESET and not (
            self._last_controlword & CW_FAULT_RESET
        )
        self._last_controlword = controlword
        if self.state == DriveState.FAULT:
            if rising_fault_reset:
                self.state = DriveState.SWITCH_ON_DISABLED
            return self.state
        command = _command(controlword)
        if (
            self.state == DriveState.QUICK_STOP_ACTIVE
            and command == "enable_operation"
            and (quick_stop_option >= 5)
        ):
            self.state = DriveState.OPERATION_ENABLED
        elif command is not None:
            self.state = _TRANSITIONS.get((self.state, command), self.state)
        return self.state

    def standstill_reached(self, quick_stop_option: int) -> None:
        """In QUICK_STOP_ACTIVE, options 0-4 end in SWITCH_ON_DISABLED once stopped."""
        if self.state == DriveState.QUICK_STOP_ACTIVE and quick_stop_option <= 4:
            self.state = DriveState.SWITCH_ON_DISABLED

    def fault(self) -> None:
        self.state = DriveState.FAULT

    def quick_stop(self) -> None:
        """Forced quick stop (safe state), whatever the controlword says."""
        if self.state == DriveState.OPERATION_ENABLED:
            self.state = DriveState.QUICK_STOP_ACTIVE
        elif self.state in (DriveState.READY_TO_SWITCH_ON, DriveState.SWITCHED_ON):
            self.state = DriveState.SWITCH_ON_DISABLED

    def statusword(self, *, target_reached: bool, internal_limit: bool) -> int:
        word = self.state.value | SW_REMOTE
        if self.state in (
            DriveState.READY_TO_SWITCH_ON,
            DriveState.SWITCHED_ON,
            DriveState.OPERATION_ENABLED,
            DriveState.QUICK_STOP_ACTIVE,
        ):
            word |= SW_VOLTAGE_ENABLED
        if target_reached:
            word |= SW_TARGET_REACHED
        if internal_limit:
            word |= SW_INTERNAL_LIMIT
        return word


# Statusword -> state (CiA 402, table "state coding"): (mask, value) per state.
_STATE_CODING: tuple[tuple[int, int, DriveState], ...] = (
    (0x4F, 0x00, DriveState.NOT_READY_TO_SWITCH_ON),
    (0x4F, 0x40, DriveState.SWITCH_ON_DISABLED),
    (0x6F, 0x21, DriveState.READY_TO_SWITCH_ON),
    (0x6F, 0x23, DriveState.SWITCHED_ON),
    (0x6F, 0x27, DriveState.OPERATION_ENABLED),
    (0x6F, 0x07, DriveState.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, DriveState.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, DriveState.FAULT),
)


def state_of(statusword: int) -> DriveState | None:
    """The drive state a statusword reports (None for a coding CiA 402 does not define)."""
    for mask, value, state in _STATE_CODING:
        if statusword & mask == value:
            return state
    return None
