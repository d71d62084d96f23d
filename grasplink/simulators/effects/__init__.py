"""Every effect a scene can ask for; importing this package registers them all."""

from grasplink.simulators.effects import actuators, damped, emg, kinematics, noise, skin, wearer

__all__ = ["actuators", "damped", "emg", "kinematics", "noise", "skin", "wearer"]
