"""ONE table of bad inputs across the commands (issue 17): each case runs ``staticdepth.cli.main``
in process and must exit 2 with exactly one non-empty stderr line ``staticdepth CMD: error: ...``
naming the path (or the option), no traceback, and nothing left behind in the data folder.

How the environment faults are made (the tests run as root, so folder permissions stop nothing):

- ``readonly``: an output under ``/sys``. sysfs refuses to create files even for root (EACCES), a
  real kernel refusal, like a folder the user may not write.
- ``erofs``: ``os.replace`` (the atomic rename every small output goes through) raises EROFS, as
  on a file system remounted read-only while the command ran.
- ``under-file``: an output whose parent is a regular file (``file/out.h5``): ENOTDIR.
- ``is-folder``: the output path is an existing folder.
- ``1x1``: a 1x1 PNG where an image is read (OpenCV asserts on it further in).
- ``damaged``: a copy of a sequence whose compressed ``left`` and ``depth`` chunks were
  overwritten in place (h5py raises OSError on read).
- ``state`` / ``binary-recipe``: a corrupt ``recipe_state.json``; a recipe that is binary junk.
- ``nonsense``: values that used to be accepted (camera height 0 or negative, NaN/inf/complex
  predictions, a corrupt frame in a capture replay).
"""
from __future__ import annotations

import errno
import json
import os
import shutil

import cv2
import h5py
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.h5 import add_prediction
from staticdepth.dataset.synth_io import render_to_file

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def _damage(src: str, dst: str) -> None:
    """Copy ``src`` (and its predictions) and overwrite the middle of every ``left`` and
    ``depth`` chunk."""
    shutil.copy(src, dst)
    if os.path.isdir(src + ".pred"):
        shutil.copytree(src + ".pred", dst + ".pred")
    with h5py.File(dst, "r") as f:
        chunks = [f[k].id.get_chunk_info(j) for k in ("left", "depth")
                  for j in range(f[k].id.get_num_chunks())]
    with open(dst, "r+b") as fh:
        for c in chunks:
            fh.seek(c.byte_offset + 8)
            fh.write(b"\xff" * max(1, c.size - 16))


