"""Scene files -> validated `SceneSpec` (load.py), composed of each stage's params (spec.py)."""

from poevp_optics.core.exceptions import SceneError
from poevp_optics.scene.load import apply_overrides, load_scene, parse_override, resolve_scene_path
from poevp_optics.scene.spec import SceneSpec
__all__ = ["SceneError", "SceneSpec", "apply_overrides", "load_scene", "parse_override", "resolve_scene_path"]
