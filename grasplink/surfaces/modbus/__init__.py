"""The gateway's Modbus TCP/RTU surface: a register map generated from the profiles and
the gateway's state (`registers`), served by pymodbus in its own thread (`server`);
docs/modbus.md is generated from the map (`docgen`)."""
