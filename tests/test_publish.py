"""Release folders: card contents, manifest, and verification of tampered releases."""
import json
import os

import h5py
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.dataset.publish import publish, sha256_file, verify_release
from staticdepth.errors import InputError
from test_export import make_sequence


@pytest.fixture
def release(tmp_path):
    frames_a = make_sequence(tmp_path / "A.h5", n=4, adapt=1, seed=1)
    make_sequence(tmp_path / "B.h5", n=3, adapt=2, seed=2, right=False)
    out = tmp_path / "rel"
    rc = main(["publish", str(tmp_path / "A.h5"), str(tmp_path / "B.h5"), "--out", str(out),
               "--licence", "CC-BY-4.0", "--citation", "Doe et al., 2025"])
    assert rc == 0
    return out, frames_a


def test_release_contents_and_card(release, capsys):
    out, frames = release
    assert sorted(os.listdir(out)) == ["MANIFEST.sha256", "README.md", "dataset_card.json",
                                       "kitti", "sequences"]
    card = json.loads((out / "dataset_card.json").read_text())
    assert card["licence"] == "CC-BY-4.0" and card["citation"] == "Doe et al., 2025"
    a, b = card["sequences"]
    assert a["name"] == "A" and a["frames"] == 4
    assert a["splits"] == {"adapt": [0, 1], "eval": [1, 4]}
    assert a["rig"]["baseline_m"] == pytest.approx(0.27) and a["camera_height_m"] == 5.0
    assert a["ground_truth"]["matcher"] == "sgbm" and b["rig"] is None
    dens = np.mean([np.isfinite(f["depth"]).mean() for f in frames])
    assert a["statistics"]["density_mean"] == pytest.approx(dens)
    stats = a["statistics"]
    assert stats["depth_min_m"] == pytest.approx(min(np.nanmin(f["depth"]) for f in frames))
    assert stats["depth_max_m"] == pytest.approx(max(np.nanmax(f["depth"]) for f in frames))
    md = (out / "README.md").read_text()
    assert "CC-BY-4.0" in md and "| A | 4 | 64x32 | 1 / 3 |" in md and "Doe et al." in md
    # every file is in the manifest with its SHA-256
    lines = (out / "MANIFEST.sha256").read_text().splitlines()
    listed = dict(reversed(l.split("  ", 1)) for l in lines)
    assert listed["sequences/A.h5"] == sha256_file(out / "sequences/A.h5")
    assert "kitti/B/proj_depth/groundtruth/image_02/0000000002.png" in listed
    with SequenceReader(out / "sequences/A.h5") as r:
        np.testing.assert_array_equal(r.left(3), frames[3]["left"])
    assert verify_release(out) == []
    assert main(["verify", str(out)]) == 0
    assert f"{out}: OK" in capsys.readouterr().out


def test_tampering_is_found(release, capsys):
    out, _ = release
    png = out / "kitti/A/image_02/data/0000000001.png"
    png.write_bytes(png.read_bytes()[:-10] + b"0123456789")
    (out / "extra.txt").write_text("hello")
    (out / "kitti/B/timestamps.txt").unlink()
    problems = verify_release(out)
    assert "kitti/A/image_02/data/0000000001.png: SHA-256 mismatch" in problems
    assert "extra.txt: not in the manifest" in problems
    assert "kitti/B/timestamps.txt: listed in the manifest but missing" in problems
    assert main(["verify", str(out)]) == 2
    assert "SHA-256 mismatch" in capsys.readouterr().out


def test_corrupted_sequence_and_manifest(release):
    out, _ = release
    # flip bytes inside a sequence file and re-hash it, so only the frame checksums can tell
    p = out / "sequences/B.h5"
    with h5py.File(p) as f:  # the stored bytes of frame 1's depth
        info = f["depth"].id.get_chunk_info(1)
    data = bytearray(p.read_bytes())
    off = info.byte_offset + info.size // 2
    data[off:off + 16] = bytes(16)
    p.write_bytes(bytes(data))
    lines = (out / "MANIFEST.sha256").read_text().splitlines()
    lines = [f"{sha256_file(p)}  sequences/B.h5" if l.endswith("sequences/B.h5") else l
             for l in lines] + ["garbage line"]
    (out / "MANIFEST.sha256").write_text("\n".join(lines) + "\n")
    problems = verify_release(out)
    assert any(l.startswith("sequences/B.h5: ") for l in problems), problems
    assert f"MANIFEST.sha256 line {len(lines)}: malformed" in problems
    (out / "MANIFEST.sha256").unlink()
    assert verify_release(out) == ["no MANIFEST.sha256 (not a release folder)"]


