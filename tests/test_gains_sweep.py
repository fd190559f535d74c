"""benchmarks/gains_sweep.py: means, spreads and ratios over seeds, seeds split over files."""
import json
import os
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "benchmarks"))
import gains_sweep  # noqa: E402


def _table(base, ft_align):
    return {"table": {"base": {"all": base}, "ft-align": {"all": ft_align}}}


def _write(path, per_scene):
    path.write_text(json.dumps({"m": {s: _table(*v) for s, v in per_scene.items()}}))
    return str(path)


def test_means_spreads_and_ratios(tmp_path):
    a0 = _write(tmp_path / "a0.json", {"i1": (0.4, 0.10), "i2": (0.2, 0.05)})
    # seed 1 of setting a: its scenes in two files, joined with +
    a1 = (_write(tmp_path / "a1x.json", {"i1": (0.4, 0.14)}) + "+"
          + _write(tmp_path / "a1y.json", {"i2": (0.2, 0.07)}))
    b0 = _write(tmp_path / "b0.json", {"i1": (0.4, 0.20), "i2": (0.2, 0.10), "i3": (0.3, 0.1)})
    label_a, seeds_a = gains_sweep.parse_run(f"a={a0},{a1}")
    runs = {label_a: seeds_a, "b": gains_sweep.parse_run(f"b={b0}")[1]}
    lines = gains_sweep.summarise(runs, None, ["ft-align"], ["all"])
    # i3 is missing from setting a: only the common scenes count
    assert "mean over i1, i2;" in lines[0]
    # a: i1 mean 0.12 spread 0.04, i2 0.06 / 0.02; mean 0.09; ratios 0.3 and 0.3
    assert lines[1].split(": ", 1)[1] == ("i1 0.120 (0.040, 2)  i2 0.060 (0.020, 2) | "
                                          "mean 0.0900 ratio 0.300")
    assert lines[2].endswith("i1 0.200 (0.000, 1)  i2 0.100 (0.000, 1) | mean 0.1500 ratio 0.500")


def test_a_bad_file_is_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(SystemExit) as e:
        gains_sweep.main(["--run", f"x={bad}"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.startswith(f"{bad}: cannot read") and err.count("\n") == 1
    with pytest.raises(SystemExit) as e:
        gains_sweep.main(["--run", "no-label"])
    assert e.value.code == 2 and "LABEL=FILE" in capsys.readouterr().err
