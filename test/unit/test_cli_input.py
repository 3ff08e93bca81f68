"""Bad command-line input to ``artcal``: broken frames are skipped, counted and named; a
recording broken part-way calibrates from its good part; every parameter with a wrong type
or value is refused with one line naming it and what it allows; no user mistake ends in a
traceback."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import pytest
import yaml

from artcal_ros.bag import BagMessage, BagReader, BagWriter
from artcal_ros.cli.main import main
from artcal_ros.core.images import image_to_numpy
from artcal_ros.core.params import PARAMETERS, allowed_text
from test.conftest import PARAMS_FILE, SAMPLE_BAG

IMAGE = "sensor_msgs/msg/Image"
TOPIC = "/camera/image_raw"


def sample_messages(n: int) -> list[BagMessage]:
    """``n`` frames spread over the sample recording."""
    with BagReader(SAMPLE_BAG) as r:
        every = list(r.messages(TOPIC))
    return every[:: len(every) // n][:n]


@pytest.fixture(scope="module")
def good_frames() -> list[BagMessage]:
    return sample_messages(6)


def weird_frame(stamp_ns: int) -> dict[str, Any]:
    return {"header": {"stamp": {"sec": stamp_ns // 10**9, "nanosec": stamp_ns % 10**9}},
            "height": 480, "width": 640, "encoding": "yuv_weird", "is_bigendian": 0,
            "step": 640, "data": bytes(640 * 480)}


def calibrate(args: list[str], capsys: pytest.CaptureFixture) -> tuple[int, str, str]:
    code = main(["calibrate", *args, "--params", str(PARAMS_FILE), "--quiet"])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


# -- broken frames ----------------------------------------------------------------------------


def test_a_bag_frame_in_an_unknown_encoding_is_skipped_counted_and_named(
        tmp_path: Path, good_frames: list[BagMessage],
        capsys: pytest.CaptureFixture) -> None:
    bag = tmp_path / "mixed"
    with BagWriter(bag) as w:
        for k, m in enumerate(good_frames):
            w.write(TOPIC, IMAGE, m.log_time_ns, m.data)
            if k == 2:
                w.write(TOPIC, IMAGE, m.log_time_ns + 1, weird_frame(m.log_time_ns + 1))
    out_file = tmp_path / "camera.yaml"
    code, out, err = calibrate(["--bag", str(bag), "--output", str(out_file),
                                "--max-frames", "0", "--time-budget", "0"], capsys)
    assert code == 0, err
    assert out_file.exists()
    assert "skipped 1 broken frame: 1 unknown encoding 'yuv_weird'" in out
    assert "skipped 1 broken frame" in err  # said while it runs, too


def test_a_bag_broken_part_way_calibrates_from_the_good_part_and_says_where(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    bag = tmp_path / "cut.mcap"
    frames = sample_messages(12)
    with BagWriter(bag, chunk_size=64 * 1024) as w:
        for m in frames:
            w.write(TOPIC, IMAGE, m.log_time_ns, m.data)
    size = bag.stat().st_size
    with open(bag, "r+b") as fh:
        fh.truncate(int(size * 0.6))
    out_file = tmp_path / "camera.yaml"
    code, _out, err = calibrate(["--bag", str(bag), "--output", str(out_file),
                                 "--max-frames", "0", "--time-budget", "0"], capsys)
    assert code == 0, err
    assert out_file.exists()
    assert f"warning: {bag}: truncated at byte offset" in err


@pytest.fixture(scope="module")
def good_pngs(tmp_path_factory: pytest.TempPathFactory,
              good_frames: list[BagMessage]) -> list[str]:
    folder = tmp_path_factory.mktemp("pngs")
    paths = []
    for k, m in enumerate(good_frames):
        path = folder / f"view{k}.png"
        cv2.imwrite(str(path), image_to_numpy(m.decode()))
        paths.append(str(path))
    return paths


def test_image_files_that_cannot_be_read_are_skipped_counted_and_named(
        tmp_path: Path, good_pngs: list[str], capsys: pytest.CaptureFixture) -> None:
    broken = tmp_path / "broken.png"
    broken.write_bytes(b"\x89PNG\r\n\x1a\n not really")
    missing = tmp_path / "missing.png"
    out_file = tmp_path / "camera.yaml"
    code, out, err = calibrate([*good_pngs, str(broken), str(missing), str(tmp_path),
                                "--output", str(out_file)], capsys)
    assert code == 0, err
    assert "skipped 3 broken frames: " in out
    assert f"1 cannot read image {broken}: not an image OpenCV can decode" in out
    assert f"1 cannot read image {missing}: no such file" in out
    assert f"1 cannot read image {tmp_path}: it is a directory" in out


def test_detect_skips_unreadable_images_and_names_them(
        tmp_path: Path, good_pngs: list[str], capsys: pytest.CaptureFixture) -> None:
    broken = tmp_path / "broken.jpg"
    broken.write_bytes(b"nope")
    out_json = tmp_path / "dets.json"
    code = main(["detect", good_pngs[0], str(broken), "--params", str(PARAMS_FILE),
                 "--json", str(out_json), "--quiet"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "in 1 image(s); skipped 1 broken frame: 1 cannot read image" in out
    assert len(yaml.safe_load(out_json.read_text())["images"]) == 1
    code = main(["detect", str(broken), "--json", str(out_json), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "no usable image: skipped 1 broken frame" in err


@pytest.mark.parametrize("what", ["missing file", "empty directory", "only broken frames"])
def test_nothing_usable_exits_2_with_the_reason(tmp_path: Path, what: str,
                                                capsys: pytest.CaptureFixture) -> None:
    if what == "missing file":
        args, says = [str(tmp_path / "nope.png")], "no such file"
    elif what == "empty directory":
        (tmp_path / "frames").mkdir()
        args, says = [str(tmp_path / "frames")], "it is a directory (with no image files in it)"
    else:
        bag = tmp_path / "weird"
        with BagWriter(bag) as w:
            w.write(TOPIC, IMAGE, 1, weird_frame(1))
        args, says = ["--bag", str(bag)], "1 unknown encoding 'yuv_weird'"
    code, _out, err = calibrate([*args, "--output", str(tmp_path / "c.yaml")], capsys)
    assert code == 2
    assert "no usable frame: skipped 1 broken frame" in err and says in err
    assert len(err.strip().splitlines()) == 1


def test_a_topic_not_in_the_bag_lists_the_topics_with_types(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    code, _out, err = calibrate(["--bag", str(SAMPLE_BAG), "--topic", "/nope", "--output",
                                 str(tmp_path / "c.yaml")], capsys)
    assert code == 2
    assert f"--topic /nope: not in {SAMPLE_BAG} (topics: {TOPIC} ({IMAGE}))" in err


def test_an_unwritable_output_exits_2_naming_the_path_and_the_reason(
        tmp_path: Path, good_pngs: list[str], capsys: pytest.CaptureFixture) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    target = blocker / "sub" / "camera.yaml"
    code, _out, err = calibrate([*good_pngs, "--output", str(target)], capsys)
    assert code == 2
    assert f"--output {target}: cannot write it: {blocker} is not a directory" in err


# -- parameters, table-driven over every one --------------------------------------------------


def wrong_values(spec: Any) -> list[Any]:
    """Values of the wrong type and, where the parameter has a range, out of it."""
    kind = type(spec.default)
    if kind is bool:
        return ["maybe", 3]
    if spec.choices:
        return ["bogus", [1, 2]]
    if kind is int:
        low = {"_positive": 0, "_non_negative": -1}[spec.check.__name__]
        return ["many", 2.5, ".inf", low]
    if kind is float:
        return ["far", ".nan", -0.5]
    if spec.name == "board.dictionary":
        return ["DICT_FOO", [1]]
    if spec.name == "camera_name":
        return ["''", [1]]
    return [[1, 2]]


@pytest.mark.parametrize("spec", PARAMETERS, ids=[s.name for s in PARAMETERS])
def test_every_parameter_refuses_a_wrong_type_or_value_naming_what_it_allows(
        spec: Any, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    for value in wrong_values(spec):
        text = value if isinstance(value, str) else yaml.safe_dump(value,
                                                                   default_flow_style=True)
        params = tmp_path / "p.yaml"
        params.write_text(yaml.safe_dump(
            {"/**": {"ros__parameters": {spec.name: yaml.safe_load(text)}}}))
        for how in (["--set", f"{spec.name}={text.strip()}"], ["--params", str(params)]):
            code = main(["calibrate", "x.png", *how])
            err = capsys.readouterr().err
            assert code == 2, (spec.name, value, how)
            assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
            assert f"parameter '{spec.name}'" in err, err
            said = (allowed_text(spec), spec.allowed, "must be > 0", "must be >= 0",
                    "not one of", "must not be empty", "allowed: DICT_4X4_")
            assert any(s and s in err for s in said), err


def test_every_parameter_says_what_it_allows() -> None:
    for spec in PARAMETERS:
        text = allowed_text(spec)
        if spec.choices:
            assert all(c in text for c in spec.choices)
        elif isinstance(spec.default, bool):
            assert text == "true or false"
        elif isinstance(spec.default, int | float):
            assert text.startswith(("an integer >", "a number >")), spec.name
        elif spec.name != "board.dictionary":  # its check lists the dictionaries
            assert spec.allowed, spec.name


def test_an_empty_yaml_value_for_output_file_means_the_default(tmp_path: Path) -> None:
    from artcal_ros.core.params import load_params, output_path

    params = tmp_path / "p.yaml"
    params.write_text("/**:\n  ros__parameters:\n    output_file:\n")
    assert output_path(load_params(params)).name == "camera.yaml"


# -- file names: wildcards, folders, a line per image ------------------------------------------


@pytest.mark.parametrize("verb", ["calibrate", "detect"])
def test_a_wildcard_matching_nothing_is_named_not_called_a_broken_frame(
        tmp_path: Path, verb: str, capsys: pytest.CaptureFixture) -> None:
    out = ["--output", str(tmp_path / "c.yaml")] if verb == "calibrate" else [
        "--json", str(tmp_path / "d.json")]
    code = main([verb, "/nonexistent/frames/*.png", *out, "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert "no file matches /nonexistent/frames/*.png" in err
    assert "broken" not in err and "cannot read image" not in err
    assert len(err.strip().splitlines()) == 1


def test_a_quoted_wildcard_is_expanded_in_order(tmp_path: Path, good_pngs: list[str],
                                                capsys: pytest.CaptureFixture) -> None:
    folder = Path(good_pngs[0]).parent
    out_json = tmp_path / "d.json"
    assert main(["detect", str(folder / "view*.png"), "--params", str(PARAMS_FILE),
                 "--json", str(out_json), "--quiet"]) == 0
    files = [r["file"] for r in yaml.safe_load(out_json.read_text())["images"]]
    assert files == sorted(good_pngs)


def test_a_folder_hint_names_the_image_files_it_holds(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(3):
        (folder / f"left{k}.jpg").write_bytes(b"")
    (folder / "notes.txt").write_text("not an image")
    code, _out, err = calibrate([str(folder), "--output", str(tmp_path / "c.yaml")], capsys)
    assert code == 2
    assert f"give the image files in it, e.g. {folder / '*.jpg'}" in err
    assert "*.png" not in err and "*.txt" not in err


def test_detect_prints_a_line_per_image_unless_quiet(tmp_path: Path, good_pngs: list[str],
                                                    capsys: pytest.CaptureFixture) -> None:
    missing = tmp_path / "missing.png"
    args = ["detect", *good_pngs[:2], str(missing), "--params", str(PARAMS_FILE),
            "--json", str(tmp_path / "d.json")]
    assert main(args) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 4
    for path, line in zip(good_pngs[:2], lines, strict=False):
        assert line.startswith(f"{path}: ") and line.endswith(" markers")
        assert int(line.split(": ")[1].split()[0]) > 0
    assert lines[2] == f"cannot read image {missing}: no such file"
    assert lines[3].startswith("wrote ") and "in 2 image(s)" in lines[3]
    assert main([*args, "--quiet"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("wrote ")
