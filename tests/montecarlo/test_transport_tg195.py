"""The transport against AAPM TG-195 (Sechopoulos et al. 2015): four Monte Carlo codes'
results for cases 1 and 2 (tests/data/tg195/, README there).

Tolerance of case 2 (the issue's): within max(2 %, twice the four codes' spread) of their
mean, plus three of our standard errors.
"""

from __future__ import annotations

import pytest

import xray_viz

from tg195 import case1_kermas, case2_scene, reference, total_body


@pytest.mark.parametrize("label", ["30 keV", "100 keV", "30 kVp", "100 kVp"])
def test_case1_air_kermas_and_hvl_qvl_ratios(label):
    k = case1_kermas(label)
    for name, ours in k.items():
        assert ours == pytest.approx(float(reference("1", name, label)["mean"]), rel=0.003)
    for ratio, filt in (("HVL ratio", "HVL filter"), ("QVL ratio", "QVL filter")):
        ref = float(reference("1", ratio, label)["mean"])
        assert abs(k[filt] / k["no filter"] - ref) < 0.002


def _tolerance(row, ours, error):
    mean = float(row["mean"])
    return max(0.02 * mean, 2 * float(row["spread_pct"]) / 100 * mean) + 3 * error


@pytest.mark.parametrize("label", ["56.4 keV", "120 kVp"])
def test_case2_total_body_bounded(label):
    result = xray_viz.transport(case2_scene(label), 100_000, seed=195)
    ours, err = total_body(result)
    row = reference("2", "Total body", label)
    assert abs(ours - float(row["mean"])) < _tolerance(row, ours, err)
    assert err < 0.005 * ours                      # the bounded run still measures to 0.5 %
    b = result.balance
    assert b["deposited"] + b["world"] + b["escaped"] + b["detector"] == pytest.approx(
        b["emitted"], rel=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("label", ["56.4 keV", "120 kVp"])
def test_case2_total_body_and_nine_vois(label):
    result = xray_viz.transport(case2_scene(label), 10_000_000, seed=1950)
    ours, err = total_body(result)
    row = reference("2", "Total body", label)
    assert abs(ours - float(row["mean"])) < _tolerance(row, ours, err)
    for k in range(1, 10):
        name = f"VOI {k}"
        row = reference("2", name, label)
        e, s = result.energy[name], result.energy_error[name]
        assert abs(e - float(row["mean"])) < _tolerance(row, e, s), name


def _case3_row(name, label):
    """16.8 keV: PENELOPE is up to 11 % off the three others there (README): the median."""
    row = dict(reference("3", name, label))
    if label == "16.8 keV":
        row["mean"] = row["median"]
    return row


@pytest.mark.parametrize("label", ["16.8 keV", "30 kVp"])
def test_case3_breast_total_body_bounded(label):
    from tg195 import case3_scene, case3_total_body

    result = xray_viz.transport(case3_scene(label), 50_000, seed=3195)
    ours, err = case3_total_body(result)
    row = _case3_row("Total body", label)
    assert abs(ours - float(row["mean"])) < _tolerance(row, ours, err)
    assert err < 0.01 * ours


@pytest.mark.slow
@pytest.mark.parametrize("label", ["16.8 keV", "30 kVp"])
def test_case3_breast_and_seven_vois(label):
    from tg195 import case3_scene, case3_total_body

    result = xray_viz.transport(case3_scene(label), 4_000_000, seed=31950)
    ours, err = case3_total_body(result)
    row = _case3_row("Total body", label)
    assert abs(ours - float(row["mean"])) < _tolerance(row, ours, err)
    for k in range(1, 8):
        name = f"VOI {k}"
        try:
            row = _case3_row(name, label)
        except KeyError:                           # no reference row for this VOI
            continue
        e, s = result.energy[name], result.energy_error[name]
        assert abs(e - float(row["mean"])) < _tolerance(row, e, s), name
