"""ARKit CSV streams: formats, name matching, bad input policies, round trips, real data."""

from __future__ import annotations

import csv
import io
import sys

import numpy as np
import pytest

from head360cli.errors import BadInputError, FileFormatError
from head360cli.io.arkit import (
    LIVE_LINK_FACE_ORDER,
    ROTATION_COLUMNS,
    ArkitStream,
    read_arkit_csv,
    resample,
    smooth,
    write_arkit_csv,
)
from head360cli.mesh.arkit52 import ARKIT52, INDEX


def make_stream(frames: int = 90, fps: float = 60.0, seed: int = 0) -> ArkitStream:
    rng = np.random.default_rng(seed)
    return ArkitStream(
        weights=rng.uniform(0, 1, (frames, 52)).astype(np.float32),
        timestamps=np.arange(frames) / fps,
        fps=fps,
        nominal_fps=fps,
        head_rotation=rng.uniform(-0.5, 0.5, (frames, 3)).astype(np.float32),
        eye_rotation=rng.uniform(-0.2, 0.2, (frames, 6)).astype(np.float32),
    )


def write_rows(path, header, rows):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)
    return path


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("fps", [24.0, 30.0, 60.0])
def test_live_link_face_round_trip(tmp_path, fps):
    stream = make_stream(fps=fps)
    path = tmp_path / "take.csv"
    write_arkit_csv(stream, path, flavor="livelinkface", start_seconds=18 * 3600 + 59.5)
    back = read_arkit_csv(path)
    assert back.source_format == "livelinkface"
    assert back.weights.shape == (90, 52)
    np.testing.assert_allclose(back.weights, stream.weights, atol=1e-9)
    np.testing.assert_allclose(back.head_rotation, stream.head_rotation, atol=1e-7)
    np.testing.assert_allclose(back.eye_rotation, stream.eye_rotation, atol=1e-7)
    np.testing.assert_allclose(back.timestamps, stream.timestamps, atol=1e-3 / fps)
    assert back.fps == fps and back.nominal_fps == fps
    assert back.warnings == []
    header = path.read_text().splitlines()[0].split(",")
    assert header[:2] == ["Timecode", "BlendshapeCount"]
    assert header[2:54] == list(LIVE_LINK_FACE_ORDER)
    assert header[54:] == list(ROTATION_COLUMNS)


@pytest.mark.parametrize(("frames", "fps"), [(3, 30.0), (5, 60.0), (20, 25.0), (2, 120.0)])
def test_live_link_face_takes_shorter_than_a_second_keep_their_times(tmp_path, frames, fps):
    # Timecodes carry no rate, and a short take's frame numbers never reach the top of
    # its rate: the writer numbers them at a rate the reader infers back.
    stream = make_stream(frames=frames, fps=fps)
    path = tmp_path / "short.csv"
    write_arkit_csv(stream, path, flavor="livelinkface")
    back = read_arkit_csv(path)
    np.testing.assert_allclose(back.timestamps, stream.timestamps, atol=1e-3 / 24)
    assert back.fps == fps
    np.testing.assert_allclose(back.weights, stream.weights, atol=1e-9)


def test_arkit_flavor_round_trip_and_open_stream(tmp_path):
    stream = make_stream(frames=30, fps=30.0)
    buf = io.StringIO()
    write_arkit_csv(stream, buf, flavor="arkit")
    buf.seek(0)
    back = read_arkit_csv(buf)
    assert back.source_format == "arkit"
    np.testing.assert_allclose(back.weights, stream.weights, atol=1e-9)
    assert back.fps == 30.0


def test_live_link_face_order_swaps_jaw_and_mouth_sides():
    assert LIVE_LINK_FACE_ORDER[15:17] == ("JawRight", "JawLeft")
    assert LIVE_LINK_FACE_ORDER[21:23] == ("MouthRight", "MouthLeft")


def test_columns_are_matched_by_name_not_position(tmp_path):
    rng = np.random.default_rng(1)
    values = rng.uniform(0, 1, (10, 52))
    order = rng.permutation(52)
    header = ["time"] + [ARKIT52[i] for i in order]
    rows = [[f"{t / 60:.6f}"] + [f"{values[t, i]:.8f}" for i in order] for t in range(10)]
    back = read_arkit_csv(write_rows(tmp_path / "perm.csv", header, rows))
    np.testing.assert_allclose(back.weights, values, atol=1e-7)


