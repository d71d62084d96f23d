"""Walking a CiA 402 drive to OPERATION ENABLED from the statusword it reports.

A master reads the drive's state from its statusword (TPDO) and sends the
controlword that moves it one step on (shutdown 06h, switch on 07h, enable
operation 0Fh; fault reset 80h from FAULT; disable voltage 00h out of QUICK
STOP ACTIVE). Until the first statusword arrives it starts the walk blind,
from the state every drive boots into (SWITCH ON DISABLED).
"""

from __future__ import annotations

from grasplink.devices.cia402 import DriveState, state_of

SHUTDOWN, SWITCH_ON, ENABLE_OPERATION = 0x06, 0x07, 0x0F
DISABLE_VOLTAGE, FAULT_RESET = 0x00, 0x80

NEXT_CONTROLWORD: dict[DriveState, int] = {
    DriveState.NOT_READY_TO_SWITCH_ON: SHUTDOWN,  # it moves on by itself; shutdown is harmless
    DriveState.SWITCH_ON_DISABLED: SHUTDOWN,
    DriveState.READY_TO_SWITCH_ON: SWITCH_ON,
    DriveState.SWITCHED_ON: ENABLE_OPERATION,
    DriveState.OPERATION_ENABLED: ENABLE_OPERATION,
    DriveState.QUICK_STOP_ACTIVE: DISABLE_VOLTAGE,
    DriveState.FAULT_REACTION_ACTIVE: DISABLE_VOLTAGE,
    DriveState.FAULT: FAULT_RESET,
}


class DriveHandshake:
    """The controlword to send next to one drive."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """The drive rebooted: it is in SWITCH ON DISABLED again."""
        self._set(None)

    def on_statusword(self, statusword: int) -> None:
        self._set(state_of(statusword))

    def _set(self, state: DriveState | None) -> None:
        # The controlword is looked up when the state changes: it is asked for every
        # command the master sends (several per TPDO it gets), the state changes rarely.
        self.state = state
        self._controlword = NEXT_CONTROLWORD.get(state or DriveState.SWITCH_ON_DISABLED, SHUTDOWN)

    @property
    def enabled(self) -> bool:
        return self.state is DriveState.OPERATION_ENABLED

    def controlword(self) -> int:
        return self._controlword
