"""Diagnosis of a system (issue 42): the effect library on every coordinate and relative
coordinate, and a missing friction on mass 2 found and named on equation 2."""

from __future__ import annotations

import json

import numpy as np
import pytest
import sympy as sp

import gpjax
from gpjax._effects import effects
from gpjax._system_bank import match_bank, system_variables
from gpjax._system_effects import _candidates, _in_equations, diagnose_system
from gpjax._weak_form import smoothed_weak_form
from gpjax.systems import generate, get_system
from test_mdof import U, V1, V2, X1, X2, _equations

NAMES = ("x1", "x2")


def _record(name: str, seed: int, duration: float | None = None):
    system = get_system(name)
    if duration is not None:
        import dataclasses

        system = dataclasses.replace(system, duration=duration)
    return generate(system, seed=seed).fit.system_measurement()


def _chain_key():
    """The chain2 truth's structure (per equation: state features, forcing features)."""
    return tuple((tuple(c.state), tuple(c.forcing))
                 for c in _equations(get_system("chain2").constants))


def test_relative_effects_enter_both_equations_mirrored_and_only_system_terms_are_offered():
    names = NAMES
    variables = system_variables(names)
    scales = np.full((2, 4), 50.0)
    key = (((V1,), (U,)), ((V2,), ()))
    z, z_dot = sp.symbols("gpjax_relative gpjax_relative_dot")
    cubic = gpjax.Terms(state=(z ** 3,))
    added = _in_equations(cubic, (0, 1), key, names, variables, scales)
    assert added == {0: (((X1 - X2) ** 3,), ()), 1: (((X2 - X1) ** 3,), ())}
    friction = gpjax.Terms(state=(sp.tanh(z_dot / 0.01),))
    added = _in_equations(friction, (0, 1), key, names, variables, scales)
    for i, (state, _) in added.items():  # the bank's width, whatever the effect's grid
        assert match_bank(state[0], variables[i]) == ("sign", 3, 50.0)
    assert _in_equations(gpjax.Terms(forcing=(sp.Integer(1),)), (0, 1), key, names,
                         variables, scales) is None  # a relative coordinate does not force
    assert _in_equations(gpjax.Terms(state=(V1,)), (0,), key, names, variables,
                         scales) is None  # already there
    assert _in_equations(gpjax.Terms(parametric=(sp.cos(3 * sp.Symbol("t")) * X1,)), (0,),
                         key, names, variables, scales) is None
    assert _in_equations(gpjax.Terms(state=(sp.Abs(X1 - 0.1) - sp.Abs(X1 + 0.1),)), (0,),
                         key, names, variables, scales) is None  # a dead zone


def test_a_missing_friction_on_mass_two_explains_most_of_equation_two():
    measurement = _record("chain2_friction_x2", 100, duration=10.0)
    ranked = _candidates(_chain_key(), smoothed_weak_form(measurement), measurement, effects())
    first = ranked[0]
    assert (first.effect.name, first.where, sorted(first.added)) == ("coulomb_friction", "x2",
                                                                     [1])
    assert first.explained > 0.5 > ranked[1].explained
    places = {c.where for c in ranked}
    assert places == {"x1", "x2", "x1 - x2"}
    assert not {c.effect.name for c in ranked} & {"mesh_stiffness_variation", "backlash"}
    assert any(c.effect.name == "static_offset" and c.added == {1: ((), (sp.Integer(1),))}
               for c in ranked)
    assert any(c.effect.name == "input_gain" and c.added == {1: ((), (U,))} for c in ranked)


def test_the_records_coordinates_must_be_the_models():
    measurement = _record("chain2", 0, duration=2.0)
    model = gpjax.Model.from_equations(("x2", "x1"), "t", ("u",),
                                       _equations(get_system("chain2").constants))
    with pytest.raises(gpjax.UserInputError, match="not the model's coordinates"):
        diagnose_system(measurement, model)


