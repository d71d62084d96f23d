"""Skin decoding: grip force, slip, slip speed and slip position from one FSR signal."""
