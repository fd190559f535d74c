"""Strict configuration loading."""
from dataclasses import dataclass

import pytest

from staticdepth.config import config_hash, from_dict, load_yaml
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
