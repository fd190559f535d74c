"""``timestamps.txt`` of a KITTI-style export: the times as recorded, at one fixed precision that
float64 holds (no float noise in the last digits)."""
import numpy as np

from staticdepth.cli import main
from staticdepth.dataset.h5 import SequenceMeta, SequenceWriter
from staticdepth.geometry import Camera

CAM = Camera.from_intrinsics(20.0, 20.0, 7.5, 3.5, 16, 8)
# KITTI 2011_09_26 timestamps.txt lines, as import-kitti stores them (float64 epoch seconds)
KITTI = ["2011-09-26 13:02:25.964389445", "2011-09-26 13:02:26.067888934",
         "2011-09-26 13:02:26.171468896"]


def _export_times(tmp_path, times) -> list[str]:
    seq, out = tmp_path / "s.h5", tmp_path / "export"
    meta = SequenceMeta(name="s", camera=CAM, gt_kind="none", source="test", adapt_frames=1)
    with SequenceWriter(seq, meta, ("left",)) as w:
        for t in times:
            w.append(timestamp=t, left=np.zeros((8, 16, 3), np.uint8))
    assert main(["export", str(seq), "--out", str(out)]) == 0
    return (out / "timestamps.txt").read_text().splitlines()


def test_epoch_times_are_written_to_the_microsecond_they_hold(tmp_path):
    times = [np.datetime64(s.replace(" ", "T"), "ns").astype(np.int64) / 1e9 for s in KITTI]
    assert f"{times[0]:.9f}" == "1317042145.964389324"      # nanoseconds float64 cannot hold
    lines = _export_times(tmp_path, times)
    assert lines == ["1317042145.964389", "1317042146.067889", "1317042146.171469"]
    assert [round(float(s), 6) for s in lines] == [round(t, 6) for t in times]


def test_frame_rate_times_are_written_to_the_nanosecond(tmp_path):
    times = [i * 0.1 for i in range(4)] + [1 / 30]            # 3 * 0.1 = 0.30000000000000004
    assert times[3] != 0.3
    lines = _export_times(tmp_path, times)
    assert lines == ["0.000000000", "0.100000000", "0.200000000", "0.300000000", "0.033333333"]


def test_decimals_follow_the_largest_time():
    from staticdepth.dataset.export import timestamp_decimals

    assert timestamp_decimals(np.array([0.0, 1e3])) == 9
    assert timestamp_decimals(np.array([1.3e9, 0.5])) == 6
    assert timestamp_decimals(np.array([np.nan, 2.0])) == 9
    assert timestamp_decimals(np.array([])) == 9