def test_mediapipe_names_and_neutral_are_handled(tmp_path):
    header = ["_neutral", "eyeBlinkLeft", "jawOpen", "mouthSmileRight"]
    rows = [["0.9", "0.1", "0.5", "0.25"], ["0.8", "0.2", "0.6", "0.35"]]
    back = read_arkit_csv(write_rows(tmp_path / "mp.csv", header, rows))
    assert back.source_format == "mediapipe"
    assert back.columns_found == ["eyeBlinkLeft", "jawOpen", "mouthSmileRight"]
    assert "_neutral" in back.columns_ignored
    assert back.weight("JawOpen").tolist() == pytest.approx([0.5, 0.6])


def test_generic_subset_gives_zeros_and_one_warning(tmp_path):
    header = ["frame", "jaw_open", "eyeBlink_L", "eyeBlink_R"]
    rows = [[str(i), "0.5", "0.1", "0.2"] for i in range(5)]
    back = read_arkit_csv(write_rows(tmp_path / "g.csv", header, rows), fps=25)
    assert back.source_format == "generic"
    assert len(back.columns_missing) == 49
    missing_warnings = [w for w in back.warnings if "missing" in w]
    assert len(missing_warnings) == 1
    assert np.all(back.weights[:, INDEX["tongueOut"]] == 0)
    assert back.weights[0, INDEX["eyeBlinkRight"]] == pytest.approx(0.2)
    assert back.fps == 25.0
    np.testing.assert_allclose(back.timestamps, np.arange(5) / 25)


def test_split_halves_are_merged_by_mean(tmp_path):
    header = ["browInnerUp_L", "browInnerUp_R", "cheekPuff_L", "cheekPuff_R"]
    rows = [["0.2", "0.4", "1.0", "0.0"]]
    back = read_arkit_csv(write_rows(tmp_path / "ict.csv", header, rows))
    assert back.weights[0, INDEX["browInnerUp"]] == pytest.approx(0.3)
    assert back.weights[0, INDEX["cheekPuff"]] == pytest.approx(0.5)


def test_no_time_column_assumes_60_fps_with_a_warning(tmp_path):
    back = read_arkit_csv(write_rows(tmp_path / "x.csv", ["jawOpen"], [["0.1"], ["0.2"]]))
    assert back.fps == 60.0
    assert any("assuming 60 fps" in w for w in back.warnings)


def test_stdin_is_read_for_dash(monkeypatch):
    monkeypatch.setattr(sys, "stdin", io.StringIO("time,jawOpen\n0,0.5\n0.5,0.25\n"))
    back = read_arkit_csv("-")
    assert back.num_frames == 2
    assert back.fps == pytest.approx(2.0)


def test_timecodes_wrap_at_midnight(tmp_path):
    header = ["Timecode", "BlendshapeCount", "JawOpen"]
    rows = [["23:59:59:58.000", "61", "0.1"], ["23:59:59:59.000", "61", "0.2"],
            ["00:00:00:00.000", "61", "0.3"]]
    back = read_arkit_csv(write_rows(tmp_path / "wrap.csv", header, rows), fps=60)
    np.testing.assert_allclose(np.diff(back.timestamps), [1 / 60, 1 / 60])


# --------------------------------------------------------------------------- bad input


def bad_file(tmp_path, cell: str, line_of_bad: int = 3):
    header = ["time", "jawOpen", "eyeBlinkLeft"]
    rows = [[f"{i / 60:.6f}", "0.5", "0.25"] for i in range(4)]
    rows[line_of_bad - 2][1] = cell
    return write_rows(tmp_path / "bad.csv", header, rows)


@pytest.mark.parametrize("cell", ["nan", "NaN", "inf", "-inf", "", "abc", "0.5.1"])
def test_bad_cells_are_errors_with_the_line_number(tmp_path, cell):
    with pytest.raises(BadInputError, match=r"line 3, column 'jawOpen'"):
        read_arkit_csv(bad_file(tmp_path, cell))


def test_skip_policy_drops_bad_rows(tmp_path):
    back = read_arkit_csv(bad_file(tmp_path, "nan"), on_bad="skip")
    assert back.num_frames == 3
    assert back.skipped_rows == 1
    assert np.isfinite(back.weights).all()
    assert any("skipped 1" in w for w in back.warnings)