@pytest.fixture(scope="module")
def d(tmp_path_factory):
    root = tmp_path_factory.mktemp("bad")
    p = {k: str(root / k) for k in ("seq.h5", "damaged.h5", "file", "folder", "one.png",
                                    "binary.yaml", "gt.npy", "nan.npy", "inf.npy", "complex.npy",
                                    "state.yaml", "cam.json", "plane.json", "pairs", "left.png",
                                    "right.png", "folder.npy", "empty.npy", "cut.npy",
                                    "pickled.npy", "obs.csv")}
    p["root"] = str(root)
    render_to_file(p["seq.h5"], preset_name="c1", n_frames=4, adapt_frames=2, seed=1,
                   overrides={"width": 64, "height": 32})
    from staticdepth.dataset.h5 import SequenceReader
    with SequenceReader(p["seq.h5"]) as r:
        gts = [r.depth(i) for i in range(len(r))]
    add_prediction(p["seq.h5"], "base", [g * 1.1 for g in gts])
    _damage(p["seq.h5"], p["damaged.h5"])
    open(p["file"], "w").write("a regular file\n")
    os.makedirs(p["folder"])
    cv2.imwrite(p["one.png"], np.full((1, 1, 3), 255, np.uint8))
    texture = (np.random.default_rng(0).random((64, 96, 3)) * 255).astype(np.uint8)
    cv2.imwrite(p["left.png"], texture)
    cv2.imwrite(p["right.png"], np.roll(texture, -4, axis=1))  # a rectified pair, disparity 4
    os.makedirs(p["folder.npy"])
    open(p["binary.yaml"], "wb").write(bytes(range(256)) * 8)
    gt = np.full((8, 8), 5.0)
    np.save(p["gt.npy"], gt)
    for name, value in (("nan.npy", np.nan), ("inf.npy", np.inf)):
        a = gt.copy()
        a[2, 3] = value
        np.save(p[name], a)
    np.save(p["complex.npy"], gt + 1j)
    open(p["empty.npy"], "wb").close()
    raw = open(p["gt.npy"], "rb").read()
    open(p["cut.npy"], "wb").write(raw[: len(raw) // 2])
    np.save(p["pickled.npy"], np.array([{"a": 1}], dtype=object), allow_pickle=True)
    open(p["obs.csv"], "w").write("frame,track,foot_u,foot_v,height_px\n")
    os.makedirs(root / "state")
    (root / "state" / "recipe_state.json").write_text('{"a": "12')
    open(p["state.yaml"], "w").write(
        f"name: s\nout_dir: {root / 'state'}\nstages:\n"
        f"  a: {{command: inspect, args: {{_: [{p['seq.h5']}]}}}}\n")
    json.dump({"fx": 40.0, "fy": 40.0, "cx": 3.5, "cy": 3.5, "width": 8, "height": 8},
              open(p["cam.json"], "w"))
    json.dump({"normal": [0.0, 0.8, 0.6], "horizon": [0, 1, 0]}, open(p["plane.json"], "w"))
    # a replay whose second left frame is corrupt
    from staticdepth.capture.sources.synthetic import SyntheticSource
    src = SyntheticSource(40, 20)
    for side in ("left", "right"):
        os.makedirs(os.path.join(p["pairs"], side))
    for k in range(3):
        left, right = src.make_pair(k)
        cv2.imwrite(os.path.join(p["pairs"], "left", f"{k:03d}.png"), left)
        cv2.imwrite(os.path.join(p["pairs"], "right", f"{k:03d}.png"), right)
    open(os.path.join(p["pairs"], "left", "001.png"), "wb").write(b"\x89PNG\r\n\x1a\n junk")
    return p


def _align(d, pred):
    return ["align", "--pred", d[pred], "--intrinsics", d["cam.json"], "--plane",
            d["plane.json"], "--ground-polygon", "0,4 7,4 7,7 0,7", "--out",
            os.path.join(d["root"], "aligned.npy")]


def _stereo(d, left, out):
    right = "right.png" if left == "left.png" else left
    return ["stereo", "--rectified", "--left", d[left], "--right", d[right], "--max-disparity",
            "16", "--disparity-out", out]


# (id, argv from the data paths, what the line must contain); ids start with the fault class
CASES = [
    ("readonly-synth", lambda d: ["synth", "--out", "/sys/sd-bad.h5", "--frames", "2"],
     "/sys/sd-bad.h5"),
    ("readonly-train-builtin", lambda d: ["train-builtin", "--out", "/sys/sd-bad.pt",
                                          "--frames", "2", "--epochs", "1", "--size", "64x32"],
     "/sys/sd-bad.pt: permission denied"),
    ("readonly-report", lambda d: ["report", d["seq.h5"], "--out", "/sys/sd-bad-report"],
     "/sys/sd-bad-report:"),
    ("readonly-capture", lambda d: ["capture", "--source", "synthetic", "--size", "32x16",
                                    "--frames", "1", "--out", "/sys/sd-bad-rec"],
     "/sys/sd-bad-rec:"),
    ("readonly-metrics-json", lambda d: ["metrics", "--pred", d["gt.npy"], "--gt", d["gt.npy"],
                                         "--json", "/sys/sd-bad.json"],
     "/sys/sd-bad.json: permission denied"),
    ("readonly-evaluate-json", lambda d: ["evaluate", d["seq.h5"], "--json", "/sys/sd-bad.json"],
     "/sys/sd-bad.json: permission denied"),
    ("erofs-metrics-json", lambda d: ["metrics", "--pred", d["gt.npy"], "--gt", d["gt.npy"],
                                      "--json", os.path.join(d["root"], "m.json")],
     "m.json: read-only file system"),
    ("erofs-evaluate-json", lambda d: ["evaluate", d["seq.h5"], "--json",
                                       os.path.join(d["root"], "e.json")],
     "e.json: read-only file system"),
    ("under-file-synth", lambda d: ["synth", "--out", d["file"] + "/x.h5", "--frames", "2"],
     "file"),
    ("under-file-capture", lambda d: ["capture", "--source", "synthetic", "--size", "32x16",
                                      "--frames", "1", "--out", d["file"] + "/rec"],
     "file/rec: a parent of the path is not a folder"),
    ("under-file-train-builtin", lambda d: ["train-builtin", "--out", d["file"] + "/b.pt",
                                            "--frames", "2", "--epochs", "1", "--size", "64x32"],
     "file: output's parent is not a folder"),
    ("under-file-metrics-json", lambda d: ["metrics", "--pred", d["gt.npy"], "--gt", d["gt.npy"],
                                           "--json", d["file"] + "/m.json"],
     "file: output's parent is not a folder"),
    ("under-file-report", lambda d: ["report", d["seq.h5"], "--out", d["file"] + "/rep"],
     "file/rep"),
    ("is-folder-metrics-json", lambda d: ["metrics", "--pred", d["gt.npy"], "--gt", d["gt.npy"],
                                          "--json", d["folder"]],
     "folder: is a folder, not a file"),
    ("is-folder-evaluate-json", lambda d: ["evaluate", d["seq.h5"], "--json", d["folder"]],
     "folder: is a folder, not a file"),
    ("is-folder-train-builtin", lambda d: ["train-builtin", "--out", d["folder"], "--frames", "2",
                                           "--epochs", "1", "--size", "64x32"],
     "folder: is a folder, not a file"),
    ("is-folder-report", lambda d: ["report", d["seq.h5"], "--out", d["file"]],
     "file"),
    ("is-folder-align", lambda d: _align(d, "gt.npy")[:-1] + [d["folder"]],
     "folder: is a folder, not a file"),
    ("is-folder-align-json", lambda d: _align(d, "gt.npy") + ["--json", d["folder"]],
     "folder: is a folder, not a file"),
    ("readonly-align", lambda d: _align(d, "gt.npy")[:-1] + ["/sys/sd-bad.npy"],
     "/sys/sd-bad.npy: permission denied"),
    ("readonly-stereo", lambda d: _stereo(d, "left.png", "/sys/sd-bad.npy"),
     "/sys/sd-bad.npy: permission denied"),
    ("is-folder-stereo", lambda d: _stereo(d, "left.png", d["folder.npy"]),
     "folder.npy: is a folder, not a file"),
    ("readonly-export", lambda d: ["export", d["seq.h5"], "--out", "/sys/sd-bad-export"],
     "/sys/sd-bad-export"),
    ("1x1-stereo", lambda d: _stereo(d, "one.png", os.path.join(d["root"], "disp.npy")),
     "one.png: image is 1x1: too small"),
    ("1x1-align-mask", lambda d: _align(d, "gt.npy")[:-4] + [
        "--ground-mask", d["one.png"], "--out", os.path.join(d["root"], "aligned.npy")],
     "one.png: prediction shape (8, 8) differs"),
    ("damaged-inspect", lambda d: ["inspect", d["damaged.h5"]],
     "damaged.h5: depth frame 0 is unreadable"),
    ("damaged-export", lambda d: ["export", d["damaged.h5"], "--out",
                                  os.path.join(d["root"], "export")],
     "damaged.h5: left frame 0 is unreadable"),
    ("damaged-evaluate", lambda d: ["evaluate", d["damaged.h5"]],
     "damaged.h5: depth frame 2 is unreadable"),
    ("state-run", lambda d: ["run", d["state.yaml"]],
     "recipe_state.json: corrupt recipe state"),
    ("binary-recipe-run", lambda d: ["run", d["binary.yaml"]],
     "binary.yaml: expected a text (UTF-8) YAML file, got binary data"),
    ("binary-recipe-adapt", lambda d: ["adapt", d["seq.h5"], "--recipe", d["binary.yaml"]],
     "binary.yaml: expected a text (UTF-8) YAML file, got binary data"),
    ("nonsense-kitti-height-0", lambda d: ["import-kitti", "--root", d["root"], "--drives", "x",
                                           "--out", os.path.join(d["root"], "k.h5"),
                                           "--camera-height", "0"],
     "--camera-height must be a height in metres in (0, 1000], got 0.0"),
    ("nonsense-kitti-height-negative", lambda d: ["import-kitti", "--root", d["root"], "--drives",
                                                  "x", "--out", os.path.join(d["root"], "k.h5"),
                                                  "--camera-height", "-1.65"],
     "got -1.65"),
    ("nonsense-kitti-height-nan", lambda d: ["import-kitti", "--root", d["root"], "--drives", "x",
                                             "--out", os.path.join(d["root"], "k.h5"),
                                             "--camera-height", "nan"],
     "got nan"),
    ("nonsense-pack-height-0", lambda d: ["pack", "--recording", d["pairs"], "--out",
                                          os.path.join(d["root"], "p.h5"), "--camera-height", "0"],
     "--camera-height must be a height in metres in (0, 1000], got 0.0"),
    ("nonsense-metrics-nan", lambda d: ["metrics", "--pred", d["nan.npy"], "--gt", d["gt.npy"]],
     "nan.npy: the prediction is NaN at 1 pixel(s) where the ground truth is valid"),
    ("nonsense-metrics-inf", lambda d: ["metrics", "--pred", d["inf.npy"], "--gt", d["gt.npy"]],
     "inf.npy: the prediction has 1 infinite pixel(s)"),
    ("nonsense-metrics-complex", lambda d: ["metrics", "--pred", d["complex.npy"], "--gt",
                                            d["gt.npy"]],
     "complex.npy: the array holds complex numbers"),
    ("nonsense-align-inf", lambda d: _align(d, "inf.npy"),
     "inf.npy: the prediction has 1 infinite pixel(s)"),
    ("nonsense-align-complex", lambda d: _align(d, "complex.npy"),
     "complex.npy: the prediction holds complex numbers"),
    ("nonsense-align-empty-npy", lambda d: _align(d, "empty.npy"),
     "empty.npy: not a readable .npy file"),
    ("nonsense-align-cut-npy", lambda d: _align(d, "cut.npy"),
     "cut.npy: not a readable .npy file"),
    ("nonsense-metrics-pickled-npy", lambda d: ["metrics", "--pred", d["pickled.npy"], "--gt",
                                                d["gt.npy"]],
     "pickled.npy: not a readable .npy file (it holds pickled Python objects"),
    ("nonsense-metrics-empty-gt", lambda d: ["metrics", "--pred", d["gt.npy"], "--gt",
                                             d["empty.npy"]],
     "empty.npy: not a readable .npy file"),
    *[(f"nonsense-ground-plane{opt}-{v}", lambda d, opt=opt, v=v: [
        "ground-plane", "--observations", d["obs.csv"], "--intrinsics", d["cam.json"], opt, v,
        "--out", os.path.join(d["root"], "plane-out.json")], f"{opt} must be")
      for opt, v in (("--agent-height", "nan"), ("--agent-height", "inf"), ("--radius", "nan"),
                     ("--radius", "-0.1"), ("--camera-height", "inf"), ("--bootstrap", "-1"),
                     ("--max-normal-std", "nan"), ("--column-weight", "inf"))],
    ("nonsense-ground-plane-radius-over-height", lambda d: [
        "ground-plane", "--observations", d["obs.csv"], "--intrinsics", d["cam.json"],
        "--model", "exact", "--radius", "2", "--out", os.path.join(d["root"], "plane-out.json")],
     "agent radius and head radius must be less than the agent height"),
    *[(f"nonsense-observations-sequence{opt}", lambda d, opt=opt: [
        "observations", d["seq.h5"], opt, "1", "--out", os.path.join(d["root"], "obs-out.csv")],
       f"{opt}: for a video only")
      for opt in ("--start", "--max-frames", "--step")],
    *[(f"nonsense-import-video{opt}-{v}", lambda d, opt=opt, v=v: [
        "import-video", d["pairs"] + "/right", opt, v, "--out", os.path.join(d["root"], "v.h5")],
       f"{opt} must") for opt, v in (("--width", "99999999"), ("--fps", "inf"))],
    ("nonsense-synth-seed", lambda d: ["synth", "--frames", "2", "--seed", "-1", "--out",
                                       os.path.join(d["root"], "s.h5")],
     "--seed must be a whole number in [0, 2^32), got -1"),
    ("nonsense-train-builtin-seed", lambda d: ["train-builtin", "--frames", "2", "--epochs", "1",
                                               "--size", "64x32", "--seed", "-1", "--out",
                                               os.path.join(d["root"], "b.pt")],
     "--seed must be a whole number in [0, 2^32), got -1"),
    ("nonsense-adapt-seed", lambda d: ["adapt", d["seq.h5"], "--model", "builtin:/nonexistent.pt",
                                       "--seed", "-1"],
     "finetune.seed must be a whole number in [0, 2^32), got -1"),
    ("nonsense-demo-var", lambda d: ["demo", "--out", os.path.join(d["root"], "demo"), "--var",
                                     "frames"], "--var expects key=value"),
    ("nonsense-observations-min-height", lambda d: [
        "observations", d["seq.h5"], "--min-height-px", "-1", "--out",
        os.path.join(d["root"], "obs-out.csv")], "--min-height-px must be"),
    ("nonsense-capture-corrupt-frame", lambda d: ["capture", "--source", "replay", "--input",
                                                  d["pairs"], "--out",
                                                  os.path.join(d["root"], "rec")],
     "001.png: corrupt or unreadable image"),
]


def _tree(root: str) -> set[str]:
    out = set()
    for dirpath, dirs, files in os.walk(root):
        out.update(os.path.relpath(os.path.join(dirpath, n), root) for n in dirs + files)
    return out


@pytest.mark.parametrize("argv_of, expected", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_is_one_line_exit_2(d, argv_of, expected, capsys, monkeypatch, request):
    if request.node.callspec.id.startswith("erofs"):
        def read_only(src, dst, *a, **k):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), dst)
        monkeypatch.setattr(os, "replace", read_only)
    argv = argv_of(d)
    before = _tree(d["root"])
    rc = main(argv)
    monkeypatch.undo()
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert lines[0].startswith(f"staticdepth {argv[0]}: error: "), lines[0]
    assert expected in lines[0], lines[0]
    left = {p for p in _tree(d["root"]) - before if not p.endswith(".lock")}
    if request.node.callspec.id == "nonsense-capture-corrupt-frame":
        # the frames before the corrupt one are kept, but never called complete
        manifest = json.load(open(os.path.join(d["root"], "rec", "manifest.json")))
        assert manifest["status"] == "failed"
        assert "001.png" in manifest["summary"]["detail"]
        assert manifest["summary"]["frames_written"] == 1
        shutil.rmtree(os.path.join(d["root"], "rec"))
        left = {p for p in left if p != "rec" and not p.startswith("rec" + os.sep)}
    assert not left, f"left behind: {sorted(left)}"


def test_a_cut_png_is_one_line_even_at_the_file_descriptor(d, tmp_path, capfd):
    """libpng printed "libpng error: PNG input buffer is incomplete" to fd 2 before the
    toolkit's own line (capsys does not see it; capfd does). A PNG with bytes after its end
    chunk still decodes."""
    raw = open(d["left.png"], "rb").read()
    cut = tmp_path / "cut.png"
    cut.write_bytes(raw[: len(raw) // 2])
    rc = main(_stereo({**d, "cut": str(cut)}, "cut", str(tmp_path / "disp.npy")))
    err = capfd.readouterr().err
    assert rc == 2 and err.strip().splitlines() == [
        f"staticdepth stereo: error: {cut}: corrupt or unreadable image (a PNG cut short: no "
        "IEND chunk)"], err
    tail = tmp_path / "tail.png"
    tail.write_bytes(raw + b"appended by some tool")
    from staticdepth.fileio import read_image
    assert np.array_equal(read_image(tail), read_image(d["left.png"]))


def test_a_binary_file_where_a_text_file_is_read_says_what_it_is(tmp_path, capsys):
    """A PNG given as a rig, camera, plane or recipe said "cannot read: 'utf-8' codec can't
    decode byte 0x89 in position 0: invalid start byte"; now it says what was expected and got."""
    import cv2

    from staticdepth.cli import main
    from staticdepth.config import load_yaml
    from staticdepth.errors import InputError
    from staticdepth.geometry.camera import read_json

    png = tmp_path / "g.png"
    cv2.imwrite(str(png), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(InputError) as e:
        read_json(png)
    assert str(e.value) == f"{png}: expected a JSON file, got a PNG image"
    with pytest.raises(InputError, match="expected a text \\(UTF-8\\) YAML file, got a PNG image"):
        load_yaml(png)
    np.save(tmp_path / "p.npy", np.ones((4, 4), np.float32))
    assert main(["align", "--pred", str(tmp_path / "p.npy"), "--intrinsics", str(png),
                 "--plane", str(png), "--ground-polygon", "0,3 3,3 3,0", "--out",
                 str(tmp_path / "o.npy")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "expected a JSON file, got a PNG image" in err, err
