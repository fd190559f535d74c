"""The prediction store: sidecar files beside the sequence, resume, identity, verify, publish."""
import os
import shutil

import h5py
import numpy as np
import pytest

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceReader, add_prediction
from staticdepth.dataset.predictions import (clean_store, prediction_names, prediction_path,
                                             prediction_writer, remove_prediction,
                                             verify_predictions, write_prediction)
from staticdepth.errors import InputError
from test_h5 import _write

MAPS = [np.full((32, 64), i + 0.5, np.float32) for i in range(5)]


def _maps(counter=None, fail_at=None):
    for i, m in enumerate(MAPS):
        if i == fail_at:
            raise RuntimeError("interrupted")
        if counter is not None:
            counter.append(i)
        yield m


def test_sidecar_file_round_trip_and_legacy_groups(tmp_path):
    p = tmp_path / "s.h5"
    _write(p)
    size = os.path.getsize(p)
    add_prediction(p, "base", MAPS, {"model": "x", "params": {"a": 1}, "config_hash": "h1"})
    assert os.path.getsize(p) == size                       # the sequence is not rewritten
    assert os.path.isfile(tmp_path / "s.h5.pred" / "base.h5")
    with h5py.File(p, "a") as f:                            # a legacy in-file prediction
        f.create_dataset("pred/old/depth", data=np.stack(MAPS) * 2)
        f.create_dataset("pred/base/depth", data=np.stack(MAPS) * 3)
        f["pred/old"].attrs["model"] = "legacy"
    with SequenceReader(p) as r:
        assert r.predictions() == ["base", "old"]
        np.testing.assert_array_equal(r.prediction("base", 3), MAPS[3])     # sidecar wins
        np.testing.assert_array_equal(r.prediction("old", 3), MAPS[3] * 2)
        a = r.prediction_attrs("base")
        assert a["model"] == "x" and a["config_hash"] == "h1" and a["complete"]
        assert a["sequence_id"] == r.sequence_id()
        assert r.prediction_attrs("old")["model"] == "legacy"
        with pytest.raises(InputError, match="no prediction 'nope'"):
            r.prediction("nope", 0)
    with pytest.raises(InputError, match="already exists"):
        add_prediction(p, "base", MAPS, overwrite=False)
    assert remove_prediction(p, "base")
    with SequenceReader(p) as r:                             # removed: the legacy group shows
        np.testing.assert_array_equal(r.prediction("base", 3), MAPS[3] * 3)
    with pytest.raises(InputError, match="bad prediction name"):
        add_prediction(p, "../x", MAPS)


def test_a_prediction_of_another_sequence_is_refused(tmp_path):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    _write(a)
    _write(b, rng=np.random.default_rng(7))
    add_prediction(a, "base", MAPS)
    os.makedirs(tmp_path / "b.h5.pred")
    shutil.copy(prediction_path(a, "base"), prediction_path(b, "base"))
    with SequenceReader(b) as r:
        assert "base" in r.predictions()
        with pytest.raises(InputError, match="belongs to another sequence"):
            r.prediction("base", 0)
    assert any("another sequence" in s for s in verify_predictions(b))


def test_interrupted_write_resumes_with_the_same_hash_only(tmp_path):
    p = tmp_path / "s.h5"
    _write(p)
    with pytest.raises(RuntimeError):
        write_prediction(p, "ft", _maps(fail_at=3), {"config_hash": "h1"})
    assert not os.path.exists(prediction_path(p, "ft"))
    assert os.path.exists(prediction_path(p, "ft") + ".partial")
    with SequenceReader(p) as r:
        assert "ft" not in r.predictions()
    written = []
    with SequenceReader(p) as r:
        w = prediction_writer(p, "ft", n=5, height=32, width=64, identity=r.sequence_id(),
                              config_hash="h1")
    with w:
        assert w.start == 3                  # frames 0..2 verified and kept
        for i in range(w.start, 5):
            written.append(i)
            w.write(i, MAPS[i])
    assert written == [3, 4]
    with SequenceReader(p) as r:
        np.testing.assert_array_equal(np.stack([r.prediction("ft", i) for i in range(5)]),
                                      np.stack(MAPS))
    # complete with the same hash: nothing to do
    with SequenceReader(p) as r:
        w = prediction_writer(p, "ft", n=5, height=32, width=64, identity=r.sequence_id(),
                              config_hash="h1")
    assert w.done
    # an interrupted write of another hash starts over; the complete file stays until replaced
    with pytest.raises(RuntimeError):
        write_prediction(p, "ft", _maps(fail_at=2), {"config_hash": "h2"})
    with pytest.raises(RuntimeError):
        write_prediction(p, "ft", _maps(fail_at=4), {"config_hash": "h3"})
    with h5py.File(prediction_path(p, "ft") + ".partial") as f:
        assert f.attrs["config_hash"] == "h3" and f.attrs["n_written"] == 4
    with SequenceReader(p) as r:
        assert r.prediction_attrs("ft")["config_hash"] == "h1"
    assert clean_store(p) == [prediction_path(p, "ft") + ".partial"]


def test_verify_finds_a_changed_frame_and_publish_ships_predictions(tmp_path, capsys):
    from staticdepth.dataset.publish import publish, verify_release

    p = tmp_path / "s.h5"
    _write(p)
    add_prediction(p, "base", MAPS)
    assert verify_predictions(p) == []
    rel = tmp_path / "rel"
    publish([p], rel, export=False)
    assert os.path.isfile(rel / "sequences" / "s.h5.pred" / "base.h5")
    assert "sequences/s.h5.pred/base.h5" in (rel / "MANIFEST.sha256").read_text()
    assert verify_release(rel) == []
    with h5py.File(prediction_path(p, "base"), "a") as f:
        f["depth"][2] = MAPS[2] + 1
    assert verify_predictions(p) == ["pred/base[2]: checksum mismatch"]
    assert main(["verify", str(p)]) == 2
    assert "pred/base[2]: checksum mismatch" in capsys.readouterr().out
    with pytest.raises(InputError, match="prediction fails verification"):
        publish([p], tmp_path / "rel2", export=False)


def test_overwriting_a_sequence_removes_only_predictions_it_cannot_read(tmp_path, capsys):
    # `synth --overwrite` left the replaced sequence's predictions beside the new file, which
    # verify then failed; a re-render of identical content keeps its predictions (they still fit)
    seq = tmp_path / "s.h5"
    args = ["synth", "--preset", "c1", "--frames", "3", "--adapt-frames", "1", "--set",
            "width=96", "--set", "height=48", "--out", str(seq)]
    assert main(args) == 0
    add_prediction(seq, "base", [np.ones((48, 96), np.float32)] * 3)
    assert main([*args, "--overwrite"]) == 0                      # the same content
    assert "removed the predictions" not in capsys.readouterr().out
    assert prediction_names(seq) == ["base"] and main(["verify", str(seq)]) == 0
    capsys.readouterr()
    assert main([*args, "--overwrite", "--seed", "3"]) == 0        # another sequence
    assert ("removed the predictions of the sequence this file replaced (another sequence's, "
            "unreadable with it): base") in capsys.readouterr().out
    assert prediction_names(seq) == [] and main(["verify", str(seq)]) == 0
