"""grasplink: the CANopen/Modbus stack of a sensate upper-limb prosthesis.

Data flows around one loop: scene -> simulators -> device nodes -> bus ->
gateway (decode -> control) -> bus -> device nodes -> simulators.
"""

__version__ = "0.1.0"
