"""spotlights.inputs: the one JSON reader of users' files and the one check that a path named inside a
dataset stays inside it."""

from __future__ import annotations

import os

import pytest

from spotlights.errors import InputFileError
from spotlights.inputs import path_inside, read_json


@pytest.fixture
def tree(tmp_path):
    """root/sub/in.bin inside; out.bin beside root; root/link.bin -> out.bin; root/dirlink -> tmp_path;
    root/inlink.bin -> root/sub/in.bin (a link that stays inside)."""
    root = tmp_path / "root"
    (root / "sub").mkdir(parents=True)
    (root / "sub" / "in.bin").write_bytes(b"")
    (tmp_path / "out.bin").write_bytes(b"")
    os.symlink(tmp_path / "out.bin", root / "link.bin")
    os.symlink(tmp_path, root / "dirlink")
    os.symlink(root / "sub" / "in.bin", root / "inlink.bin")
    return root


@pytest.mark.parametrize("name", ["sub/in.bin", "sub/../sub/in.bin", "inlink.bin", "sub/not-yet.bin"])
def test_names_inside_the_root_are_kept_as_written(tree, name):
    assert path_inside(tree, name, "index.json") == tree / name


@pytest.mark.parametrize(
    "name, why",
    [
        ("../out.bin", "leads outside"),
        ("sub/../../out.bin", "leads outside"),
        ("/etc/passwd", "is an absolute path"),
        ("link.bin", "through a symbolic link"),
        ("dirlink/out.bin", "through a symbolic link"),
        ("", "is not a relative path"),
        (5, "is not a relative path"),
        (None, "is not a relative path"),
        ("a\x00b", "is not a relative path"),
    ],
)
def test_names_leading_out_are_refused_naming_the_file_that_holds_them(tree, name, why):
    with pytest.raises(InputFileError, match=why) as err:
        path_inside(tree, name, "index.json", "shard file")
    assert str(err.value).startswith("index.json: shard file")


@pytest.mark.parametrize(
    "text, why",
    [
        ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
        ("[" + "9" * 5000 + "]", "thousands of digits"),
        ('{"a": ', "not valid JSON"),
        (b"\xff\xfe[1]", "not valid JSON"),
        ('{"center": [1' + "0" * 400 + ", 0, 0]}", r"an integer beyond 64 bits \(10000000000000000000\.\.\.\)"),
        ('{"frame_index": -9223372036854775809}', "beyond 64 bits"),  # one below int64's least
    ],
)
def test_read_json_refuses_every_fault_in_one_line(tmp_path, text, why):
    p = tmp_path / "f.json"
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(InputFileError, match=why) as err:
        read_json(p)
    assert str(err.value).startswith(str(p)) and "\n" not in str(err.value)


def test_read_json_reads_json_and_names_a_missing_file(tmp_path):
    (tmp_path / "ok.json").write_text('{"center": [1, 2.5, -3], "id": "汽车"}', encoding="utf-8")
    assert read_json(tmp_path / "ok.json") == {"center": [1, 2.5, -3], "id": "汽车"}
    (tmp_path / "ts.json").write_text('{"timestamp": 1700000000123456789, "least": -9223372036854775808}')
    assert read_json(tmp_path / "ts.json") == {"timestamp": 1700000000123456789, "least": -(2**63)}  # ns stay exact
    with pytest.raises(InputFileError, match="box file not found"):
        read_json(tmp_path / "nope.json", "box file")
    with pytest.raises(InputFileError, match="is not a file"):
        read_json(tmp_path)
