"""Scenes for the ``usdbtf build`` tests of bound meshes (issue 31): two synthetic materials
(``captures/pebbles`` and ``captures/moss``, 16-texel tiny samplings of 5 cm) and a build."""
from __future__ import annotations

from pathlib import Path

from usdbtf.cli import main
from usdbtf.usd.scenes.build import build


def build_scene(root: Path, text: str, **options):
    """Write the scene ``text`` in ``root`` beside the two synthetic captures it names, build it
    once (``options``: :func:`usdbtf.usd.scenes.build.build`'s, e.g. ``jobs``).  Returns (scene path, the
    build's report, the scene's bytes before the build)."""
    for preset, name in (("pebbles", "pebbles"), ("fuzzy_moss", "moss")):
        assert main(["synth", preset, "-o", str(root / "captures" / name), "--sampling", "tiny", "--size", "16",
                     "-q"]) == 0
    scene = root / "scene.usda"
    scene.write_text(text)
    before = scene.read_bytes()
    return scene, build(scene, **options), before


def open_stage(path):
    from pxr import Usd

    return Usd.Stage.Open(str(path))
