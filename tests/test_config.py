"""Strict configuration loading."""
import re
from dataclasses import dataclass

import pytest

from staticdepth.config import (config_hash, format_config, from_dict, load_yaml, parse_set,
                                split_options)
from staticdepth.errors import InputError


@dataclass(frozen=True)
class Conf:
    epochs: int = 30
    lr: float = 1e-5
    size: tuple[int, int] = (384, 192)
    flip: bool = True
    model: str | None = None


def test_from_dict_converts_and_rejects_unknown_keys():
    c = from_dict(Conf, {"epochs": "5", "lr": "1e-4", "size": "256x128", "flip": "false"})
    assert c == Conf(epochs=5, lr=1e-4, size=(256, 128), flip=False)
    assert from_dict(Conf, {"model": "none"}).model is None
    with pytest.raises(InputError, match=r"unknown setting\(s\) \['epoch'\]"):
        from_dict(Conf, {"epoch": 3})
    with pytest.raises(InputError, match="expected int"):
        from_dict(Conf, {"epochs": "many"})
    with pytest.raises(InputError, match="expected bool"):
        from_dict(Conf, {"flip": "maybe"})
    base = Conf(epochs=7)
    assert from_dict(Conf, {"lr": 0.1}, base=base) == Conf(epochs=7, lr=0.1)


def test_config_hash_changes_with_values():
    assert config_hash(Conf()) == config_hash(Conf())
    assert config_hash(Conf()) != config_hash(Conf(epochs=29))


def test_load_yaml_errors(tmp_path):
    p = tmp_path / "r.yaml"
    p.write_text("a: [1, 2\n")
    with pytest.raises(InputError, match="not valid YAML"):
        load_yaml(p)
    p.write_text("- 1\n- 2\n")
    with pytest.raises(InputError, match="mapping"):
        load_yaml(p)
    p.write_text("name: K1\nstages: {import: {kind: kitti}}\n")
    assert load_yaml(p)["stages"]["import"]["kind"] == "kitti"


@dataclass(frozen=True)
class Inner:
    min_height_px: float = 20.0
    classes: frozenset = frozenset({0, 1})


@dataclass(frozen=True)
class Outer:
    model: str = "x"
    tracking: Inner = Inner()
    options: dict = None


def test_dotted_keys_nested_mappings_and_nearest_key():
    c = from_dict(Outer, parse_set(["tracking.min_height_px=8", "model=y"]))
    assert c == Outer(model="y", tracking=Inner(min_height_px=8.0))
    assert from_dict(Outer, {"tracking": {"classes": "3,1"}}).tracking.classes == {1, 3}
    base = Outer(tracking=Inner(min_height_px=5.0))
    assert from_dict(Outer, {"tracking.classes": [2]}, base=base).tracking == Inner(5.0, {2})
    with pytest.raises(InputError, match=r"\['min_height_px'\] for Outer: did you mean "
                                         r"'tracking.min_height_px'\?"):
        from_dict(Outer, {"min_height_px": 3})
    with pytest.raises(InputError, match="did you mean 'tracking.min_height_px'"):
        from_dict(Outer, {"tracking.min_heigth_px": 3})
    with pytest.raises(InputError, match="unknown setting.*'model.name'"):
        from_dict(Outer, {"model.name": 3})
    with pytest.raises(InputError, match="'tracking' is a group of settings"):
        from_dict(Outer, {"tracking": 3})
    for bad in ("novalue", "=3", "a..b=1"):
        with pytest.raises(InputError, match="--set expects key=value"):
            parse_set([bad])
    assert format_config(Outer()) == ("model: x\ntracking:\n  min_height_px: 20.0\n"
                                      "  classes: 0, 1\noptions: null")
    assert config_hash(Inner(classes=frozenset({1, 0}))) == config_hash(Inner())


def test_split_options_routes_fields_and_options():
    assert split_options(Outer, {"model": "m", "options.border": "full", "lr": "3"}) == (
        {"model": "m", "lr": "3"}, {"border": "full"})
    assert split_options(Outer, {"border": "none", "options.k": "3"}, strict=False) == (
        {}, {"border": "none", "k": 3})


