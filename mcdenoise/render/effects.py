"""From a scene's declared effects to what is simulated: the effect plan.

The renderer simulates, and pays for, only the light transport a spec declares. The rules,
checked both ways (a declared effect the scene lacks the means for is an error, and so is
content that produces an effect the spec does not declare, so no effect is a silent no-op):

=========  ===================================================================================
effect     what it switches
=========  ===================================================================================
ao         ambient occlusion instead of lighting: the ``mcd_ao`` integrator (one occlusion ray
           per sample, ``render.ao_radius`` required), no materials or lights involved; the
           feature buffers are the geometric ones (normal, depth, position). Excludes
           direct/indirect/glossy/caustics.
direct     light reaching a visible surface straight from a light: path depth 2 (camera ->
           surface -> light). Needs a light (a ``[[lights]]`` entry or an emissive object).
indirect   full paths up to ``render.max_depth`` (default 8) with Russian roulette.
glossy     the scene has glossy materials (rough plastic/conductor/glass); declared iff present.
caustics   light through specular chains onto diffuse/glossy surfaces (needs ``indirect``, a
           smooth specular object and a light). Without it, a scene with specular objects and
           ``indirect`` is rendered by ``mcd_path`` with ``caustics = false``: a path stops at a
           delta bounce that follows a diffuse/glossy one, so those chains cost nothing.
dof        thin-lens depth of field; declared iff the camera is ``thinlens``. Without it the
           pinhole camera samples no lens.
=========  ===================================================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mcdenoise.render.scene_spec import SceneSpec, SpecError

#: Feature buffers written for a lit scene and for an AO scene (each with its ``_var``).
LIT_FEATURES: tuple[str, ...] = ("albedo", "normal", "depth", "position")
AO_FEATURES: tuple[str, ...] = ("normal", "depth", "position")
#: Path depth of direct lighting only (Mitsuba's convention: camera -> surface -> light).
DIRECT_DEPTH = 2


@dataclass(frozen=True)
class EffectPlan:
    """What a render of one spec simulates.

    Attributes:
        effects: the declared effects.
        integrator: ``"path"`` (Mitsuba's), ``"mcd_path"`` (ours, without caustics) or
            ``"mcd_ao"`` (ours).
        max_depth: longest path (2 = direct only); ``None`` for AO.
        rr_depth: Russian roulette starts at this depth.
        caustics: specular chains after a diffuse/glossy bounce are simulated.
        thinlens: the camera samples a lens (depth of field).
        ao_radius: occlusion distance for AO.
        features: feature buffers written (each also with its variance).
    """

    effects: tuple[str, ...]
    integrator: str
    max_depth: int | None
    rr_depth: int
    caustics: bool
    thinlens: bool
    ao_radius: float | None
    features: tuple[str, ...]

    def integrator_dict(self) -> dict[str, Any]:
        """The Mitsuba dict of the radiance integrator (``mcd_*`` need
        :func:`mcdenoise.render.integrators.register_integrators` first)."""
        if self.integrator == "mcd_ao":
            return {"type": "mcd_ao", "radius": float(self.ao_radius or 1.0)}
        d: dict[str, Any] = {
            "type": self.integrator,
            "max_depth": int(self.max_depth or DIRECT_DEPTH),
            "rr_depth": int(self.rr_depth),
        }
        if self.integrator == "mcd_path":
            d["caustics"] = self.caustics
        return d

    def describe(self) -> str:
        """One line for logs and manifests."""
        if self.integrator == "mcd_ao":
            what = f"AO radius {self.ao_radius:g}"
        else:
            depth = "direct only" if self.max_depth == DIRECT_DEPTH else f"depth {self.max_depth}"
            what = f"{self.integrator} {depth}, caustics {'on' if self.caustics else 'off'}"
        lens = ", thin lens" if self.thinlens else ""
        return f"{what}{lens}; features {', '.join(self.features)}"


def plan_effects(spec: SceneSpec) -> EffectPlan:
    """Check that ``spec``'s effects and content agree, and return what to simulate.

    Raises:
        SpecError: naming the effect and what the scene lacks (or has undeclared).
    """
    eff = set(spec.effects)
    where = spec.source or spec.name

    def fail(msg: str) -> SpecError:
        return SpecError(f"{where}: effects: {msg}")

    thinlens = spec.camera.type == "thinlens"
    if "dof" in eff and not thinlens:
        raise fail(
            "'dof' needs a thin-lens camera (camera.type = \"thinlens\" with aperture_radius "
            "and focus_distance); this camera is a pinhole"
        )
    if thinlens and "dof" not in eff:
        raise fail("the camera is a thin lens but 'dof' is not declared (add it or use a pinhole)")

    if "ao" in eff:
        clash = sorted(eff & {"direct", "indirect", "glossy", "caustics"})
        if clash:
            raise fail(f"'ao' renders occlusion, not lighting: it excludes {', '.join(clash)}")
        if spec.render.ao_radius is None:
            raise fail("'ao' needs render.ao_radius (the occlusion distance)")
        return EffectPlan(
            effects=spec.effects,
            integrator="mcd_ao",
            max_depth=None,
            rr_depth=spec.render.rr_depth,
            caustics=False,
            thinlens=thinlens,
            ao_radius=spec.render.ao_radius,
            features=AO_FEATURES,
        )

    if "direct" not in eff:
        raise fail("a lit scene needs 'direct' (or declare 'ao' for ambient occlusion)")
    if not spec.has_lights:
        raise fail("'direct' needs a light: a [[lights]] entry or an object with emission")

    materials = [o.material for o in spec.objects]
    glossy = [o for o in spec.objects if o.material.glossy]
    if "glossy" in eff and not glossy:
        raise fail(
            "'glossy' is declared but no object has a glossy material "
            "(roughplastic, roughconductor, rough dielectric)"
        )
    if glossy and "glossy" not in eff:
        names = sorted({o.material_name or o.material.type for o in glossy})
        raise fail(f"glossy material(s) {', '.join(names)} present but 'glossy' is not declared")

    specular = any(m.specular_lobe for m in materials)
    indirect = "indirect" in eff
    if "caustics" in eff:
        if not indirect:
            raise fail("'caustics' needs 'indirect' (a caustic is at least a 3-vertex path)")
        if not specular:
            raise fail(
                "'caustics' needs a smooth specular object (dielectric with roughness 0, "
                "conductor or plastic) to focus light"
            )
    caustics = "caustics" in eff
    if indirect and specular and not caustics:
        integrator = "mcd_path"  # cut the specular chains the spec did not ask for
    else:
        integrator = "path"
    return EffectPlan(
        effects=spec.effects,
        integrator=integrator,
        max_depth=spec.render.max_depth if indirect else DIRECT_DEPTH,
        rr_depth=spec.render.rr_depth,
        caustics=caustics,
        thinlens=thinlens,
        ao_radius=None,
        features=LIT_FEATURES,
    )