def test_publish_bad_input(tmp_path):
    make_sequence(tmp_path / "A.h5", n=2, adapt=1)
    (tmp_path / "x").mkdir()
    make_sequence(tmp_path / "x" / "A.h5", n=2, adapt=1)
    with pytest.raises(InputError, match="share the name 'A'"):
        publish([tmp_path / "A.h5", tmp_path / "x" / "A.h5"], tmp_path / "rel")
    with pytest.raises(InputError, match="exists already; pass --overwrite"):
        publish([tmp_path / "A.h5"], tmp_path / "x")
    (tmp_path / "bad.h5").write_bytes(b"nope")
    with pytest.raises(InputError, match="not a readable HDF5 file"):
        publish([tmp_path / "bad.h5"], tmp_path / "rel")
    assert not (tmp_path / "rel").exists()
    assert not [n for n in os.listdir(tmp_path) if "partial" in n]


def test_lock_files_are_not_shipped_listed_or_required(release):
    out, _ = release
    every = [os.path.relpath(os.path.join(d, n), out) for d, _, ns in os.walk(out) for n in ns]
    assert not [p for p in every if p.endswith(".lock")]  # the export's kitti/A.lock was
    manifest = (out / "MANIFEST.sha256").read_text()
    assert ".lock" not in manifest
    # a lock file that appears later (a writer locking a file of the release) is not "extra" ...
    (out / "sequences/A.h5.lock").write_text("")
    (out / "kitti/B.lock").write_text("12345")
    assert verify_release(out) == []
    # ... and one listed by an older release is not required
    empty = "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
    (out / "MANIFEST.sha256").write_text(manifest + f"{empty}  kitti/A.lock\n")
    assert verify_release(out) == []
    # a file that merely ends in .lock (nothing beside it of that name) is still checked
    (out / "notes.lock").write_text("x")
    assert verify_release(out) == ["notes.lock: not in the manifest"]


