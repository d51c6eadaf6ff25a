"""Attenuation coefficients against NIST XCOM, and material names, formulas and mixtures."""

import numpy as np
import pytest

from physics_scenes import box, load, parallel_detector
from xray_viz.errors import MaterialError, SceneError
from xray_viz.physics.materials import (check_material, linear_attenuation, mass_attenuation,
                                        material_density, nist_compounds)

# NIST XCOM / NIST X-ray mass attenuation coefficient tables (Hubbell and Seltzer, NISTIR 5632,
# tables 3 and 4): "mu/rho", total with coherent scattering, cm^2/g.
XCOM_WATER = {20: 0.8096, 30: 0.3756, 40: 0.2683, 50: 0.2269, 60: 0.2059, 80: 0.1837,
              100: 0.1707, 150: 0.1505}
XCOM_ALUMINIUM = {20: 3.441, 30: 1.128, 40: 0.5685, 50: 0.3681, 60: 0.2778, 80: 0.2018,
                  100: 0.1704, 150: 0.1378}
# "Bone, Cortical (ICRU-44)", density 1.92, composition of the same NIST table 2 by mass.
ICRU44_CORTICAL_BONE = {"H": 0.034, "C": 0.155, "N": 0.042, "O": 0.435, "Na": 0.001,
                        "Mg": 0.002, "P": 0.103, "S": 0.003, "Ca": 0.225}
XCOM_CORTICAL_BONE = {20: 4.001, 30: 1.331, 40: 0.6655, 50: 0.4242, 60: 0.3148, 80: 0.2229,
                      100: 0.1855, 150: 0.1480}


@pytest.mark.parametrize("material, table", [("Water, Liquid", XCOM_WATER), ("Al", XCOM_ALUMINIUM),
                                             (ICRU44_CORTICAL_BONE, XCOM_CORTICAL_BONE)],
                         ids=["water", "aluminium", "cortical-bone-icru44"])
def test_mass_attenuation_matches_xcom(material, table):
    energies = np.array(list(table), dtype=float)
    expected = np.array(list(table.values()))
    got = mass_attenuation(material, energies)
    # xraylib agrees with these tables to better than 0.04 %; 0.5 % leaves room for rounding of
    # the tabulated values and of the mixture's mass fractions, not for a wrong cross section
    np.testing.assert_allclose(got, expected, rtol=0.005)


def test_water_60kev_anchor():
    assert mass_attenuation("Water, Liquid", 60.0)[0] == pytest.approx(0.2059, rel=1e-3)


def test_icrp_cortical_bone_is_a_different_composition():
    # xraylib's "Bone, Cortical (ICRP)" has 1.85 g/cm3 and less calcium than ICRU-44; above the
    # photoelectric region both agree to ~1 %.
    assert material_density("Bone, Cortical (ICRP)") == pytest.approx(1.85)
    e = np.array([80.0, 100.0, 150.0])
    np.testing.assert_allclose(mass_attenuation("Bone, Cortical (ICRP)", e),
                               [XCOM_CORTICAL_BONE[int(k)] for k in e], rtol=0.015)


def test_linear_is_mass_times_density():
    e = np.linspace(20, 150, 7)
    np.testing.assert_allclose(linear_attenuation("Bone, Cortical (ICRP)", e),
                               1.85 * mass_attenuation("Bone, Cortical (ICRP)", e))
    np.testing.assert_allclose(linear_attenuation("Water, Liquid", e, density=2.0),
                               2.0 * mass_attenuation("Water, Liquid", e))
    np.testing.assert_allclose(linear_attenuation("Al", e, density=2.699),
                               2.699 * mass_attenuation("Al", e))


def test_formula_equals_nist_water():
    e = np.array([30.0, 60.0, 120.0])
    np.testing.assert_allclose(mass_attenuation("H2O", e), mass_attenuation("Water, Liquid", e),
                               rtol=2e-3)


def test_mixture_is_mass_weighted():
    e = np.array([40.0, 80.0])
    mix = mass_attenuation({"Water, Liquid": 0.7, "Bone, Cortical (ICRP)": 0.3}, e)
    np.testing.assert_allclose(mix, 0.7 * mass_attenuation("Water, Liquid", e)
                               + 0.3 * mass_attenuation("Bone, Cortical (ICRP)", e))


