"""Load, or compile on a machine's first run, the decoders' kernels: `python -m
grasplink.decoding.warm_up` (`make` runs it in set-up).

numba caches what it compiles beside the kernels' sources; compiling takes tens of seconds
the first time on a machine (and after a kernel changes), loading a second or two. Done
here once, before tests run on several workers or a gateway goes live, neither pays it in
a loop.
"""

from __future__ import annotations

import time

from grasplink.decoding.registry import DEFAULT_DECODER, make_decoder
from grasplink.profiles.layouts import LAYOUTS_MM

WARM_UP_LAYOUT = "alpha0.1"


def main() -> int:
    started = time.monotonic()
    make_decoder(DEFAULT_DECODER, LAYOUTS_MM[WARM_UP_LAYOUT], 400.0).warm_up()
    print(f"decoder kernels ready ({time.monotonic() - started:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
