"""Simulators: the physical signals a scene asks for, and nothing more."""
