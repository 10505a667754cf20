"""The packaged assets of the random scenes: meshes, image textures and the studio envmap.

They live in ``mcdenoise/render/assets/`` (made by ``assets/make_assets.py``) and are referred
to by absolute path in the specs.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

_ASSETS = "assets"


@dataclass(frozen=True)
class MeshAsset:
    """A packaged mesh: absolute ``file``, bounding-box ``half_extents`` (centred at the
    origin) and ``radius`` (largest vertex distance from the origin), in mesh units."""

    name: str
    file: str
    half_extents: tuple[float, float, float]
    radius: float


def asset_dir() -> Path:
    """Folder of the packaged assets (``meshes/``, ``textures/``, ``envmaps/``)."""
    return Path(str(resources.files("mcdenoise.render").joinpath(_ASSETS)))


@functools.cache
def mesh_assets() -> tuple[MeshAsset, ...]:
    """The packaged meshes, from ``assets/meshes/index.json`` (sorted by name)."""
    folder = asset_dir() / "meshes"
    index = json.loads((folder / "index.json").read_text(encoding="utf-8"))
    return tuple(
        MeshAsset(
            name=name,
            file=str((folder / name).resolve()),
            half_extents=tuple(float(x) for x in entry["half_extents"]),  # type: ignore[arg-type]
            radius=float(entry["radius"]),
        )
        for name, entry in sorted(index.items())
    )


def texture_files() -> tuple[str, ...]:
    """Absolute paths of the packaged image textures (sorted)."""
    return tuple(str(p.resolve()) for p in sorted((asset_dir() / "textures").glob("*.png")))


def envmap_file() -> str:
    """Absolute path of the packaged studio environment map."""
    return str((asset_dir() / "envmaps" / "studio.exr").resolve())
