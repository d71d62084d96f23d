"""What the gateway writes to a node over SDO before starting it.

A node that boots (or reboots) comes up with its defaults overlaid by
whatever its NVM holds; the gateway makes it match the configuration before
any process data flows: heartbeat producer and consumer times, the PDO
mappings the gateway decodes with (the EDS defaults, re-asserted with the
CiA 301 mapping procedure), and the application parameters (skin layout and
sample rate, EMG window and calibration, hand crush limit and grip rate).
Values are encoded through the node's object dictionary (python-canopen's
types), never by hand.

A node boots on the gateway's real-time thread, so nothing here may parse an
EDS at that moment (tens of ms: heartbeats and SDO answers of every node would
wait): the writes come from the dictionary the node's configuration already
holds (`NodeConfig.dictionary`, parsed once when the description is read), and
the gateway builds every node's writes when it is constructed
(`Provisioner.writes` costs ~0.1 ms; handing out the built tuple costs nothing).
"""

from __future__ import annotations

import canopen
from canopen.objectdictionary import ODVariable

from grasplink.gateway.config import EmgConfig, GatewayConfig, HandConfig, NodeConfig, SkinConfig
from grasplink.gateway.description import SdoWrite, dcf_writes
from grasplink.profiles import objects as obj
from grasplink.profiles import od_default, od_variable
from grasplink.profiles.layouts import PRESET_CODES, spacings_um

COB_ID_INVALID = 0x80000000
# (first communication object, first mapping object) of the RPDOs and of the TPDOs
PDO_OBJECTS = ((obj.RPDO_COMM, obj.RPDO_MAP), (obj.TPDO_COMM, obj.TPDO_MAP))