def test_hold_policy_repeats_the_previous_frame(tmp_path):
    header = ["time", "jawOpen", "eyeBlinkLeft"]
    rows = [["0", "0.1", "0.2"], ["0.1", "nan", "0.3"], ["0.2", "", "0.4"], ["0.3", "0.7", "x"]]
    back = read_arkit_csv(write_rows(tmp_path / "h.csv", header, rows), on_bad="hold")
    np.testing.assert_allclose(back.weight("jawOpen"), [0.1, 0.1, 0.1, 0.7], atol=1e-7)
    np.testing.assert_allclose(back.weight("eyeBlinkLeft"), [0.2, 0.3, 0.4, 0.4], atol=1e-7)
    assert back.repaired == 3


def test_hold_policy_uses_zero_before_the_first_good_value(tmp_path):
    header = ["time", "jawOpen"]
    rows = [["0", "nan"], ["0.1", "0.5"]]
    back = read_arkit_csv(write_rows(tmp_path / "h0.csv", header, rows), on_bad="hold")
    np.testing.assert_allclose(back.weight("jawOpen"), [0.0, 0.5])


def test_wrong_column_count_is_an_error_or_a_policy(tmp_path):
    path = tmp_path / "short.csv"
    path.write_text("time,jawOpen,eyeBlinkLeft\n0,0.1,0.2\n0.1,0.3\n0.2,0.5,0.6\n")
    with pytest.raises(BadInputError, match=r"line 3: expected 3 cells .* found 2"):
        read_arkit_csv(path)
    assert read_arkit_csv(path, on_bad="skip").num_frames == 2
    held = read_arkit_csv(path, on_bad="hold")
    assert held.num_frames == 3
    np.testing.assert_allclose(held.weight("jawOpen"), [0.1, 0.1, 0.5], atol=1e-7)
    np.testing.assert_allclose(held.timestamps, [0.0, 0.1, 0.2])
    assert any("held the previous frame for 1 row(s)" in w for w in held.warnings)


@pytest.mark.parametrize("sep", [";", "\t"])
def test_semicolon_and_tab_separated_files_with_decimal_commas(tmp_path, sep):
    path = tmp_path / "locale.csv"
    lines = [["time", "jawOpen", "eyeBlinkLeft"], ["0", "0,25", "1"], ["0,5", "0.75", "0,5"]]
    path.write_text("\n".join(sep.join(cells) for cells in lines) + "\n")
    back = read_arkit_csv(path)
    np.testing.assert_allclose(back.weight("jawOpen"), [0.25, 0.75], atol=1e-7)
    np.testing.assert_allclose(back.weight("eyeBlinkLeft"), [1.0, 0.5], atol=1e-7)
    np.testing.assert_allclose(back.timestamps, [0.0, 0.5])


def test_a_comma_in_the_header_keeps_commas_as_the_separator(tmp_path):
    path = tmp_path / "comma.csv"
    path.write_text("time,jawOpen,note;x\n0,0.5,a;b\n")  # semicolons inside cells
    back = read_arkit_csv(path)
    np.testing.assert_allclose(back.weight("jawOpen"), [0.5], atol=1e-7)
    assert back.columns_ignored == ["note;x"]


def test_trailing_comma_and_blank_lines_are_tolerated(tmp_path):
    path = tmp_path / "trail.csv"
    path.write_text("time,jawOpen\n0,0.1,\n\n0.1,0.2,\n")
    assert read_arkit_csv(path).num_frames == 2


def test_out_of_range_values_are_clamped_and_counted(tmp_path):
    header = ["time", "jawOpen", "eyeBlinkLeft"]
    rows = [["0", "1.2", "-0.1"], ["0.1", "0.5", "0.2"], ["0.2", "1.0000001", "0.3"]]
    back = read_arkit_csv(write_rows(tmp_path / "c.csv", header, rows))
    assert back.clamped == 3
    assert back.weights.min() >= 0 and back.weights.max() <= 1
    assert any("clamped 3" in w for w in back.warnings)


def test_time_going_backwards_is_an_error(tmp_path):
    header = ["time", "jawOpen"]
    rows = [["0", "0.1"], ["0.2", "0.1"], ["0.1", "0.1"]]
    with pytest.raises(BadInputError, match="line 4: expected time to increase"):
        read_arkit_csv(write_rows(tmp_path / "t.csv", header, rows))