def test_a_stage_version_reruns_that_stage_and_those_after_it(monkeypatch):
    """Raising a stage's method version (a code change that alters its output) changes its hash
    and its downstream stages' hashes, never an upstream one: outputs an older version wrote are
    not reused."""
    import staticdepth.adaptation.config as ac

    conf = ac.build_config({"model": "builtin", "pseudo_labels.source": "aligned"})
    before = ac.stage_hashes(conf)
    monkeypatch.setitem(ac.STAGE_VERSIONS, "pseudo_labels", ac.STAGE_VERSIONS["pseudo_labels"] + 1)
    after = ac.stage_hashes(conf)
    changed = {k for k in before if before[k] != after[k]}
    assert changed == {"pseudo_labels", "finetune", "ft", "align", "scale"}
    monkeypatch.setitem(ac.STAGE_VERSIONS, "ground_plane", ac.STAGE_VERSIONS["ground_plane"] + 1)
    again = ac.stage_hashes(conf)
    assert {k for k in after if after[k] != again[k]} == changed | {"ground_plane"}
    assert again["base"] == before["base"] and again["agents"] == before["agents"]


def test_a_known_camera_height_reruns_the_ground_plane():
    """A given camera height (or the sequence's, taken or not) enters the joint plane fit as a
    prior (adaptation.ground_plane.plane_config): the plane's hash and those after it change."""
    import staticdepth.adaptation.config as ac

    base = ac.stage_hashes(ac.build_config({"model": "builtin"}))
    for sets in ({"scale.camera_height_m": 5.0}, {"scale.sequence_height": False}):
        h = ac.stage_hashes(ac.build_config({"model": "builtin", **sets}))
        assert h["ground_plane"] != base["ground_plane"] and h["align"] != base["align"]
        assert h["agents"] == base["agents"] and h["base"] == base["base"]
    from staticdepth.adaptation.ground_plane import plane_config

    conf = ac.build_config({"model": "builtin", "detector.name": "motion"})
    assert plane_config(conf).known_height_m is None
    assert plane_config(conf, 5.0).known_height_m == 5.0 and plane_config(conf).classes == (0,)
    told = ac.build_config({"model": "builtin", "plane.known_height_m": 4.0})
    assert plane_config(told, 5.0).known_height_m == 4.0    # the plane's own setting wins


def _numeric_keys():
    import typing

    from staticdepth.adaptation.config import AdaptConfig
    from staticdepth.config import setting_keys

    out = []
    for k in setting_keys(AdaptConfig):
        cls = AdaptConfig
        for part in k.split(".")[:-1]:
            cls = typing.get_type_hints(cls)[part]
        t = str(typing.get_type_hints(cls)[k.split(".")[-1]])
        if "float" in t and "tuple" not in t:
            out.append(k)
    return out


def test_no_adapt_setting_takes_nan():
    """NaN passed every range check written as `x < 0` (tracking.min_iou=nan, plane.inlier_px=nan,
    finetune.grad_weight=nan ... were taken): the conversion refuses it for every float setting."""
    from staticdepth.adaptation.config import build_config

    keys = _numeric_keys()
    assert len(keys) > 30
    for k in keys:
        with pytest.raises(InputError, match=f"setting '{k}': NaN is no value"):
            build_config({k: "nan"})


@pytest.mark.parametrize("key,value,msg", [
    ("tracking.min_iou", "-1", "tracking.min_iou must be a finite number within 0..1, got -1.0"),
    ("tracking.min_frames", "0", "tracking.min_frames must be a finite number >= 1, got 0"),
    ("tracking.edge_px", "inf", "tracking.edge_px must be a finite number >= 0, got inf"),
    ("plane.inlier_px", "0", "plane.inlier_px must be a finite number > 0, got 0.0"),
    ("plane.ransac_iters", "-1", "plane.ransac_iters must be a finite number >= 1, got -1"),
    ("plane.max_roll_deg", "120", "plane.max_roll_deg must be at most 90, got 120.0"),
    ("plane.height_prior_weight", "inf", "plane.height_prior_weight must be a finite number"),
    ("finetune.grad_weight", "-1", "finetune.grad_weight must be a finite number >= 0"),
    ("finetune.weight_decay", "inf", "finetune.weight_decay must be a finite number >= 0"),
    ("pseudo_labels.accessory_reach", "-1", "pseudo_labels.accessory_reach must be a finite"),
])
def test_adapt_settings_out_of_range_name_themselves(key, value, msg):
    """Each was taken (build_config returned) before; the run then failed deep inside, or not."""
    from staticdepth.adaptation.config import build_config

    with pytest.raises(InputError, match=re.escape(msg)):
        build_config({key: value})


def test_unbounded_settings_still_take_inf():
    from staticdepth.adaptation.config import build_config

    conf = build_config({"tracking.max_step_rel": "inf", "plane.max_class_misfit_deg": "inf"})
    assert conf.tracking.max_step_rel == float("inf")
