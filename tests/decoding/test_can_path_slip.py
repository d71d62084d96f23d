"""Issue 11 end to end: shipped slip scenes through the skin node and its CAN log.

`grasplink run SCENE --out R` then `grasplink decode R/can.asc`: the
default decoder must give the slip's true direction and speed from what the
node sends (12-bit ADC counts, 3 samples per TPDO1), as it does from the
float signal. Before the fix: alpha0.1 20 mm/s reverse decoded to a median
+18.4 mm/s (97 % wrong sign), the headline scene to ~-300 mm/s (68 % wrong
sign) even from skin.csv.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from grasplink.cli import main
from grasplink.decoding.io import read_can_log, read_csv
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation.scoring import along_truth
from grasplink.profiles.layouts import LAYOUTS_MM

SCENES = Path(__file__).resolve().parents[2] / "scenes"


def truth(run: Path) -> dict[str, np.ndarray]:
    rows = np.genfromtxt(run / "truth.csv", delimiter=",", names=True)
    return {
        "t_s": rows["t_s"],
        "slipping": rows["objectslipping"],
        "speed_mm_s": rows["objectspeed_mm_s"],
    }


def decode(layout, t: np.ndarray, x: np.ndarray, chunk: int = 3):
    decoder = TrackerDecoder(layout, 400.0)
    out = []
    for start in range(0, len(t), chunk):
        out += decoder.feed(t[start : start + chunk], x[start : start + chunk])
    return out


def judged(estimates, true: dict[str, np.ndarray]) -> tuple[int, int, float, float]:
    """(speeds given while slipping, of which a wrong direction, median error, largest
    |speed|); a speed without a direction counts as its magnitude (scoring.along_truth)."""
    t = np.array([e.t_s for e in estimates])
    slipping = np.interp(t, true["t_s"], true["slipping"]) > 0.5
    v_true = np.interp(t, true["t_s"], true["speed_mm_s"])
    v, direction = along_truth(estimates, v_true)
    given = slipping & np.isfinite(v) & (v != 0) & (np.abs(v_true) > 1.0)
    wrong = int(np.count_nonzero(given & (direction != 0) & (direction != np.sign(v_true))))
    error = np.abs(v[given] - v_true[given]) / np.abs(v_true[given])
    return int(given.sum()), wrong, float(np.median(error)), float(np.nanmax(np.abs(v)))


@pytest.mark.parametrize(
    "scene,layout,speed_mm_s",
    [
        ("slip_alpha0.1_20mm_s_reverse", "alpha0.1", 20.0),
        ("slip_alpha0.9_60mm_s_reverse", "alpha0.9", 60.0),
        ("headline_slip", "alpha0.1", 40.0),  # speed dips, hysteresis, drift, 0 N rail
    ],
)
def test_scene_through_can_decodes_like_its_float_signal(tmp_path, scene, layout, speed_mm_s):
    run = tmp_path / scene
    assert main(["run", str(SCENES / f"{scene}.toml"), "--out", str(run)]) == 0
    true = truth(run)
    t_can, x_can, _ = read_can_log(run / "can.asc")
    t_csv, x_csv = read_csv(run / "skin.csv")
    layout_mm = LAYOUTS_MM[layout]
    for label, t, x in (("CAN", t_can, x_can), ("skin.csv", t_csv, x_csv)):
        given, wrong, error, fastest = judged(decode(layout_mm, t, x), true)
        assert given >= 20, label
        assert wrong == 0, (label, wrong, given)
        assert error <= 0.05, (label, error)
        assert fastest <= 1.5 * speed_mm_s, (label, fastest)