def test_times_too_far_apart_to_tell_frames_apart_are_an_error(tmp_path):
    """Found by hypothesis: -2**53 s then -1, 0, 1 s increase, but from zero the last
    three round to one time (float64 has 53 bits), which once divided by zero."""
    header = ["time", "jawOpen"]
    rows = [["-9007199254740996.0", "0"], ["-1.0", "0"], ["0.0", "0"], ["1.0", "0"]]
    with pytest.raises(BadInputError, match="line 4: expected time to increase"):
        read_arkit_csv(write_rows(tmp_path / "far.csv", header, rows))
    rows[0][0] = "-3.0"  # the same steps at a sane scale are fine
    assert read_arkit_csv(write_rows(tmp_path / "near.csv", header, rows)).num_frames == 4


def test_times_that_overflow_are_an_error(tmp_path):
    """Found by hypothesis: a good time of 9e307 s after 0, with a bad first row held
    under ``hold``, was extrapolated and offset past the float range (an infinite time
    stamp was returned); times that overflow once offset from the first are refused."""
    header = ["time", "jawOpen", "eyeBlinkLeft"]
    rows = [["", "0.0", "0.0"], ["0.0"], ["8.98846567431158e+307"]]
    with pytest.raises(BadInputError, match="line 4: expected a time stamp within float"):
        read_arkit_csv(write_rows(tmp_path / "held.csv", header, rows), on_bad="hold")
    rows = [["-1.7e308", "0"], ["1.7e308", "0"]]
    with pytest.raises(BadInputError, match="line 3: expected a time stamp within float"):
        read_arkit_csv(write_rows(tmp_path / "far.csv", header[:2], rows))


def test_structural_errors(tmp_path):
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(BadInputError, match="empty file"):
        read_arkit_csv(empty)
    header_only = tmp_path / "header.csv"
    header_only.write_text("time,jawOpen\n")
    with pytest.raises(BadInputError, match="at least one frame"):
        read_arkit_csv(header_only)
    nonames = tmp_path / "nonames.csv"
    nonames.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(BadInputError, match="expected columns named after ARKit"):
        read_arkit_csv(nonames)
    dup = tmp_path / "dup.csv"
    dup.write_text("jawOpen,JawOpen\n0.1,0.2\n")
    with pytest.raises(BadInputError, match="appears twice"):
        read_arkit_csv(dup)
    binary = tmp_path / "bin.csv"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00")
    with pytest.raises(FileFormatError, match="UTF-8"):
        read_arkit_csv(binary)
    with pytest.raises(BadInputError, match="no such file"):
        read_arkit_csv(tmp_path / "missing.csv")
    with pytest.raises(BadInputError, match="on_bad"):
        read_arkit_csv(dup, on_bad="ignore")  # type: ignore[arg-type]


# --------------------------------------------------------------------------- processing


def test_resample_bridges_gaps_and_hits_the_grid():
    t = np.array([0.0, 0.1, 0.2, 0.5])  # a gap between 0.2 and 0.5
    w = np.zeros((4, 52), dtype=np.float32)
    w[:, INDEX["jawOpen"]] = [0.0, 0.1, 0.2, 0.5]
    s = ArkitStream(weights=w, timestamps=t, fps=10.0)
    r = resample(s, 20.0)
    assert r.num_frames == 11
    assert r.fps == 20.0
    np.testing.assert_allclose(r.weight("jawOpen"), np.arange(11) / 20, atol=1e-6)


def test_resample_unwraps_angles():
    s = make_stream(frames=3, fps=10.0)
    s.head_rotation = np.array([[3.1, 0, 0], [-3.1, 0, 0], [-3.0, 0, 0]], dtype=np.float32)
    r = resample(s, 20.0)
    # Half-way between 3.1 and -3.1 (across +-pi) is +-pi, not 0.
    assert abs(abs(r.head_rotation[1, 0]) - np.pi) < 1e-3


def test_smooth_reduces_jitter_and_keeps_range():
    rng = np.random.default_rng(2)
    s = make_stream(frames=600, fps=60.0)
    s.weights = np.clip(0.5 + 0.3 * rng.standard_normal((600, 52)), 0, 1).astype(np.float32)
    out = smooth(s, 0.05)
    assert np.diff(out.weights, axis=0).std() < 0.3 * np.diff(s.weights, axis=0).std()
    assert out.weights.min() >= 0 and out.weights.max() <= 1
    assert smooth(s, 0.0).weights is not s.weights
    with pytest.raises(BadInputError):
        smooth(s, -1.0)


