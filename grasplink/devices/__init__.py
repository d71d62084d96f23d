"""Device runtime: CANopen slave behaviour shared by all grasplink nodes.

Everything here is sans-IO: a node is fed integer-microsecond time and CAN
frames and returns frames to send. Threads and buses wrap it in
`grasplink.bus`.
"""
