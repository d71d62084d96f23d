"""The CAN log formats grasplink records, replays and decodes (python-can reads them all)."""

LOG_FORMATS = {
    ".asc": "Vector ASC",
    ".blf": "Vector BLF",
    ".log": "can-utils candump -L",
    ".trc": "PEAK PCAN-View trace",
}