def test_smoothing_a_rotation_across_the_half_turn_keeps_it_there():
    """A head yaw passing from +179 to -179 degrees was averaged to about 0 by --smooth,
    turning the head round for a few frames; resample already unwrapped it."""
    s = make_stream(frames=120, fps=60.0)
    yaw = np.radians(np.linspace(170.0, 190.0, 120))
    s.head_rotation = np.stack([np.angle(np.exp(1j * yaw)), np.zeros(120), np.zeros(120)],
                               axis=1).astype(np.float32)  # wrapped into (-pi, pi]
    assert s.head_rotation[:, 0].min() < -3.0 < 3.0 < s.head_rotation[:, 0].max()
    out = smooth(s, 0.05)
    # every frame still looks along the half turn, and the unwrapped track is kept smooth
    assert np.cos(out.head_rotation[:, 0]).max() < -0.95
    np.testing.assert_allclose(out.head_rotation[10:-10, 0], yaw[10:-10], atol=1e-3)
    assert np.abs(np.diff(out.head_rotation[:, 0])).max() < np.radians(1.0)


def test_between_selects_and_retimes():
    s = make_stream(frames=120, fps=60.0)
    part = s.between(0.5, 1.0)
    assert part.num_frames == 30
    assert part.timestamps[0] == 0.0
    np.testing.assert_array_equal(part.weights, s.weights[30:60])
    with pytest.raises(BadInputError, match=r"from 5\.0 s to 6\.0 s, found none"):
        s.between(5.0, 6.0)
    with pytest.raises(BadInputError, match=r"frames from 5\.0 s, found none \(the stream "
                       r"lasts 2\.000 s\)"):
        s.between(5.0)
    with pytest.raises(BadInputError, match=r"frames before 0\.0 s, found none"):
        s.between(end=0.0)


# --------------------------------------------------------------------------- real captures


@pytest.mark.shared_data
@pytest.mark.parametrize("name, frames", [("livelinkface_fearful.csv", 1846),
                                          ("livelinkface_happy.csv", 3046)])
def test_real_live_link_face_captures(shared_data, name, frames):
    s = read_arkit_csv(shared_data / "arkit" / name)
    assert s.weights.shape == (frames, 52)
    assert s.source_format == "livelinkface"
    assert s.nominal_fps == 60.0
    assert s.fps == pytest.approx(60.0, rel=0.01)
    assert s.duration == pytest.approx(frames / 60.0, rel=0.01)
    assert s.columns_missing == []
    assert s.head_rotation is not None and s.head_rotation.shape == (frames, 3)
    assert np.isfinite(s.weights).all()
    assert s.weights.max() > 0.2  # a real take moves the face


@pytest.mark.shared_data
def test_udp_order_file_matches_a_lookup_by_name(shared_data):
    path = shared_data / "arkit" / "llv_dao_udp_order.csv"
    s = read_arkit_csv(path)
    assert s.weights.shape == (180, 52)
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header = rows[0]
    for name in ("JawOpen", "JawLeft", "JawRight", "MouthLeft", "MouthRight"):
        raw = np.array([float(r[header.index(name)]) for r in rows[1:]], dtype=np.float32)
        np.testing.assert_array_equal(s.weight(name), np.clip(raw, 0, 1))
    # The UDP order puts JawLeft before JawRight, the app's CSV the other way round:
    assert header.index("JawLeft") < header.index("JawRight")


def test_a_gap_in_time_is_named_not_silently_bridged(tmp_path):
    """A take with an hour between two frames read as a 3604 s stream at 60 fps without a
    word, and animate would have interpolated 216,000 frames across the hour."""
    rows = ["time,jawOpen"] + [f"{i / 60:.6f},0.5" for i in range(60)]
    rows += [f"{3600 + i / 60:.6f},0.2" for i in range(60)]
    path = tmp_path / "joined.csv"
    path.write_text("\n".join(rows) + "\n")
    stream = read_arkit_csv(path)
    gaps = [w for w in stream.warnings if "gap" in w]
    assert gaps == ["1 gap(s) in time, the longest 3599 s after 0.983 s (line 62): animate "
                    "fills a gap with frames interpolated across it; --start/--end cut it "
                    "out"]
    assert stream.fps == 60.0
    # dropped frames (a step of a few frames) are not gaps
    rows = ["time,jawOpen"] + [f"{i / 60:.6f},0.5" for i in range(120) if i % 7]
    path.write_text("\n".join(rows) + "\n")
    assert not [w for w in read_arkit_csv(path).warnings if "gap" in w]


