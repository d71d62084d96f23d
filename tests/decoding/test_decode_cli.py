"""`grasplink decode`: recordings in, JSON lines out; bad input, one line and exit 1."""

from __future__ import annotations

import json
from pathlib import Path

import can
import numpy as np
import pytest

from grasplink.cli import main
from grasplink.decoding import io, registry
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth

ROOT = Path(__file__).resolve().parents[2]
FIELDS = {  # the output contract (SlipEstimate.as_dict): speed and direction apart
    "t_s", "slip", "speed_mm_s", "speed_low_mm_s", "speed_high_mm_s", "direction",
    "direction_confidence", "position_mm", "force_n", "confidence",
}  # fmt: skip


@pytest.fixture(scope="module")
def recording():
    return synth.slip_recording(LAYOUTS_MM["alpha0.1"], 40.0, seed=21)


def write_csv(path: Path, t, x, header: str = "t_s,force_n") -> Path:
    lines = [header] + [f"{float(a)!r},{float(b)!r}" for a, b in zip(t, x, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return path


def decode(capsys, *args: str) -> tuple[int, list[dict], str]:
    rc = main(["decode", *map(str, args)])
    captured = capsys.readouterr()
    lines = [json.loads(line) for line in captured.out.splitlines()]
    return rc, lines, captured.err


def assert_error(capsys, *args, contains: list[str]) -> str:
    rc, lines, err = decode(capsys, *args)
    assert rc == 1
    assert not lines
    assert err.startswith("grasplink: error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    for text in contains:
        assert text in err, (text, err)
    return err


def assert_slip_decoded(lines: list[dict], duration_s: float) -> None:
    assert lines and all(set(d) == FIELDS for d in lines)
    assert abs(len(lines) - duration_s / 0.01) <= 2
    speeds = [d["speed_mm_s"] for d in lines if d["speed_mm_s"] is not None]
    assert any(d["slip"] for d in lines) and speeds
    assert abs(np.median(speeds) - 40.0) <= 4.0
    for d in lines:
        assert isinstance(d["slip"], bool) and 0.0 <= d["confidence"] <= 1.0
        assert d["speed_mm_s"] is None or d["speed_mm_s"] >= 0  # a magnitude
        assert d["direction"] in (None, 1, -1)
        assert (d["direction"] is None) == (d["direction_confidence"] is None)


# -- CSV and NPZ ---------------------------------------------------------------------------
def test_csv(tmp_path, capsys, recording):
    path = write_csv(tmp_path / "rec.csv", recording.t_s, recording.force_n)
    rc, lines, err = decode(capsys, path, "--skin", "alpha0.1", "--decoder", "ratio")
    assert rc == 0 and not err
    assert_slip_decoded(lines, recording.t_s[-1])


def test_csv_header_and_value_whitespace_tolerated(tmp_path, capsys, recording):
    rows = [" t_s , force_n "] + [
        f" {float(a)!r} ,\t{float(b)!r} "
        for a, b in zip(recording.t_s, recording.force_n, strict=True)
    ]
    path = tmp_path / "spaced.csv"
    path.write_text("\n".join(rows) + "\n\n")
    rc, lines, _ = decode(capsys, path, "--skin", "19,12,5,8,4,3,33", "--decoder", "ratio")
    assert rc == 0
    assert_slip_decoded(lines, recording.t_s[-1])


def test_npz_and_explicit_rate(tmp_path, capsys, recording):
    path = tmp_path / "rec.npz"
    np.savez(path, t_s=recording.t_s, force_n=recording.force_n)
    rc, lines, _ = decode(capsys, path, "--skin", "alpha0.1", "--decoder", "mmse")
    assert rc == 0
    assert_slip_decoded(lines, recording.t_s[-1])
    rc, again, _ = decode(capsys, path, "--skin", "alpha0.1", "--decoder", "mmse", "--fs", "400")
    assert rc == 0 and again == lines


def test_every_registered_decoder_runs(tmp_path, capsys, recording):
    path = write_csv(tmp_path / "rec.csv", recording.t_s[:800], recording.force_n[:800])
    for name in registry.DECODERS:
        if not registry.available(name):
            continue
        rc, lines, _ = decode(capsys, path, "--skin", "alpha0.1", "--decoder", name)
        assert rc == 0 and lines and all(set(d) == FIELDS for d in lines), name


def test_default_decoder(tmp_path, capsys, recording):
    path = write_csv(tmp_path / "rec.csv", recording.t_s[:400], recording.force_n[:400])
    if registry.available(registry.DEFAULT_DECODER):
        rc, lines, _ = decode(capsys, path, "--skin", "alpha0.1")
        assert rc == 0 and lines
    else:
        assert_error(
            capsys, path, "--skin", "alpha0.1", contains=[registry.DEFAULT_DECODER, "not available"]
        )


# -- bad input: one line, exit 1 ----------------------------------------------------------------
def test_csv_errors(tmp_path, capsys):
    good = "t_s,force_n\n0.0,1.0\n0.0025,1.1\n0.005,1.2\n"
    cases = {
        "header.csv": ("time,force\n0,1\n", ["header must be 't_s,force_n'", "'time,force'"]),
        "columns.csv": ("force_n,t_s\n0,1\n", ["'force_n,t_s'"]),
        "text.csv": (good + "0.0075,abc\n", [":5:", "force_n 'abc'"]),
        "nan.csv": (good + "0.0075,nan\n", [":5:", "'nan'"]),
        "inf_time.csv": (good + "inf,1.0\n", [":5:", "t_s 'inf'"]),
        "backwards.csv": (good + "0.004,1.0\n", [":5:", "0.004", "time must increase"]),
        "repeat.csv": (good + "0.005,1.0\n", [":5:", "not after"]),
        "empty.csv": ("", ["empty file"]),
        "header_only.csv": ("t_s,force_n\n", ["no samples"]),
        "three.csv": (good + "0.0075,1,2\n", [":5:", "expected 2 values"]),
        "one_sample.csv": ("t_s,force_n\n0.0,1.0\n", ["cannot tell the sample rate", "--fs"]),
    }
    for name, (text, expected) in cases.items():
        path = tmp_path / name
        path.write_text(text)
        assert_error(
            capsys, path, "--skin", "alpha0.1", "--decoder", "ratio", contains=[name, *expected]
        )
    assert_error(
        capsys,
        tmp_path / "missing.csv",
        "--skin",
        "alpha0.1",
        "--decoder",
        "ratio",
        contains=["missing.csv", "no such file"],
    )
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"\xff\xfe\x00\x01garbage")
    assert_error(
        capsys, binary, "--skin", "alpha0.1", "--decoder", "ratio", contains=["binary.csv"]
    )


def test_npz_errors(tmp_path, capsys):
    t = np.arange(10) / 400.0
    cases = {
        "keys.npz": (dict(time=t, force_n=t), ["missing array(s) t_s", "found"]),
        "both.npz": (dict(a=t), ["t_s, force_n"]),
        "nan.npz": (dict(t_s=t, force_n=np.where(t > 0.01, np.nan, 1.0)), ["force_n[5]", "nan"]),
        "back.npz": (
            dict(t_s=np.r_[t[:5], t[3], t[6:]], force_n=t),
            ["t_s[5]", "time must increase"],
        ),
        "length.npz": (dict(t_s=t, force_n=t[:5]), ["10 values", "force_n 5"]),
        "shape.npz": (dict(t_s=t.reshape(2, 5), force_n=t.reshape(2, 5)), ["1-D"]),
    }
    for name, (arrays, expected) in cases.items():
        path = tmp_path / name
        np.savez(path, **arrays)
        assert_error(
            capsys, path, "--skin", "alpha0.1", "--decoder", "ratio", contains=[name, *expected]
        )
    fake = tmp_path / "fake.npz"
    fake.write_text("not a zip")
    assert_error(capsys, fake, "--skin", "alpha0.1", "--decoder", "ratio", contains=["fake.npz"])


def test_npz_of_non_real_or_no_archive_is_refused(tmp_path, capsys):
    """Complex values lost their imaginary part, booleans and dates became numbers."""
    t = np.arange(10) / 400.0
    cases = {
        "complex.npz": (dict(t_s=t, force_n=t + 1j * t), ["force_n", "complex numbers"]),
        "bools.npz": (dict(t_s=t, force_n=t > 0.01), ["force_n", "booleans"]),
        "dates.npz": (
            dict(t_s=np.arange(10).astype("datetime64[s]"), force_n=t),
            ["t_s", "dates"],
        ),
        "text.npz": (dict(t_s=t.astype(str), force_n=t), ["t_s", "text"]),
    }
    for name, (arrays, expected) in cases.items():
        path = tmp_path / name
        np.savez(path, **arrays)
        assert_error(
            capsys,
            path,
            "--skin",
            "alpha0.1",
            contains=[name, *expected, "must be real numbers"],
        )
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    assert_error(capsys, empty, "--skin", "alpha0.1", contains=["empty.npz", "empty file"])
    nothing = tmp_path / "nothing.npz"
    np.savez(nothing)
    assert_error(capsys, nothing, "--skin", "alpha0.1", contains=["missing array(s)", "none"])
    lone = tmp_path / "lone.npz"
    with lone.open("wb") as handle:
        np.save(handle, t)
    assert_error(capsys, lone, "--skin", "alpha0.1", contains=["lone.npz", "single array"])


def test_option_errors(tmp_path, capsys, recording):
    path = write_csv(tmp_path / "rec.csv", recording.t_s[:100], recording.force_n[:100])
    assert_error(
        capsys,
        path,
        "--skin",
        "alpha9",
        "--decoder",
        "ratio",
        contains=["unknown ridge layout 'alpha9'", "alpha0.1"],
    )
    assert_error(
        capsys, path, "--skin", "5,-3", "--decoder", "ratio", contains=["spacing #2", "-3"]
    )
    assert_error(
        capsys,
        path,
        "--skin",
        "alpha0.1",
        "--decoder",
        "magic",
        contains=["unknown decoder 'magic'", "fft, ratio, mmse, dtw, tracker"],
    )
    with pytest.raises(SystemExit):
        main(["decode", str(path), "--skin", "alpha0.1", "--fs", "-5"])
    assert "positive number of Hz" in capsys.readouterr().err


def test_missing_decoder_module_is_a_clear_error(monkeypatch, tmp_path, capsys, recording):
    monkeypatch.setitem(
        registry.DECODERS, "tracker", "grasplink.decoding.no_such_module:TrackerDecoder"
    )
    path = write_csv(tmp_path / "rec.csv", recording.t_s[:100], recording.force_n[:100])
    assert_error(
        capsys,
        path,
        "--skin",
        "alpha0.1",
        "--decoder",
        "tracker",
        contains=["decoder 'tracker' is not available", "no_such_module"],
    )


# -- CAN logs ------------------------------------------------------------------------------------
def skin_frames(
    counts: np.ndarray,
    *,
    node_id: int = 0x10,
    t0: float = 1.0,
    fs: float = 400.0,
    drop: tuple[int, ...] = (),
    repeat: tuple[int, ...] = (),
) -> list[can.Message]:
    """TPDO1 frames of 3 samples + sequence, the last sample of each at its time stamp."""
    frames = []
    for k in range(len(counts) // 3):
        stamp = t0 + (3 * k + 2) / fs
        data = b"".join(int(c).to_bytes(2, "little") for c in counts[3 * k : 3 * k + 3])
        data += ((k + 1) & 0xFF).to_bytes(1, "little")
        msg = can.Message(
            timestamp=stamp, arbitration_id=0x180 + node_id, data=data, is_extended_id=False
        )
        if k not in drop:
            frames.append(msg)
        if k in repeat:
            frames.append(
                can.Message(
                    timestamp=stamp + 0.001,
                    arbitration_id=msg.arbitration_id,
                    data=data,
                    is_extended_id=False,
                )
            )
        if k % 5 == 0:  # other traffic on the bus
            frames.append(
                can.Message(
                    timestamp=stamp, arbitration_id=0x710, data=b"\x05", is_extended_id=False
                )
            )
    return frames


def write_log(path: Path, frames: list[can.Message]) -> Path:
    with can.Logger(str(path)) as logger:
        for msg in frames:
            logger.on_message_received(msg)
    return path


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".log"])
def test_can_log_formats(tmp_path, suffix):
    counts = (np.arange(300) * 7) % 4096
    path = write_log(tmp_path / f"skin{suffix}", skin_frames(counts, drop=(10, 11), repeat=(20,)))
    t, force, stats = io.read_can_log(path)
    assert stats.lost_packets == 2 and stats.republished == 1
    assert len(t) == 300 - 6
    assert np.all(np.diff(t) > 0)
    expected_t = 1.0 + np.delete(np.arange(300), np.arange(30, 36)) / 400.0
    # .asc and .blf store times from the start of the log: compare from the first sample
    np.testing.assert_allclose(t - t[0], expected_t - expected_t[0], atol=2e-6)
    expected = np.delete(counts, np.arange(30, 36)) * 98067.0 / 4095 / 1000
    np.testing.assert_allclose(force, expected, rtol=1e-12)


def test_can_log_node_id_and_errors(tmp_path, capsys):
    counts = np.full(60, 1000)
    path = write_log(tmp_path / "other.asc", skin_frames(counts, node_id=0x22))
    assert_error(
        capsys,
        path,
        "--skin",
        "alpha0.1",
        "--decoder",
        "ratio",
        contains=["other.asc", "no skin TPDO1 frames", "0x190", "0x1A2"],
    )
    rc, lines, _ = decode(
        capsys, path, "--skin", "alpha0.1", "--decoder", "ratio", "--node-id", "0x22"
    )
    assert rc == 0 and lines
    junk = tmp_path / "junk.blf"
    junk.write_bytes(b"definitely not a BLF file" * 10)
    assert_error(capsys, junk, "--skin", "alpha0.1", "--decoder", "ratio", contains=["junk.blf"])


def test_can_log_of_a_scene_matches_the_simulated_signal(tmp_path, capsys):
    out = tmp_path / "hl"
    assert main(["run", str(ROOT / "scenes" / "headline_slip.toml"), "--out", str(out)]) == 0
    capsys.readouterr()
    t, force, stats = io.read_can_log(out / "can.asc")
    assert stats.lost_packets == 0 and stats.malformed == 0
    sim = np.genfromtxt(out / "skin.csv", delimiter=",", skip_header=1)
    inside = (t >= sim[0, 0]) & (t <= sim[-1, 0])
    assert inside.sum() > 0.99 * len(sim) - 3
    lsb = 98.067 / 4095
    assert np.max(np.abs(force[inside] - np.interp(t[inside], sim[:, 0], sim[:, 1]))) <= lsb / 2
    rc, lines, _ = decode(capsys, out / "can.asc", "--skin", "alpha0.1", "--decoder", "ratio")
    assert rc == 0 and all(set(d) == FIELDS for d in lines)
    assert abs(len(lines) - 350) <= 2 and any(d["slip"] for d in lines)


# -- absurd options, hostile samples, a run's own files ------------------------------------------
def test_absurd_layouts_and_rates_are_one_line_errors(tmp_path, capsys, recording):
    path = write_csv(tmp_path / "rec.csv", recording.t_s[:100], recording.force_n[:100])
    cases = [
        (["--skin", "1e300,1"], ["spacing #1"]),
        (["--skin", "5,0.2"], ["spacing #2", "0.5-200 mm", "0x2140"]),
        (["--skin", ",".join(["2"] * 41)], ["41 spacings", "at most 40"]),
        (["--skin", "nan,1"], ["spacing #1", "nan"]),
        (["--skin", "alpha0.1", "--fs", "1e300"], ["1e+300 Hz", "80-1000 Hz", "0x2120"]),
        (["--skin", "alpha0.1", "--fs", "50"], ["50 Hz", "80-1000 Hz"]),
        (["--skin", "alpha0.1", "--fs", "2000"], ["2000 Hz"]),
    ]
    for options, expected in cases:
        assert_error(capsys, path, *options, "--decoder", "ratio", contains=expected)
    for fs in ("0", "-5", "nan", "inf"):
        with pytest.raises(SystemExit):
            main(["decode", str(path), "--skin", "alpha0.1", "--fs", fs])
        assert "positive number of Hz" in capsys.readouterr().err
    assert_error(capsys, path, "--decoder", "ratio", contains=["--skin LAYOUT is required"])


def test_inferred_rate_outside_the_skin_range_is_a_one_line_error(tmp_path, capsys):
    path = tmp_path / "pico.npz"
    np.savez(path, t_s=np.arange(800) * 1e-12, force_n=np.ones(800))
    assert_error(
        capsys,
        path,
        "--skin",
        "alpha0.1",
        contains=["pico.npz", "median time step 1e-12 s", "80-1000 Hz", "give --fs"],
    )


def test_out_of_range_samples_are_reported_never_null_at_confidence(tmp_path, capsys, recording):
    x = recording.force_n.copy()
    x[100::50] = 1e308
    x[125::50] = -1e308
    path = tmp_path / "huge.npz"
    np.savez(path, t_s=recording.t_s, force_n=x)
    rc, lines, err = decode(capsys, path, "--skin", "alpha0.1")
    assert rc == 0
    bad = len(x[100::50]) + len(x[125::50])
    assert err.count("\n") == 1 and f"rejected {bad}: {bad} out of range" in err
    assert lines and all(d["force_n"] is not None for d in lines)  # was null at confidence 1


def test_time_gap_is_reported_and_has_no_updates(tmp_path, capsys, recording):
    t = recording.t_s.copy()
    half = len(t) // 2
    t[half:] += 1e6
    path = write_csv(tmp_path / "gap.csv", t, recording.force_n)
    rc, lines, err = decode(capsys, path, "--skin", "alpha0.1", "--decoder", "ratio")
    assert rc == 0
    assert not [d for d in lines if t[half - 1] < d["t_s"] < t[half]]
    assert abs(len(lines) - recording.t_s[-1] / 0.01) <= 3
    assert "1 gap(s) over 8 sample periods (20 ms; longest 1e+06 s)" in err


def test_mostly_unusable_samples_exit_1_after_the_report(tmp_path, capsys, recording):
    n = len(recording.t_s)
    t = np.sort(np.concatenate([recording.t_s, recording.t_s[:-1] + 1e-12]))
    x = np.resize(recording.force_n, len(t))
    path = tmp_path / "jitter.npz"
    np.savez(path, t_s=t, force_n=x)
    rc, _, err = decode(capsys, path, "--skin", "alpha0.1", "--fs", "400", "--decoder", "ratio")
    assert rc == 0 and f"{n - 1} timing errors" in err  # half of them: just enough
    t3 = np.sort(np.concatenate([t, recording.t_s[:-1] + 2e-12]))
    np.savez(path, t_s=t3, force_n=np.resize(recording.force_n, len(t3)))
    rc, _, err = decode(capsys, path, "--skin", "alpha0.1", "--fs", "400", "--decoder", "ratio")
    assert rc == 1
    last = err.splitlines()[-1]
    assert last.startswith("grasplink: error: ") and f"only {n} of {len(t3)} samples usable" in last


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    scene = ROOT / "scenes" / "slip_alpha0.1_20mm_s_forward.toml"
    assert main(["run", str(scene), "--out", str(out)]) == 0
    return out


def test_skin_csv_of_a_run_and_the_run_folder_decode(run_folder, capsys):
    from grasplink.simulators import signals

    assert signals.SKIN_FORCE_N in io.FORCE_COLUMNS  # the column `grasplink run` writes
    capsys.readouterr()
    rc, from_csv, err = decode(
        capsys, run_folder / "skin.csv", "--skin", "alpha0.1", "--decoder", "ratio"
    )
    assert rc == 0 and not err and from_csv and any(d["slip"] for d in from_csv)
    rc, from_folder, _ = decode(capsys, run_folder, "--decoder", "ratio")
    assert rc == 0 and from_folder == from_csv  # layout and rate from summary.json
    rc, other, _ = decode(capsys, run_folder, "--skin", "fibonacci", "--decoder", "ratio")
    assert rc == 0 and other != from_csv  # --skin overrides the summary


def test_folders_that_are_not_runs_are_one_line_errors(tmp_path, capsys):
    assert_error(capsys, tmp_path, "--decoder", "ratio", contains=["no summary.json"])
    (tmp_path / "summary.json").write_text('{"files": {"skin": "../x.csv"}}')
    assert_error(capsys, tmp_path, "--decoder", "ratio", contains=["files.skin"])
    (tmp_path / "summary.json").write_text("{not json")
    assert_error(capsys, tmp_path, "--decoder", "ratio", contains=["summary.json"])
    (tmp_path / "summary.json").write_text('{"files": {"skin": "skin.csv"}}')
    (tmp_path / "skin.csv").write_text("t_s,skin.force_n\n0,1\n0.0025,1\n0.005,1\n")
    assert_error(capsys, tmp_path, "--decoder", "ratio", contains=["names no skin layout"])