def test_names_are_case_sensitive_with_the_right_spelling_suggested():
    assert len(nist_compounds()) > 100
    with pytest.raises(MaterialError, match=r"unknown material 'water, liquid': did you mean "
                                            r"'Water, Liquid'\?"):
        check_material("water, liquid")


def _suggestions(name):
    with pytest.raises(MaterialError) as info:
        mass_attenuation(name, 60.0)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"unknown material {name!r}: ")
    if "did you mean " not in msg:
        return []
    import ast

    return list(ast.literal_eval("(" + msg.split("did you mean ", 1)[1].split("? ", 1)[0] + ",)"))


@pytest.mark.parametrize("name, expected", [
    ("water", ["Water, Liquid", "Water Vapor"]),         # the liquid first, no 'Amber'
    ("WATER", ["Water, Liquid", "Water Vapor"]),
    ("Water Liquid", ["Water, Liquid"]),
    ("tissue, soft (icrp)", ["Tissue, Soft (ICRP)"]),
    ("al", ["Al"]),                                      # the element, not 'Valine'
    ("AL", ["Al"]),
    ("h2o", ["H2O"]),                                    # a formula with its case corrected
    ("CACO3", ["CaCO3", "CaCo3"]),
    ("nacl", ["NaCl"]),
])
def test_unknown_name_suggestions(name, expected):
    assert _suggestions(name) == expected


def test_unknown_name_suggestion_order():
    assert _suggestions("Bone Cortical ICRP")[0] == "Bone, Cortical (ICRP)"
    assert _suggestions("bone")[0] == "Bone, Cortical (ICRP)"         # the common tissue first
    assert _suggestions("muscle")[0] == "Muscle, Skeletal"
    assert _suggestions("fat") == []                     # no 'FAt' (F + astatine)
    assert "Valine" not in _suggestions("Al ")           # a stray blank: still the element


@pytest.mark.parametrize("material", ["H2O", "Al", {"H2O": 1.0}])
def test_formula_element_mixture_need_density(material):
    with pytest.raises(MaterialError, match="density"):
        linear_attenuation(material, 60.0)


def test_bad_mixtures():
    with pytest.raises(MaterialError, match="sum to"):
        mass_attenuation({"H2O": 0.5, "Al": 0.2}, 60.0)
    with pytest.raises(MaterialError, match="> 0"):
        mass_attenuation({"H2O": 1.2, "Al": -0.2}, 60.0)
    with pytest.raises(MaterialError, match="unknown material"):
        mass_attenuation({"H2O": 0.5, "Unobtainium": 0.5}, 60.0)


def test_bad_energies_and_density():
    with pytest.raises(MaterialError, match="energies"):
        mass_attenuation("Al", [0.0, 10.0])
    with pytest.raises(MaterialError, match="density"):
        linear_attenuation("Al", 60.0, density=-1.0)


def test_results_are_cached_and_read_only():
    a = mass_attenuation("Water, Liquid", [50.0, 60.0])
    assert a is mass_attenuation("Water, Liquid", [50.0, 60.0])
    with pytest.raises(ValueError):
        a[0] = 1.0


def test_scene_body_material(tmp_path):
    scene = load(tmp_path, source={"position": [0, 0, 1000], "kind": "parallel", "energy": 60.0},
                 detector=parallel_detector(),
                 bodies=[("slab", box([20, 20, 10]), {"material": "Al", "density": 2.699}),
                         ("mix", box([2, 2, 2], center=[30, 0, 0]),
                          {"material": {"Water, Liquid": 0.5, "Al": 0.5}, "density": 1.8})])
    from xray_viz.physics.imaging import body_mu

    mu = body_mu(scene, [60.0])[0]
    assert mu[0] == pytest.approx(0.2778 * 2.699, rel=0.01)
    assert mu[1] == pytest.approx(1.8 * (0.5 * 0.2059 + 0.5 * 0.2778), rel=0.01)


@pytest.mark.parametrize("keys, message", [
    ({"material": "Alumnium", "density": 2.7}, "unknown material"),
    ({"material": "Al"}, "density"),
    ({"material": 3}, "material must be"),
    ({"mu": 0.2, "density": 1.0}, "density goes with 'material'"),
])
def test_scene_body_material_errors(tmp_path, keys, message):
    with pytest.raises(SceneError, match=message):
        load(tmp_path, source={"position": [0, 0, 1000], "energy": 60.0},
             detector=parallel_detector(), bodies=[("b", box([2, 2, 2]), keys)])