class Provisioner:
    """The SDO writes that configure one node, from its profile and the gateway config."""

    def __init__(self, node: NodeConfig, config: GatewayConfig):
        self.node = node
        self.config = config
        self.od: canopen.ObjectDictionary = node.dictionary()  # shared: never mutated

    def writes(self) -> list[SdoWrite]:
        """Heartbeats; then for our own nodes their PDO maps and application parameters, for
        a device its DCF's values (its EDS's PDO maps are its own: never overwritten); then
        the description's `[sdo]` table, last, so it has the final word."""
        out = self._heartbeats()
        if self.node.eds is None:
            out += self._pdo_mappings()
            out += self._application()
        elif self.node.eds.suffix.lower() == ".dcf":
            out += dcf_writes(self.od)
        out += self.node.sdo
        return out

    # -- helpers -----------------------------------------------------------------------
    def _entry(self, index: int, subindex: int = 0) -> ODVariable:
        return od_variable(self.od, index, subindex)

    def _default(self, index: int, subindex: int = 0) -> int:
        return od_default(self.od, index, subindex)

    def _write(self, index: int, subindex: int, value: int | float, what: str) -> SdoWrite:
        var = self._entry(index, subindex)
        if var.data_type in canopen.objectdictionary.INTEGER_TYPES:
            value = round(value)
        return SdoWrite(index, subindex, var.encode_raw(value), what)

    # -- what is written -------------------------------------------------------------------
    def _heartbeats(self) -> list[SdoWrite]:
        """The node's heartbeat time, and its watch of the gateway's (where its dictionary
        has 1017h and 1016h:01: every grasplink node; a device may lack them)."""
        consumer_ms = self.config.consumer_ms
        out = []
        if self._has(obj.HEARTBEAT_PRODUCER_MS, 0):
            out.append(
                self._write(obj.HEARTBEAT_PRODUCER_MS, 0, self.node.heartbeat_ms, "heartbeat time")
            )
        if self._has(obj.HEARTBEAT_CONSUMER, 1):
            out.append(
                self._write(
                    obj.HEARTBEAT_CONSUMER,
                    1,
                    (self.config.node_id << 16) | consumer_ms,
                    "watch the gateway's heartbeat",
                )
            )
        return out

    def _has(self, index: int, subindex: int) -> bool:
        if index not in self.od:
            return False
        try:
            var = self._entry(index, subindex)
        except KeyError:
            return False
        return var.access_type in ("rw", "wo", "rww", "rwr")

    def _pdo_mappings(self) -> list[SdoWrite]:
        """Every PDO the profile defines, set back to its EDS mapping (CiA 301 7.5.2.36)."""
        out: list[SdoWrite] = []
        for comm_base, map_base in PDO_OBJECTS:
            for comm in (i for i in sorted(self.od.indices) if comm_base <= i < map_base):
                mapping = map_base + (comm - comm_base)
                if mapping not in self.od:
                    continue
                cob_id = self._default(comm, 1)
                count = self._default(mapping, 0)
                label = f"PDO 0x{comm:04X}"
                out.append(self._write(comm, 1, cob_id | COB_ID_INVALID, f"{label} off"))
                out.append(self._write(mapping, 0, 0, f"{label} mapping cleared"))
                for sub in range(1, count + 1):
                    entry = self._default(mapping, sub)
                    out.append(self._write(mapping, sub, entry, f"{label} maps 0x{entry:08X}"))
                out.append(self._write(mapping, 0, count, f"{label} {count} objects"))
                for sub, what in ((2, "transmission type"), (5, "event timer")):
                    if sub in self.od[comm]:  # type: ignore[operator]  # a RECORD here
                        value = self._default(comm, sub)
                        out.append(self._write(comm, sub, value, f"{label} {what}"))
                out.append(self._write(comm, 1, cob_id, f"{label} on"))
        return out

    def _application(self) -> list[SdoWrite]:
        node = self.node
        if isinstance(node, SkinConfig):
            return self._skin(node)
        if isinstance(node, EmgConfig):
            return [
                self._write(obj.EMG_SAMPLE_RATE_HZ, 0, node.sample_rate_hz, "EMG sample rate"),
                self._write(obj.EMG_WINDOW_MS, 0, node.window_ms, "EMG envelope window"),
                self._write(
                    obj.EMG_ENVELOPE_PERIOD_MS, 0, node.envelope_period_ms, "EMG envelope period"
                ),
                *self._calibration(node),
            ]
        if isinstance(node, HandConfig):
            return [
                self._write(obj.HAND_CRUSH_LIMIT_MN, 0, node.crush_limit_n * 1000, "crush limit"),
                self._write(obj.HAND_GRIP_RATE_MN_S, 0, node.grip_rate_n_s * 1000, "grip rate"),
            ]
        return []

    def _skin(self, node: SkinConfig) -> list[SdoWrite]:
        out = [
            self._write(obj.SKIN_SAMPLE_RATE_HZ, 0, node.sample_rate_hz, "skin sample rate"),
            self._write(obj.SKIN_SAMPLES_PER_PDO, 0, node.samples_per_pdo, "samples per TPDO"),
        ]
        preset = next((c for c, name in PRESET_CODES.items() if name == node.layout), 0)
        out.append(self._write(obj.SKIN_LAYOUT_PRESET, 0, preset, f"layout {node.layout}"))
        if not preset:
            spacings = spacings_um(node.layout_mm)
            out.append(self._write(obj.SKIN_RIDGE_SPACING_UM, 0, len(spacings), "ridge count"))
            for sub, um in enumerate(spacings, start=1):
                out.append(self._write(obj.SKIN_RIDGE_SPACING_UM, sub, um, f"spacing {sub}"))
        return out

    def _calibration(self, node: EmgConfig) -> list[SdoWrite]:
        """e_min and e_max in the order that keeps e_min < e_max true after each write."""
        e_min = self._write(obj.EMG_CALIBRATION, 1, node.e_min_uv, "EMG e_min")
        e_max = self._write(obj.EMG_CALIBRATION, 2, node.e_max_uv, "EMG e_max")
        stored_max = float(self._default(obj.EMG_CALIBRATION, 2))
        return [e_min, e_max] if node.e_min_uv < stored_max else [e_max, e_min]