@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-be"])
def test_utf16_text_with_a_byte_order_mark_reads_as_utf8_does(tmp_path, encoding):
    """Excel's "Unicode text" export (UTF-16, tab-separated) was refused as binary data."""
    import codecs

    text = "Timecode\tJawOpen\tEyeBlinkLeft\n" + "".join(
        f"00:00:00:{i:02d}.000\t{i / 10:.1f}\t0\n" for i in range(10))
    path = tmp_path / "excel.csv"
    bom = codecs.BOM_UTF16_BE if encoding.endswith("be") else b""
    path.write_bytes(bom + text.encode(encoding))
    utf8 = tmp_path / "utf8.csv"
    utf8.write_text(text)
    a, b = read_arkit_csv(path), read_arkit_csv(utf8)
    np.testing.assert_array_equal(a.weights, b.weights)
    np.testing.assert_array_equal(a.timestamps, b.timestamps)
    path.write_bytes(text.encode("utf-16-le"))  # no mark: not told from binary data
    with pytest.raises(FileFormatError, match="UTF-16 with a byte-order mark"):
        read_arkit_csv(path)


def test_standard_input_is_decoded_as_a_file_is(monkeypatch):
    """``cat excel.csv | head360 animate ... --arkit -``: standard input was read as text
    in the locale's encoding, so a UTF-16 take failed on a header of NULs and escapes."""
    import io
    import sys

    text = "Timecode\tJawOpen\n" + "".join(f"00:00:00:{i:02d}.000\t0.5\n" for i in range(5))
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(text.encode("utf-16"))))
    stream = read_arkit_csv("-")
    assert stream.num_frames == 5 and stream.columns_found == ["jawOpen"]
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(b"\x89PNG\r\n\x1a\n\xff")))
    with pytest.raises(FileFormatError, match="'<stdin>', found binary data"):
        read_arkit_csv("-")


def test_old_mac_line_endings_read_as_the_others(tmp_path):
    """Excel for Mac's "CSV (Macintosh)" ends lines with a lone CR: the whole file read as
    one line, "new-line character seen in unquoted field"."""
    body = ["time,jawOpen,eyeBlinkLeft", "0,0.5,0", "0.1,0.6,0.2", "0.2,0.7,0"]
    streams = {}
    for name, end in (("lf", "\n"), ("crlf", "\r\n"), ("cr", "\r")):
        (tmp_path / f"{name}.csv").write_bytes(end.join(body).encode() + end.encode())
        streams[name] = read_arkit_csv(tmp_path / f"{name}.csv")
    for name in ("crlf", "cr"):
        np.testing.assert_array_equal(streams[name].weights, streams["lf"].weights)
        np.testing.assert_array_equal(streams[name].timestamps, streams["lf"].timestamps)
    assert streams["cr"].weights[1, INDEX["eyeBlinkLeft"]] == pytest.approx(0.2)


def _live_link_rows(seconds_and_frames) -> str:
    lines = ["Timecode,BlendshapeCount,EyeBlinkLeft,JawOpen"]
    for i, (sec, ff) in enumerate(seconds_and_frames):
        lines.append(f"14:58:{sec:02d}:{ff:02d}.668,61,0.1,{i / 100:.2f}")
    return "\n".join(lines) + "\n"


def test_a_live_link_take_within_one_second_warns_that_its_rate_is_unknown(tmp_path):
    """30 rows cut from a 60 fps take, frames 0 to 29 of one second, read as 30 fps and
    played at half speed without a word. The rate cannot be told from such timecodes:
    the reader says so, and the stream's rate, when given, reads it right."""
    within = tmp_path / "within.csv"
    within.write_text(_live_link_rows((3, ff) for ff in range(30)))
    s = read_arkit_csv(within)
    assert s.fps == 30.0 and s.timestamps[-1] == pytest.approx(29 / 30)
    assert [w for w in s.warnings if "does not tell its frame rate" in w] == [
        "the stream's timecodes stay within one second (frames 0 to 29), which does not "
        "tell its frame rate: read at 30 fps, the smallest standard rate above frame 29; "
        "if it was recorded at another rate (Live Link Face records at 60), give it with "
        "--stream-fps"]
    given = read_arkit_csv(within, fps=60)
    assert given.fps == 60.0 and given.timestamps[-1] == pytest.approx(29 / 60)
    assert not any("frame rate" in w for w in given.warnings)
    # the same 30 rows across a second show the rate's top frame: no doubt, no warning
    across = tmp_path / "across.csv"
    across.write_text(_live_link_rows([(2, ff) for ff in range(45, 60)]
                                      + [(3, ff) for ff in range(15)]))
    s = read_arkit_csv(across)
    assert s.fps == 60.0 and not any("frame rate" in w for w in s.warnings)