def test_card_escapes_names_and_notes_depth_beyond_the_export_range(tmp_path, capsys):
    from test_export import make_far_sequence

    import h5py

    from staticdepth.dataset.integrity import ATTRS_CRC, attrs_checksum

    name = "evil|<b>x</b>\n# injected"  # a name from an older file (the writers refuse it now)
    make_far_sequence(tmp_path / "E.h5")
    with h5py.File(tmp_path / "E.h5", "a") as f:       # as an older version wrote it
        f.attrs["name"] = name
        f.attrs[ATTRS_CRC] = attrs_checksum(f.attrs)
    out = tmp_path / "rel"
    assert main(["publish", str(tmp_path / "E.h5"), "--out", str(out),
                 "--title", "<script>x</script>"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == (
        f"warning: {out}/kitti/E: 5 depth pixel(s) beyond 255.996 m (the limit of KITTI's uint16 "
        "PNG, depth x 256) are stored as 0 (unknown)")
    md = (out / "README.md").read_text()
    lines = md.splitlines()
    safe = "evil|&lt;b&gt;x&lt;/b&gt; # injected"
    assert [l for l in lines if l.startswith("#")] == [
        "# &lt;script&gt;x&lt;/script&gt;", "## Sequences", f"### {safe}", "## Files",
        "## Citation"]
    rows = [l for l in lines if l.startswith("| ")]
    assert rows[1] == ("| evil\\|&lt;b&gt;x&lt;/b&gt; # injected | 2 | 64x32 | 1 / 1 | - | - | "
                       "synthetic | 1.000 | 20.00 - 10000.00 |")
    assert "<b>" not in md.split("## Sequences")[0] and "<script>" not in md
    assert (f"In the export of {safe}, 5 depth pixel(s) beyond 255.996 m (the limit of KITTI's "
            "uint16 PNG, depth x 256) are stored as 0 (unknown).") in lines
    card = json.loads((out / "dataset_card.json").read_text())
    assert card["sequences"][0]["name"] == name  # the JSON keeps the name as it is
    assert card["sequences"][0]["export_depth_beyond_range_px"] == 5


@pytest.mark.parametrize("argv", [["import-kitti", "--root", "R", "--drives", "x"],
                                  ["import-carla", "C"], ["pack", "--recording", "P"]])
def test_importers_refuse_a_name_of_more_than_one_line(argv, tmp_path, capsys):
    assert main(argv + ["--name", "evil\n# injected", "--out", str(tmp_path / "x.h5")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(
        "error: --name must be one line of printable text, got 'evil\\n# injected'")
    assert os.listdir(tmp_path) == []


def test_one_file_given_twice_is_named_and_a_shared_name_names_both_files(tmp_path, capsys):
    """'two input files share the name k' named no file, even when one file was given twice."""
    make_sequence(tmp_path / "A.h5", n=2, adapt=1)
    (tmp_path / "x").mkdir()
    make_sequence(tmp_path / "x" / "A.h5", n=2, adapt=1)
    a = str(tmp_path / "A.h5")
    assert main(["publish", a, a, "--out", str(tmp_path / "rel")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"staticdepth publish: error: {a}: is given twice (each sequence once)")
    b = str(tmp_path / "x" / "A.h5")
    assert main(["publish", a, b, "--out", str(tmp_path / "rel")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"staticdepth publish: error: two input files share the name 'A': {a} and {b} (a release "
        "names its sequences by file name: rename one)")
    assert not (tmp_path / "rel").exists()


@pytest.mark.parametrize("argv", [["publish", "{d}/A.h5"], ["export", "{d}/A.h5"],
                                  ["import-video", "{d}/v"], ["import-carla", "{d}/C"],
                                  ["synth", "--frames", "1"]])
def test_a_missing_output_folder_is_said_in_one_wording(argv, tmp_path, capsys):
    """publish and import-video said 'no such file or folder' (their lock's error), export
    "output folder's parent does not exist", the sequence writer "output folder does not
    exist": now one line from fileio.check_output_parent, naming the missing folder."""
    import cv2

    make_sequence(tmp_path / "A.h5", n=2, adapt=1)
    (tmp_path / "v").mkdir()
    cv2.imwrite(str(tmp_path / "v" / "0.png"), np.zeros((16, 16, 3), np.uint8))
    from test_carla import _export

    _export(tmp_path / "C", n=1)
    out = tmp_path / "nodir" / ("R" if argv[0] in ("publish", "export") else "s.h5")
    args = [a.format(d=tmp_path) for a in argv] + ["--out", str(out)]
    if argv[0] == "import-video":
        args += ["--fov-deg", "60"]
    before = sorted(os.listdir(tmp_path))
    assert main(args) == 2
    assert capsys.readouterr().err.strip().endswith(
        f"error: {tmp_path / 'nodir'}: output's parent does not exist (create that folder first)")
    assert sorted(os.listdir(tmp_path)) == before


@pytest.mark.parametrize("argv", [["import-kitti", "--root", "R", "--drives", "x"],
                                  ["import-carla", "C"], ["pack", "--recording", "P"],
                                  ["import-video", "V"], ["synth"]])
@pytest.mark.parametrize("name", ["x.png", "x", "x.h5.partial"])
def test_every_sequence_writer_refuses_an_out_not_ending_in_h5(argv, name, tmp_path, capsys):
    """import-kitti --out x.png wrote an HDF5 file named x.png."""
    out = tmp_path / name
    assert main(argv + ["--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(
        f"error: {out}: a sequence file's name must end in .h5 (--out)"), err
    assert os.listdir(tmp_path) == []


def test_an_out_not_ending_in_h5_that_is_a_foreign_file_is_said_to_be_left_untouched(tmp_path,
                                                                                      capsys):
    notes = tmp_path / "notes.txt"
    notes.write_text("precious")
    assert main(["synth", "--out", str(notes), "--overwrite"]) == 2
    assert "is not a readable HDF5 file" in capsys.readouterr().err
    assert notes.read_text() == "precious"


def test_a_failed_publish_or_export_leaves_no_lock_file(tmp_path, capsys):
    """REL.lock stayed beside a release that was never made (and after a failed export)."""
    (tmp_path / "bad.h5").write_bytes(b"nope")
    assert main(["publish", str(tmp_path / "bad.h5"), "--out", str(tmp_path / "REL")]) == 2
    assert main(["export", str(tmp_path / "bad.h5"), "--out", str(tmp_path / "E")]) == 2
    assert "not a readable HDF5 file" in capsys.readouterr().err
    assert os.listdir(tmp_path) == ["bad.h5"]
