"""The built-in synthetic fixed-camera scene: seeded, ray-cast stereo frames with exact geometry.

    from staticdepth.dataset.synth import SyntheticScene, preset
    scene = SyntheticScene(preset("c1", seed=0))
    frame = scene.render(0)   # left, right, depth, instances, agents, ...
"""
from staticdepth.dataset.synth.scene import (PRESETS, SceneConfig, SyntheticScene,  # noqa: F401
                                             config_from_dict, preset)