def test_head360_s_own_short_takes_read_back_without_the_rate_warning(tmp_path):
    """head360 numbers a short take's timecodes at a rate the reader infers back, in
    fractions of a frame: its times are known, so no rate warning."""
    stream = make_stream(frames=30, fps=60.0)
    path = tmp_path / "short.csv"
    write_arkit_csv(stream, path, flavor="livelinkface")
    back = read_arkit_csv(path)
    assert back.fps == 60.0
    assert not any("frame rate" in w for w in back.warnings)


def test_inspect_and_animate_take_the_stream_s_rate(run_cli, tmp_path):
    within = tmp_path / "within.csv"
    within.write_text(_live_link_rows((3, ff) for ff in range(30)))
    r = run_cli("inspect", within, "--json")
    assert r.code == 0 and "does not tell its frame rate" in r.err
    r = run_cli("inspect", within, "--stream-fps", "60", "--json")
    assert r.code == 0 and "frame rate" not in r.err
    import json

    assert json.loads(r.out)["fps"] == 60.0


def test_a_mediapipe_file_head360_writes_reads_back_without_warnings(tmp_path):
    """MediaPipe's face model scores 51 of the 52 shapes (no tongueOut): its layout, as
    head360 writes it, reads back as MediaPipe's, with nothing said about tongueOut; a
    file that lacks another shape still says so."""
    import numpy as np

    from head360cli.io.arkit import ArkitStream, read_arkit_csv, write_arkit_csv

    rng = np.random.default_rng(0)
    stream = ArkitStream(rng.uniform(0, 1, (12, 52)).astype(np.float32),
                         np.arange(12) / 30.0, 30.0)
    path = tmp_path / "mp.csv"
    write_arkit_csv(stream, path, flavor="mediapipe")
    back = read_arkit_csv(path)
    assert back.warnings == [] and back.source_format == "mediapipe"
    assert back.columns_missing == ["tongueOut"]
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    drop = header.index("jawOpen")
    cut = tmp_path / "cut.csv"
    cut.write_text("\n".join(",".join(c for i, c in enumerate(line.split(",")) if i != drop)
                             for line in lines) + "\n")
    warned = read_arkit_csv(cut).warnings
    assert any("blendshapes missing, set to zero: jawOpen" in w for w in warned)


@pytest.mark.parametrize("fps", [12.5, 24.0, 25.0, 29.97, 30.0, 60.0])
def test_takes_head360_writes_read_back_at_their_rate_without_warnings(tmp_path, fps):
    """Live Link Face timecodes carry no rate: a reader infers it from the largest frame
    number. head360 numbers a take at its own rate (or the standard one it divides) and
    starts a short take on the last frame of a second, so it reads back at its rate,
    with its times, unwarned, from 1 to 100 frames; the rate given as the warning once
    advised (--stream-fps) reads it the same."""
    import numpy as np

    from head360cli.io.arkit import ArkitStream, read_arkit_csv, write_arkit_csv

    for n in (1, 2, 3, 10, 12, 24, 25, 29, 30, 31, 59, 60, 61, 100):
        stream = ArkitStream(np.zeros((n, 52), np.float32), np.arange(n) / fps, fps)
        path = tmp_path / f"t{n}.csv"
        write_arkit_csv(stream, path)
        back = read_arkit_csv(path)
        assert back.warnings == [], (n, back.warnings)
        assert back.num_frames == n
        assert back.timestamps[-1] == pytest.approx((n - 1) / fps, abs=1e-3)
        if n > 1:  # one frame has no rate to read
            assert back.fps == pytest.approx(fps, rel=1e-3), n
            assert back.duration == pytest.approx(n / fps, abs=1e-3)
        if fps in (24.0, 25.0, 30.0, 60.0):
            again = read_arkit_csv(path, fps=fps)
            assert again.timestamps[-1] == pytest.approx((n - 1) / fps, abs=1e-3)
