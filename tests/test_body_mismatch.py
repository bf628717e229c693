"""The virtual impedance is tuned for the bodies it is given; where they are not the bodies the
dynamics integrate, the scene check says so in one warning per parameter (a mistuned impedance
ran and said valid with nothing to say why its error was larger)."""

import pytest

from dockhil.analysis.scenecheck import scene_check
from dockhil.scene import graph as graphmod
from dockhil.scene import launchfile
from tests.conftest import ROOT


def warnings_of(scene: str, changes: dict) -> list[str]:
    g = graphmod.build(launchfile.load(ROOT / "launch" / scene))
    for (node, name), value in changes.items():
        g.nodes[node].params[name] = value
    return scene_check(g)["warnings"]


@pytest.mark.parametrize("scene", ["hil.yaml", "hil6.yaml"])
def test_the_shipped_scenes_tune_the_impedance_for_their_bodies(scene):
    assert not [w for w in warnings_of(scene, {}) if "tuned for" in w]


def test_a_1dof_impedance_tuned_for_another_mass_is_named():
    got = [w for w in warnings_of("hil.yaml", {("impedance", "m1"): 300.0}) if "tuned for" in w]
    assert got == [
        "node 'impedance' is tuned for m1 = 300.0 kg but node 'dynamics' integrates m1 = 750.0 kg: "
        "the virtual impedance does not make the ideal contact for these bodies; give both the same m1"
    ]


def test_a_6dof_impedance_tuned_for_another_interface_is_named():
    got = [
        w
        for w in warnings_of("hil6.yaml", {("impedance", "interface1"): [1.2, 0.0, 0.0], ("impedance", "m2"): 2e6})
        if "tuned for" in w
    ]
    assert len(got) == 2
    assert got[0].startswith("node 'impedance' is tuned for m2 = 2000000.0 kg but node 'dynamics' integrates m2 = ")
    assert got[1].startswith(
        "node 'impedance' is tuned for interface1 = [1.2, 0.0, 0.0] m but node 'dynamics' "
        "integrates interface1 = [1.0, 0.0, 0.0] m"
    )
