"""The built-in method table: explicit, fixed order, no registration on import."""

from __future__ import annotations

from mcdenoise.method import Method
from mcdenoise.methods import builtin_methods


def test_builtin_methods_are_listed_explicitly_with_their_aliases() -> None:
    table = builtin_methods()
    assert [m.name for m, _ in table] == [
        "nlm",
        "cross-bilateral",
        "kalantari-xbf",
        "kalantari-nlm",
        "kpcn",
        "oidn",
        "svgf",
        "nfor",
        "kpcn-temporal",
        "ssao",
        "hbao",
        "alchemy",
        "gtao",
        "nnao",
    ]
    assert all(isinstance(m, Method) for m, _ in table)
    assert dict((m.name, a) for m, a in table)["cross-bilateral"] == ("xbf", "cross_bilateral")
    assert builtin_methods() == table  # the same objects every time


def test_priorities_give_the_documented_default_order() -> None:
    prio = {m.name: m.priority for m, _ in builtin_methods()}
    assert prio["kalantari-xbf"] > prio["kalantari-nlm"] > prio["nlm"] > prio["cross-bilateral"]
    assert prio["cross-bilateral"] > prio["svgf"] > prio["oidn"] == 0
    assert prio["kpcn"] in (35, -1)  # first; -1 only without shipped weights
    assert prio["kpcn"] == -1 or prio["kpcn"] > prio["kalantari-xbf"]
