"""Checks of the ``cycles`` profile's conventions against what a real Blender render must hold.

Used on the committed Cycles file (tests/io/data/cycles_32/, rendered by
data/recipes/cycles/render_cycles.py) and on a fresh render when ``bpy`` is available. The
ground truth is the scene itself (``scene.json``: the camera and the moving sphere), never the
file's own passes: world-space floor normals are (0, 0, 1), the distance along a camera ray is
``|P - camera|``, and the moving sphere's motion is where its surface points project in the
neighbouring frames.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
from scipy.ndimage import binary_erosion

from mcdenoise.io import load_buffers
from mcdenoise.io.exr import probe_exr, read_exr

LAYER = "ViewLayer"
PLAIN = "Layer2"


def raw_channels(path: Path) -> dict[str, np.ndarray]:
    """Every channel of every part of ``path``, as stored."""
    out: dict[str, np.ndarray] = {}
    for p in probe_exr(path):
        out.update(read_exr(path, part=p.index).pixels)
    return out


def load_facts(path: Path) -> dict:
    return json.loads(path.read_text())


def project(facts: dict, points: np.ndarray) -> np.ndarray:
    """Pixel coordinates (x right, y down, pixel centres at +0.5) of world points ``(3, ...)``."""
    m = np.array(facts["camera_matrix_world"])
    rot, cam = m[:3, :3], m[:3, 3]
    w, h = facts["resolution"]
    f = facts["camera_focal_px"]
    c = np.einsum("ji,j...->i...", rot, points - cam.reshape(3, *([1] * (points.ndim - 1))))
    return np.stack([w / 2 + f * c[0] / -c[2], h / 2 - f * c[1] / -c[2]])


def check_projection_matches_blender(facts: dict) -> None:
    """Our pinhole model reproduces bpy's own projection of the moving sphere's centre."""
    for frame, loc in zip(("1", "2", "3"), facts["mover_location"]):
        got = project(facts, np.array(loc, dtype=np.float64))
        np.testing.assert_allclose(got, facts["mover_pixel_xy_down"][frame], atol=1e-3)


def floor_pixels(raw: dict[str, np.ndarray]) -> np.ndarray:
    """Pixels whose first sample hit the floor (z = 0) in the bottom third of the image."""
    z = raw[f"{LAYER}.Position.Z"]
    depth = raw[f"{LAYER}.Depth.Z"]
    mask = (np.abs(z) < 1e-4) & (depth < 1e9)
    mask[: 2 * mask.shape[0] // 3] = False
    return mask


def check_conventions(path: Path, facts: dict, caplog) -> None:
    """Every convention the profile claims, on a real file of render_cycles.py's layout."""
    check_projection_matches_blender(facts)
    raw = raw_channels(path)
    spp = facts["files"][path.name]["spp"]
    with caplog.at_level(logging.WARNING, logger="mcdenoise"):
        fb = load_buffers(path)
    assert fb.profile == f"cycles:{LAYER}" and fb.spp == spp
    assert {"color", "albedo", "normal", "depth", "position", "motion", "motion_next"} <= set(
        fb.names()
    )

    m = np.array(facts["camera_matrix_world"])
    rot, cam = m[:3, :3], m[:3, 3]
    floor = floor_pixels(raw)
    assert floor.sum() >= 20

    # normal: the world-space Normal pass (floor = +Z), not the camera-space Denoising Normal.
    n = fb["normal"].numpy()
    np.testing.assert_allclose(
        n[:, floor], np.array([[0.0], [0.0], [1.0]]).repeat(floor.sum(), 1), atol=2e-3
    )
    # Denoising Normal, as Blender stores it, is camera space: x right, y up, z into the picture
    # (Blender's camera looks along its -Z, so z is flipped from Blender's camera axes).
    dn = np.stack([raw[f"{LAYER}.Denoising Normal.{c}"] for c in "XYZ"])
    want_cam = (rot.T @ np.array([0.0, 0.0, 1.0])) * np.array([1.0, 1.0, -1.0])
    np.testing.assert_allclose(dn[:, floor].mean(1), want_cam, atol=2e-3)

    # depth: distance along the camera ray (Denoising Depth), not the planar camera z.
    pos = np.stack([raw[f"{LAYER}.Position.{c}"] for c in "XYZ"]).astype(np.float64)
    ray = np.linalg.norm(pos - cam[:, None, None], axis=0)
    forward = -rot[:, 2]
    planar = np.einsum("i,ihw->hw", forward, pos - cam[:, None, None])
    d = fb["depth"].numpy()[0]
    assert np.median(np.abs(d - ray)[floor] / ray[floor]) < 0.04
    assert np.median(np.abs(d - planar)[floor] / planar[floor]) > 0.06
    # Blender's Depth pass is that planar z (first sample, like Position), 1e10 on background.
    hit = raw[f"{LAYER}.Depth.Z"] < 1e9
    np.testing.assert_allclose(raw[f"{LAYER}.Depth.Z"][hit], planar[hit], rtol=1e-4)
    # The top row is sky: no hit in any sample, depth 0 (canonical), Depth.Z 1e10 (Blender).
    assert np.all(raw[f"{LAYER}.Depth.Z"][0] >= 1e10) and np.all(d[0] == 0)
    np.testing.assert_array_equal(fb["position"].numpy(), pos.astype(np.float32))

    # motion: where the moving sphere's surface points were one frame before / will be after.
    loc = np.array(facts["mover_location"])
    on_mover = np.abs(np.linalg.norm(pos - loc[1][:, None, None], axis=0) - facts["mover_radius"])
    # Pixels inside the sphere's silhouette (their neighbours' first samples hit it too). At
    # 4 spp a few may still mix floor samples (motion 0) into Cycles' per-pixel average: they
    # are off by a multiple of 1/4 of the motion, so most pixels must match closely.
    inner = binary_erosion(on_mover < 0.01)
    assert inner.sum() >= 3
    cur = project(facts, pos)
    prev = project(facts, pos - (loc[1] - loc[0])[:, None, None])
    nxt = project(facts, pos + (loc[2] - loc[1])[:, None, None])
    mo, mn = fb["motion"].numpy(), fb["motion_next"].numpy()
    err = np.concatenate([mo - (prev - cur), mn - (nxt - cur)])[:, inner]
    good = np.all(np.abs(err) < 0.05, axis=0)
    assert good.mean() >= 0.6 and good.sum() >= 3, (good.mean(), np.abs(err).max(1))
    # The sphere moves right and up in the picture: to the previous frame is left and down.
    assert np.all(mo[0, inner] < 0) and np.all(mo[1, inner] > 0)
    assert np.all(mn[0, inner] > 0) and np.all(mn[1, inner] < 0)
    static = binary_erosion(hit & (on_mover > 0.05), iterations=2)  # away from the sphere
    assert static.sum() > 100
    assert np.abs(mo[:, static]).max() == 0.0

    # albedo above 1 where the light shows in the metal sphere: reported in one line, kept.
    alb = fb["albedo"].numpy()
    n_above = int((alb > 1).any(0).sum())
    assert n_above >= 1
    lines = [r.getMessage() for r in caplog.records if "albedo" in r.getMessage()]
    assert len(lines) == 1 and f"{n_above} pixel(s) above 1" in lines[0], lines
    assert float(alb.max()) > 1.5

    # The same layer through any of its parts: detection and spp from part 0 kept.
    for part in (f"{LAYER}.Combined", f"{LAYER}.Vector", LAYER, 0):
        via = load_buffers(path, part=part)
        assert via.profile == f"cycles:{LAYER}" and via.spp == spp and via.names() == fb.names()

    # The second layer: no denoising data; world normals, planar depth with 0 for no hit.
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="mcdenoise"):
        plain = load_buffers(path, profile=f"cycles:{PLAIN}")
    assert plain.profile == f"cycles:{PLAIN}" and plain.spp == spp
    assert plain.names() == ["color", "normal", "depth", "motion", "motion_next"]
    raw_z = raw[f"{PLAIN}.Depth.Z"]
    np.testing.assert_array_equal(plain["depth"].numpy()[0], np.where(raw_z >= 1e10, 0, raw_z))
    assert (raw_z >= 1e10).any()
    assert any("planar depth" in r.getMessage() for r in caplog.records)
    np.testing.assert_array_equal(
        plain["color"].numpy(), np.stack([raw[f"{PLAIN}.Combined.{c}"] for c in "RGB"])
    )
    assert not np.array_equal(plain["color"].numpy(), fb["color"].numpy())
    via = load_buffers(path, part=f"{PLAIN}.Combined")
    assert via.profile == f"cycles:{PLAIN}" and via.names() == plain.names()
