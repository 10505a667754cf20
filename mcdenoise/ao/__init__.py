"""Screen-space ambient occlusion from a G-buffer: the approximations the thesis compares with
ray-traced AO (issue 25).

One method per module, each a plain function ``method(g, radius, **options) -> (H, W)`` over a
:class:`~mcdenoise.ao.geometry.ViewGBuffer` (view-space positions and normals rebuilt from depth,
normal and the camera by :func:`~mcdenoise.ao.geometry.view_gbuffer`), vectorised torch on any
device:

* :mod:`~mcdenoise.ao.ssao` — Crytek-style SSAO, normal-oriented hemisphere, range check;
* :mod:`~mcdenoise.ao.hbao` — horizon-based AO (Bavoil & Sainz 2008);
* :mod:`~mcdenoise.ao.alchemy` — Alchemy AO (McGuire et al. 2011) sampled as scalable AO (2012);
* :mod:`~mcdenoise.ao.gtao` — GTAO (Jimenez et al. 2016) after Intel's XeGTAO;
* :mod:`~mcdenoise.ao.blur` — the depth-aware blurs each method is published with.

All use the AO radius of the ray-traced reference and, by default, its step falloff. Like
``filters``, this package knows tensors only (no files, no registry); the registry methods
``ssao``, ``hbao``, ``alchemy`` and ``gtao`` are :mod:`mcdenoise.methods.ao`.
"""

from mcdenoise.ao.alchemy import alchemy
from mcdenoise.ao.geometry import ViewGBuffer, view_gbuffer
from mcdenoise.ao.gtao import gtao
from mcdenoise.ao.hbao import hbao
from mcdenoise.ao.ssao import ssao

#: Screen-space AO estimators by registry name.
ESTIMATORS = {"ssao": ssao, "hbao": hbao, "alchemy": alchemy, "gtao": gtao}

__all__ = ["ESTIMATORS", "ViewGBuffer", "alchemy", "gtao", "hbao", "ssao", "view_gbuffer"]