@pytest.mark.slow
def test_friction_on_mass_two_is_named_on_equation_two_through_the_cli(tmp_path, capsys):
    from gpjax.cli import main

    _record("chain2_friction_x2", 101).to_csv(tmp_path / "fit.csv")
    model = gpjax.Model.from_equations(NAMES, "t", ("u",),
                                       _equations(get_system("chain2").constants), substeps=2)
    model.save(tmp_path / "model.json")
    assert main(["diagnose", str(tmp_path / "fit.csv"), "--model", str(tmp_path / "model.json"),
                 "--time", "t", "--response", "x1", "--response", "x2", "--input", "u",
                 "--out", str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    assert "effects added: coulomb_friction on x2 (equation 2)" in out
    assert out.splitlines()[-1].startswith("Diagnosis: ")  # its seconds, stage by stage
    assert "step 1: fitting" in out.splitlines()[-1]
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    assert [(s["effect"], s["equations"]) for s in report["steps"]] == [("coulomb_friction",
                                                                         [2])]
    assert report["steps"][0]["test"]["passed"] and report["convergence"]["converged"]
    found = gpjax.Model.load(tmp_path / "d" / "model.json").system[1]
    friction = [v for f, v in found.state.items() if f.has(sp.tanh)]
    truth = get_system("chain2_friction_x2").constants
    assert friction[0] / found.mass == pytest.approx(truth["F"] / truth["m2"], rel=0.03)
    assert all(r["noise"]["ratio"] < 1.1 for r in report["residuals"].values())
    assert (tmp_path / "d" / "report.md").read_text().startswith("# Diagnosis of a system")


def _two_mass_fit(standard_errors):
    """A converged 2-mass fit's key and intervals: x1'' = c1 v1 + k1 x1 + u + g1,
    x2'' = c1 v2; the constants 0.6, 40, 7e-4, 0.8 with ``standard_errors``."""
    from types import SimpleNamespace

    import numpy as np

    one = sp.Integer(1)
    key = (((V1, X1), (U, one)), ((V2,), ()))
    names = {"x1.c1": (0, "state", V1), "x1.k1": (0, "state", X1),
             "x1.g1": (0, "forcing", one), "x2.c1": (1, "state", V2)}
    uncertainty = SimpleNamespace(
        names=list(names), values=np.array([0.6, 40.0, 7e-4, 0.8]),
        dof=np.array([900.0, 900.0, 1.0, 900.0]), standard_errors=dict(standard_errors))
    return key, SimpleNamespace(uncertainty=uncertainty,
                                model=SimpleNamespace(constant_names=lambda: names))


def test_a_constant_the_record_does_not_determine_is_dropped_first():
    """An infinite standard error (a held-out seed of a 2-mass chain kept a constant force
    in equation 1 with ± inf) is p = 1: the least significant term, offered first; the
    other undemonstrated terms follow by p, and none that would empty an equation."""
    from gpjax._system_final import insignificant_removals

    key, fit = _two_mass_fit({"x1.c1": 0.01, "x1.k1": 0.05, "x1.g1": float("inf"),
                              "x2.c1": 0.3})
    uncertainty = fit.uncertainty
    assert insignificant_removals(key, fit, 0.05) == [(((V1, X1), (U,)), ((V2,), ()))]
    uncertainty.standard_errors |= {"x1.c1": 1.0, "x2.c1": 10.0}  # p 0.55; x2.c1 is alone
    assert insignificant_removals(key, fit, 0.05) == [(((V1, X1), (U,)), ((V2,), ())),
                                                      (((X1,), (U, sp.Integer(1))), ((V2,), ()))]
    uncertainty.standard_errors |= {"x1.c1": 0.01, "x1.g1": 1e-5}  # now demonstrated
    assert insignificant_removals(key, fit, 0.05) == []


def test_a_selected_term_is_tested_at_the_level_over_its_equations_candidates():
    """The search chose each term from its equation's candidates after seeing the record,
    so a term of equation i is tested at alpha / candidates[i] (Bonferroni): k1 at
    t = 2.58 (p = 0.01) stands at 0.05 alone, not among 10 candidates."""
    from gpjax._system_final import insignificant_removals

    key, fit = _two_mass_fit({"x1.c1": 0.01, "x1.k1": 40.0 / 2.58, "x1.g1": 1e-7,
                              "x2.c1": 0.3})
    without_k1 = (((V1,), (U, sp.Integer(1))), ((V2,), ()))
    assert insignificant_removals(key, fit, 0.05) == []
    assert insignificant_removals(key, fit, 0.05, [1, 10]) == []
    assert insignificant_removals(key, fit, 0.05, [10, 1]) == [without_k1]
    assert insignificant_removals(key, fit, 0.002, [4, 1]) == [without_k1]  # 0.0005 < p


def test_a_candidates_terms_are_tested_by_the_wald_test_of_the_reported_intervals():
    """The diagnosis accepts a candidate's terms only where its estimation-part fit's
    sandwich covariance (the intervals the report prints) tells them from 0: the
    likelihood ratio with a Newey–West sample size gave p = 1e-7 for an x1³ whose constant
    was -0.34 ± 0.59 on the whole record (chain2, seed 8)."""
    from types import SimpleNamespace

    from scipy import special

    from gpjax._system_final import added_terms_p

    cubic, relative = X1 ** 3, X1 - X2
    names = {"x1.k1": (0, "state", str(X1)), "x1.k2": (0, "state", str(cubic)),
             "x1.k3": (0, "state", str(relative)), "x2.k1": (1, "state", str(-relative))}
    covariance = np.diag([0.01, 0.09, 0.04, 0.04])
    covariance[2, 3] = covariance[3, 2] = -0.04  # a pair tied by the third law
    uncertainty = SimpleNamespace(names=tuple(names), values=np.array([30.0, -0.34, 0.5, -0.5]),
                                  covariance=covariance, dof=np.array([40.0] * 4))
    fit = SimpleNamespace(uncertainty=uncertainty,
                          model=SimpleNamespace(constant_names=lambda: names))
    alone = added_terms_p(fit, {0: ((cubic,), ())})
    assert alone == pytest.approx(2 * special.stdtr(40.0, -0.34 / 0.3))  # the t test
    assert alone > 0.05
    tied = added_terms_p(fit, {0: ((relative,), ()), 1: ((-relative,), ())})
    assert tied == pytest.approx(2 * special.stdtr(40.0, -0.5 / 0.2))  # counted once
    assert tied < 0.05
    assert added_terms_p(fit, {0: ((), (sp.Integer(1),))}) == 1.0  # no such constant
    covariance[1, 1] = np.inf  # the record does not determine it
    assert added_terms_p(fit, {0: ((cubic,), ())}) == 1.0
    assert added_terms_p(SimpleNamespace(uncertainty=None), {0: ((cubic,), ())}) == 1.0


@pytest.mark.slow
def test_the_wald_pruning_runs_only_where_the_report_finds_every_residual_at_its_noise():
    """:func:`gpjax._system_final.flagged` is the report's flag: the true chain is at its
    noise floor, the chain without its cubic coupling is far above it (the Wald intervals
    of such a fit count the missing force as noise and do not show a term spurious)."""
    from gpjax._system_final import flagged
    from gpjax.engine import fit_system

    measurement = _record("chain2", 0, duration=10.0)
    truth = (((V1, X1, X1 - X2, (X1 - X2) ** 3), {U: 1.0}),
             ((V2, X2, X2 - X1, (X2 - X1) ** 3), {}))
    assert not flagged(fit_system(measurement, truth), measurement)
    linear = tuple(((state[:3], forcing) for state, forcing in truth))
    assert flagged(fit_system(measurement, linear), measurement)


@pytest.mark.slow
def test_the_selection_guard_keeps_a_coupling_the_simulated_responses_need():
    """:meth:`SystemScorer.simulates_better` (one coordinate's guard on the coordinates'
    combined residuals): chain2 without its cubic coupling spring simulates significantly
    worse than the truth; the truth does not simulate worse than itself."""
    from gpjax import GPConfig
    from gpjax._system_search import SystemEvolution

    measurement = _record("chain2", 0, duration=10.0)
    scorer = SystemEvolution(measurement, GPConfig()).scorer
    truth = tuple((tuple(sorted(state, key=str)), tuple(sorted(forcing, key=str)))
                  for state, forcing in _chain_key())
    linear = tuple((tuple(f for f in state if not (f.is_Pow and f.exp == 3)), forcing)
                   for state, forcing in truth)
    assert linear != truth
    assert scorer.simulates_better(truth, linear, 0.05, 0.01)
    assert not scorer.simulates_better(truth, truth, 0.05, 0.01)


def test_the_report_says_where_the_model_before_diverged():
    """A step whose starting structure diverged when refitted on the estimation part (its
    held-out residual NaN) reads so in report.md, not "nan"."""
    from types import SimpleNamespace

    from gpjax._system_effects import SystemDiagnosis

    model = gpjax.Model.from_equations(NAMES, "t", ("u",),
                                       _equations(get_system("chain2").constants))
    fit = SimpleNamespace(model=model, uncertainty=None,
                          checks=[SimpleNamespace(to_json=lambda: {})])
    step = {"effect": "coulomb_friction", "acts_on": "x2", "equations": [2],
            "test": {"p_adjusted": 1e-6}, "heldout_rms_after": 0.0125}
    for before, text in ((float("nan"), "none (the model before diverged"),
                         (0.02, "0.02 -> 0.0125")):
        report = SystemDiagnosis(steps=[step | {"heldout_rms_before": before}], rankings=[],
                                 before=fit, after=fit, residuals={}, settings={}).markdown()
        assert text in report and "nan" not in report
