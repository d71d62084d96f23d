"""Offline evaluation: what decoders get right, measured against ground truth.

Sits above the simulators and the gateway (it imports both; neither imports
it): `decoders` builds any registered decoder with the reference slips the
window matchers need, `scoring` scores a decoder's estimates against a
recording's truth, `scenes` runs shipped scenes through the engine and the
skin node and reads back what went over CAN, `decoding_bench` is the
decoding benchmark (`grasplink bench decode`, benchmarks/bench_decoding.py).
Nothing here runs on a deployed gateway.
"""
