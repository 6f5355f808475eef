"""The system bank (:mod:`gpjax._system_bank`): non-polynomial terms of one variable of a
system's equations — a smoothed sign (dry friction between two masses), z·|z| and sin/cos —
in the evaluator, the structure rules, the model file and a search."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import sympy as sp

import gpjax
from gpjax import ConfigError, GPConfig, Symbols
from gpjax._coefficients import Coefficients, to_system_population
from gpjax._config import check_system_config
from gpjax._system_bank import (KINDS, bank_feature, bank_of, match_bank, sign_scales,
                                system_variables)
from gpjax._system_grammar import Equations
from gpjax.engine import PopulationEvaluator
from gpjax.systems import generate, get_system

X1, X2, V1, V2, U = sp.symbols("x1 x2 x1_dot x2_dot u")
THETA = 40.0  # the sign's scale θ (1/ε, s/m)


@functools.lru_cache(maxsize=1)
def _data():
    system = dataclasses.replace(get_system("chain2_friction"), duration=4.0)
    return generate(system, seed=2, noise=0.0, input_noise=0.0)


def _record(duration=4.0):
    record = _data().fit
    keep = record.time <= duration
    return gpjax.Measurement(time=record.time[keep], responses=record.response_true[:, keep].T,
                             inputs={"u": record.input_true[keep]},
                             response_names=record.coordinates)


def _equations(y0=((0.01, 0.1), (0.0, -0.1))):
    """Friction between the masses, drag on mass 1, a sine of the coupling on mass 2."""
    friction = bank_feature("sign", V1 - V2, THETA)
    first = Coefficients(1.0, {V1: 0.5, X1: 30.0, X1 - X2: 20.0, friction: 1.5,
                               V1 * sp.Abs(V1): 0.3}, {U: 1.0}, y0[0])
    second = Coefficients(0.8, {V2: 0.5, X2: 30.0, X2 - X1: 20.0,
                                bank_feature("sign", V2 - V1, THETA): 1.5,
                                sp.sin(X2 - X1): 2.0}, {}, y0[1])
    return [first, second]


def _model(equations, substeps=1):
    return gpjax.Model.from_equations(("x1", "x2"), "t", ("u",), equations,
                                      input_interpolation="linear", substeps=substeps)


def test_every_bank_feature_is_matched_back_in_both_equations():
    for variables in system_variables(("x1", "x2")):
        for kind in KINDS:
            for position, z in enumerate(variables):
                feature = bank_feature(kind, z, 7.5)
                assert match_bank(feature, variables) == (
                    kind, position, 7.5 if kind == "sign" else 1.0), feature
    assert match_bank(sp.sin(2 * X1), system_variables(("x1", "x2"))[0]) is None
    kinds, scales = bank_of(("x1", "x2"), [list(e.state) for e in _equations()])
    assert kinds == ("sign", "abs", "sin") and scales[3] == scales[7] == THETA
    with pytest.raises(ValueError, match="neither a power nor a bank term"):
        bank_of(("x1", "x2"), [[sp.exp(X1)], []])


def test_bank_simulation_matches_the_reference_solve():
    """RK4 on the bank's columns (the sign's θ a program argument) converges to the
    adaptive reference solve of the same model's sympy equations."""
    measurement = _record()
    model = _model(_equations(), substeps=8)
    evaluator = model.evaluator(measurement)
    assert evaluator.kinds == ("sign", "abs", "sin")
    y0 = np.array([[0.01, 0.1], [0.0, -0.1]])
    rk4 = model.simulate(measurement, initial_conditions=y0, solver="rk4")
    reference = model.simulate(measurement, initial_conditions=y0)
    scale = np.std(reference, axis=0)
    assert np.all(np.abs(rk4 - reference).max(axis=0) < 1e-5 * scale)


@pytest.mark.slow  # ~15 s: compiles forward-mode autodiff through the scan
def test_bank_variational_jacobian_matches_autodiff():
    """The hand-written partials of the bank's terms (the initial-state step and the
    refiner's Jacobian) equal forward-mode autodiff of the RK4 solution."""
    measurement = _record(duration=2.0)
    model = _model(_equations())
    ev = model.evaluator(measurement, max_degree=3)
    pop = to_system_population([_equations()], ev)
    flat = jnp.asarray(ev.layout.pack(pop)[0])
    basis = jnp.asarray(ev.forcing_basis)[: ev.stage_rows(measurement.n_samples)]
    directions = jnp.asarray(np.random.default_rng(0).standard_normal((3, flat.size)))
    x, dx = ev.constant_jacobian(flat, directions, basis)
    expected = jax.jacfwd(lambda c: ev.scan_solve(*ev.unpack(c, basis))[..., 0])(flat)
    np.testing.assert_allclose(dx, expected @ directions.T, rtol=1e-9,
                               atol=1e-9 * float(jnp.max(jnp.abs(dx))))


def test_a_new_sign_scale_compiles_nothing():
    """θ is data: two evaluators that differ only in it share their program key."""
    measurement = _record(duration=1.0)
    keys = {PopulationEvaluator(measurement, Symbols("x1", "t", ("u",)), max_degree=3,
                                kinds=("sign",), sign_scales=np.full(8, theta)).key
            for theta in (10.0, 300.0)}
    assert len(keys) == 1


@pytest.mark.parametrize("tree, expected", [
    (("add", ("s", "x1_ddot"), ("sign", ("s", "d_x1_x2_dot"))), "sign"),
    (("add", ("s", "x1_ddot"), ("tanh", ("mul", ("n", -3.0), ("s", "d_x1_x2_dot")))), "-sign"),
    (("add", ("s", "x1_ddot"), ("mul", ("s", "x1_dot"), ("abs", ("s", "x1_dot")))), "abs"),
    (("add", ("s", "x1_ddot"), ("sin", ("s", "x1"))), "sin"),
    (("add", ("s", "x1_ddot"), ("sin", ("mul", ("n", -1.0), ("s", "x1")))), "sin"),
    (("add", ("s", "x1_ddot"),
      ("sign", ("mul", ("n", -2.0), ("sign", ("s", "d_x1_x2_dot"))))), "-sign"),
    (("add", ("s", "x1_ddot"), ("sin", ("mul", ("n", 2.0), ("s", "x1")))), None),
    (("add", ("s", "x1_ddot"), ("abs", ("s", "x1_dot"))), None),
    (("add", ("s", "x1_ddot"), ("mul", ("s", "x1"), ("sign", ("s", "x1_dot")))), None),
    (("add", ("s", "x1_ddot"), ("sin", ("s", "x1_ddot"))), None),
])
def test_structure_rules_read_bank_terms(tree, expected):
    measurement = _record(duration=1.0)
    scales = np.arange(1.0, 9.0)
    equations = Equations(measurement, 3, functions=("add", "sub", "mul", "sign", "tanh",
                                                      "abs", "sin"), scales=scales)
    found = equations.structure(0, tree)
    if expected is None:
        assert found is None
        return
    state, forcing = found
    feature = {"sign": bank_feature("sign", V1 - V2, 4.0),
               "-sign": bank_feature("sign", V1 - V2, 4.0), "abs": V1 * sp.Abs(V1),
               "sin": sp.sin(X1)}[expected]
    assert state == (feature,) and forcing == ()
    assert equations.structure(0, equations.tree(0, state, forcing)) == found


def test_a_function_of_a_constant_is_a_constant_force():
    """sin(2) reads as a constant force; a constant beyond float64 makes no equation."""
    equations = Equations(_record(duration=1.0), 3, functions=("add", "sub", "mul", "sin"))
    assert equations.structure(0, ("add", ("s", "x1_ddot"), ("sin", ("n", 2.0)))) == (
        (), (sp.Integer(1),))
    huge = ("mul", ("n", 1e200), ("n", 1e200))
    assert equations.structure(0, ("add", ("s", "x1_ddot"), ("sin", huge))) is None


def test_a_system_input_enters_linearly_unless_input_forcing_is_any():
    """u² on the forcing side is refused by default and kept with input_forcing="any",
    and the local search's tree of that structure reads back as it."""
    measurement = _record(duration=1.0)
    tree = ("sub", ("add", ("s", "x1_ddot"), ("s", "x1")),
            ("add", ("u", 0), ("mul", ("u", 0), ("u", 0))))
    assert Equations(measurement, 3).structure(0, tree) is None
    equations = Equations(measurement, 3, input_forcing="any")
    state, forcing = equations.structure(0, tree)
    assert state == (X1,) and forcing == tuple(sorted((U, U ** 2), key=str))
    assert equations.structure(0, equations.tree(0, state, forcing)) == (state, forcing)


def test_sign_scales_follow_the_variables_rms():
    scales = sign_scales(("x1", "x2"), lambda z: 2.0 if z == V1 - V2 else 0.0)
    assert scales[3] == pytest.approx(1 / (0.01 * 2.0)) and scales[0] == pytest.approx(100.0)


@pytest.mark.parametrize("change, message", [
    (dict(functions=("add", "sub", "mul", "exp")), "function 'exp' is not supported"),
    (dict(functions=("add", "sub", "mul", "sign"), third_law=True),
     "third_law takes polynomial couplings only"),
    (dict(coefficients="tree"), "coefficients is not supported with several responses"),
])
def test_system_settings_outside_the_bank_are_refused(change, message):
    with pytest.raises(ConfigError, match=message):
        check_system_config(GPConfig(**change))
    check_system_config(GPConfig(functions=("add", "sub", "mul", "sign", "abs", "sin", "cos")))


def test_bank_model_file_round_trip(tmp_path):
    model = _model(_equations())
    model.save(tmp_path / "model.json")
    loaded = gpjax.Model.load(tmp_path / "model.json")
    assert [str(e) for e in loaded.sympy()] == [str(e) for e in model.sympy()]
    data = model.to_json()
    data["canonical"][1]["terms"].append({"feature": "exp(x2)", "coefficient": 1.0})
    with pytest.raises(gpjax.ModelFileError, match="neither a power nor a bank term"):
        gpjax.Model.from_json(data)


@pytest.mark.slow  # ~1 min: a small search on the friction chain
def test_search_finds_dry_friction_between_two_masses(tmp_path):
    """The Identifier on chain2_friction with sign in the function set finds the friction
    between the masses in both equations, with the spring and dampers, constants within
    3 %; the smoothed sign's width starts at 1 % of RMS(x1' − x2') (the truth's ~0.1 %) and
    is narrowed until the reported constants do not carry the smoothing."""
    data = generate("chain2_friction", seed=3)
    identifier = gpjax.Identifier(GPConfig(
        population=200, generations=4, functions=("add", "sub", "mul", "sign"))).fit(
        data.fit.system_measurement(), seed=0, out=tmp_path / "run")
    first, second = identifier.model_.system
    c = data.system.constants
    friction = [f for f in first.state if f.has(sp.tanh)]
    assert len(friction) == 1 and set(first.state) == {V1, X1, X1 - X2, friction[0]}
    assert set(second.state) == {V2, X2, X2 - X1, -friction[0]} and set(first.forcing) == {U}
    assert first.state[friction[0]] == pytest.approx(c["F"], rel=0.03)
    assert first.mass == pytest.approx(c["m1"], rel=0.03)
    assert second.state[-friction[0]] == pytest.approx(c["F"] / c["m2"], rel=0.03)
    assert second.state[X2 - X1] == pytest.approx(c["kc"] / c["m2"], rel=0.03)
    convergence = gpjax.Model.load(tmp_path / "run" / "model.json").convergence
    width = convergence["sign_width"]  # where one coordinate's is
    assert "smoothed sign tanh(z/ε)" in str(identifier)
    # narrowed from 1 % (the truth's sign is ~0.1 % of RMS z wide); the check at 1 % and
    # at each width but the last did not converge and could be made; the narrowing stops
    # at the cap, where the check cannot be made, or where RK4 could not integrate the
    # narrower sign stably within the step cap
    assert width["fraction"] < 0.01
    assert width["converged"] or width["fraction"] == pytest.approx(0.01 / 4 ** 3) or (
        width["ratio"] == np.inf) or convergence.get("stopped") in ("unstable sign",
                                                                     "width not converging")


def test_a_diverged_coordinate_gets_a_hint():
    from gpjax._system_diagnose import hint, summary_line

    line = summary_line("x2", {"rms": None, "nrms": None, "noise": None, "unexplained": None})
    assert "diverges on its record" in line and hint() in line and "--functions" in hint()


def test_a_small_significant_excess_is_marked_as_below_the_gate():
    """A residual at about its noise floor with a significant in-band excess is printed with
    its p-value and said to be below the gate; an insignificant one is printed plainly."""
    from gpjax._system_diagnose import summary_line

    def line(ratio, p, unexplained=None):
        return summary_line("x", {"rms": 1.0, "nrms": 0.01, "noise": {
            "ratio": ratio, "sigma": 0.004, "p_excess": p}, "unexplained": unexplained})

    assert "below the 1.5× gate, so not flagged" in line(0.99, 6e-6)
    assert "gate" not in line(0.99, 0.3) and "misses" not in line(0.99, 0.3)
    flagged = line(3.0, 1e-9, unexplained={})
    assert "misses something" in flagged and "gate" not in flagged


def _fitted(model, measurement):
    """A stand-in :class:`SystemFit` of ``model``: its convergence check on ``measurement``."""
    from types import SimpleNamespace

    from gpjax._convergence import check_model

    check, reference = check_model(model, measurement, tolerance=0.01)
    return SimpleNamespace(model=model, checks=(check,), reference=reference)


def test_a_systems_width_check_is_one_coordinates_check():
    """The reported system's signs narrowed 4× and 16× (constants kept) against its own
    reference response, over its convergence check's residual: a ratio, the next one (its
    rate) and a verdict, in the first response's units as that check; no sign, no check."""
    from gpjax._convergence import coordinate_weights
    from gpjax._sign_width import WidthCheck
    from gpjax._sign_width import sharpened
    from gpjax._system_search import _width_check

    measurement = _record(duration=2.0)
    model = _model(_equations())
    fit = _fitted(model, measurement)
    check = _width_check(fit, measurement, 0.01, 0.01)
    assert isinstance(check, WidthCheck) and check.fraction == 0.01
    assert 0 < check.ratio < np.inf and 0 < check.next_ratio < np.inf
    assert check.converged == (check.ratio < 0.01)
    weights = coordinate_weights(measurement.responses)
    own, sharper = (np.reshape(m.simulate(measurement, initial_conditions=model.initial_states),
                               measurement.responses.shape)
                    for m in (model, sharpened(model, 4)))
    change = np.sqrt(np.mean(((sharper - own) * weights) ** 2))
    assert check.ratio == pytest.approx(change / fit.checks[0].rms_reference, rel=1e-6)
    plain = [e.replace(state={f: v for f, v in e.state.items() if not f.has(sp.tanh)})
             for e in _equations()]
    assert _width_check(_fitted(_model(plain), measurement), measurement, 0.01, 0.01) is None


def test_width_line_says_when_the_narrower_check_cannot_be_made():
    from gpjax._sign_width import width_line

    check = {"fraction": 0.0025, "ratio": np.inf, "tolerance": 0.01, "converged": False}
    line = width_line(check)
    assert "NOT checked" in line and "4× narrower" in line and "inf" not in line
    assert "converged" in width_line(dict(check, ratio=0.003, converged=True))


def _narrowing(monkeypatch, steps, checks):
    """``_narrowed`` on a stand-in fit whose width checks give ``checks`` in turn ((ratio,
    next ratio) pairs), the narrower signs needing ``steps`` per sample and every refit
    after the first diverging: (its check's JSON, the refits' keyword arguments, the
    factors the signs were narrowed by)."""
    from types import SimpleNamespace

    import gpjax._sign_width as widths
    import gpjax._system_search as search

    calls, left = [], list(checks)

    def width_check(fit, measurement, tolerance, width):
        ratio, next_ratio = left.pop(0)
        return widths.WidthCheck(width, ratio, 1.0, ratio, tolerance, next_ratio=next_ratio)

    def refit(*args, **kwargs):
        calls.append(kwargs)
        if len(calls) > 1:
            raise ValueError("the refined system diverged")
        return fit

    monkeypatch.setattr(search, "_width_check", width_check)
    monkeypatch.setattr(search, "sharpened",  # a stand-in whose equations name the factor
                        lambda model, factor: SimpleNamespace(system=("narrowed", factor)))
    monkeypatch.setattr(widths, "narrowed_steps", lambda sharper, measurement, tolerance: steps)
    monkeypatch.setattr(search, "fit_system", refit)
    fit = SimpleNamespace(model=SimpleNamespace(system=[], substeps=2))
    out, check, stopped = search._narrowed(
        fit, (), SimpleNamespace(response_names=("x1", "x2")), {"tolerance": 0.01})
    check = check | ({"stopped": stopped} if stopped else {})
    assert out is fit
    return check, calls, [kwargs["start"][1] for kwargs in calls]


def test_a_narrowing_jumps_as_far_as_the_checks_rate_projects(monkeypatch):
    """One coordinate's rule: a change that falls 4× per narrowing from 16× the tolerance
    needs two narrowings, made in one refit (16× narrower) at the steps the narrower
    signs need; that check passes and the loop ends (it narrowed one at a time: three
    refits, each compiling its own programs, on a held-out chain with dry friction)."""
    check, calls, factors = _narrowing(monkeypatch, 6, [(0.15, 0.0375), (0.005, 0.002)])
    assert factors == [16] and len(calls) == 1 and calls[0]["first_substeps"] == 6
    assert check["converged"] and check["fraction"] == pytest.approx(0.01 / 16)
    assert "stopped" not in check


def test_a_diverged_narrower_refit_keeps_the_last_fit_and_its_check(monkeypatch):
    """The refit after the first diverges: the first refit's fit and check stand (a change
    falling 4× per narrowing from 3× the tolerance: one narrowing each time)."""
    check, calls, factors = _narrowing(monkeypatch, 6, [(0.03, 0.0075), (0.03, 0.0075)])
    assert factors == [4, 4] and len(calls) == 2
    assert check["fraction"] == pytest.approx(0.0025) and not check["converged"]
    assert "stopped" not in check


def test_a_change_that_does_not_fall_as_the_sign_narrows_stops_the_narrowing(monkeypatch):
    from gpjax._sign_width import width_line

    check, calls, _ = _narrowing(monkeypatch, 6, [(0.05, 0.06)])
    assert calls == [] and check["stopped"] == "width not converging"
    assert "would not converge" in width_line(check, check["stopped"])


def test_no_narrowing_to_a_sign_no_step_count_integrates_stably(monkeypatch):
    """One coordinate's rule (:func:`gpjax._sign_width.narrowed_steps`): where no step
    count up to the cap integrates the narrower signs stably, the last fit stands and the
    report says why, instead of an unconverged fit at the narrower signs."""
    from gpjax._sign_width import width_line

    check, calls, _ = _narrowing(monkeypatch, None, [(0.03, 0.0075)])
    assert calls == [] and check["stopped"] == "unstable sign"
    assert "more than 64 steps per sample" in width_line(check, check["stopped"])


def test_the_selection_offers_each_bank_term_its_polynomial_stand_in():
    """sin z -> z, the smoothed sign of z -> z, cos z -> z² (the selection keeps the bank
    term only where the data demonstrate it); sin z -> z³ where z is already in the
    equation; none for z·|z|."""
    from types import SimpleNamespace

    from gpjax._system_select import power_swaps

    equations = Equations(_record(duration=1.0), 3, functions=(
        "add", "sub", "mul", "sign", "abs", "sin", "cos"))
    scorer = SimpleNamespace(equations=equations)
    sign = equations.feature(0, "sign", V1 - V2)
    key = (((X1, sp.sin(X1 - X2), sign, sp.cos(X1), V1 * sp.Abs(V1)), (U,)),
           ((X2 - X1,), ()))
    swapped = {tuple(sorted(set(c[0][0]) - set(key[0][0]), key=str))
               for c in power_swaps(key, 0, scorer)}
    assert swapped == {(X1 - X2,), (V1 - V2,), (X1 ** 2,)}
    assert all(c[1] == key[1] and c[0][1] == (U,) for c in power_swaps(key, 0, scorer))
    assert list(power_swaps(key, 1, scorer)) == []
    beside = (((X1 - X2, sp.sin(X1 - X2)), (U,)), key[1])  # beside z, sin z stands for z³
    assert [c[0][0] for c in power_swaps(beside, 0, scorer)] == [((X1 - X2) ** 3, X1 - X2)]


def test_the_selection_offers_a_coupling_the_law_of_its_other_end():
    """Equation 2's polynomial stand-in c·z + c3·z³ (z = x2' − x1') for the quadratic
    damper equation 1 has in −z is offered that damper, its other terms kept; nothing is
    offered where it would add a term, where the equations already agree, or where the other
    end has no bank term."""
    from types import SimpleNamespace

    from gpjax._system_select import mirror_swaps

    equations = Equations(_record(duration=1.0), 3, functions=("add", "sub", "mul", "abs"))
    scorer = SimpleNamespace(equations=equations)
    z = V2 - V1
    key = (((V1, X1 - X2, (V1 - V2) * sp.Abs(V1 - V2)), (U,)),
           ((V2, X2 - X1, z, z ** 3), ()))
    (swapped,) = mirror_swaps(key, 1, scorer)
    assert swapped[0] == key[0]
    assert set(swapped[1][0]) == {V2, X2 - X1, z * sp.Abs(z)} and swapped[1][1] == ()
    assert list(mirror_swaps(key, 0, scorer)) == []  # equation 2 has no bank term in z
    assert list(mirror_swaps(swapped, 1, scorer)) == []
    plain = (((V1, X1 - X2, V1 - V2), (U,)), key[1])
    assert list(mirror_swaps(plain, 1, scorer)) == []
    one = (key[0], ((V2, X2 - X1, z), ()))
    assert [set(c[1][0]) for c in mirror_swaps(one, 1, scorer)] == [{V2, X2 - X1, z * sp.Abs(z)}]


def test_the_selection_offers_powers_of_a_variable_one_bank_term_in_their_place():
    """c·z + c3·z³ (z = x1' − x2') -> one bank term of z of each kind, the equation's other
    terms kept; with three powers also z kept beside it; nothing for a single power."""
    from types import SimpleNamespace

    from gpjax._system_select import bank_swaps

    equations = Equations(_record(duration=1.0), 3, functions=("add", "sub", "mul", "abs", "sin"))
    scorer = SimpleNamespace(equations=equations)
    z = V1 - V2
    key = (((V1, X1 - X2, z, z ** 3), (U,)), ((V2,), ()))
    offered = [set(c[0][0]) for c in bank_swaps(key, 0, scorer)]
    assert offered == [{V1, X1 - X2, z * sp.Abs(z)}, {V1, X1 - X2, sp.sin(z)}]
    assert all(c[0][1] == (U,) and c[1] == key[1] for c in bank_swaps(key, 0, scorer))
    three = (((V1, z, z ** 2, z ** 3), (U,)), key[1])
    assert [set(c[0][0]) for c in bank_swaps(three, 0, scorer)][:2] == [
        {V1, z * sp.Abs(z)}, {V1, z, z * sp.Abs(z)}]
    assert list(bank_swaps(key, 1, scorer)) == []


def test_only_the_simulated_guard_vetoes_a_power_swap():
    """A held-out test that calls the stand-in significantly worse does not keep sin x1 (the
    equation error's bias between a function and its Taylor stand-in), nor does one that
    calls sin x1 significantly better than x1 + x1³ replace them; the simulated guard
    decides, and a removal stays vetoed by the held-out test."""
    from types import SimpleNamespace

    from gpjax._system_select import simplest

    equations = Equations(_record(duration=1.0), 3, functions=("add", "sub", "mul", "sin"))
    noise = np.random.default_rng(0).normal(size=400)

    def scorer(scales: dict, passes: set):
        """Held-out residuals ``scales`` × noise (3 for any other system); the simulated
        guard lets only ``passes`` through."""
        return SimpleNamespace(
            equations=equations, held_out=lambda key: noise * scales.get(key, 3.0),
            simulates_better=lambda current, other, a, r: other not in passes)

    other = ((V2, X2 - X1), ())
    function, stand_in = (((sp.sin(X1), V1), (U,)), other), (((X1, V1), (U,)), other)
    scales = {function: 1.0, stand_in: 1.5}  # the stand-in significantly worse held out
    assert simplest(function, scorer(scales, {stand_in}), 0.05, 0.01) == stand_in
    assert simplest(function, scorer(scales, set()), 0.05, 0.01) == function
    powers = (((X1, X1 ** 3, V1), (U,)), other)
    scales = {powers: 1.0, function: 0.5}  # sin x1 significantly better held out
    assert simplest(powers, scorer(scales, set()), 0.05, 0.01) == powers
    assert simplest(powers, scorer(scales, {function}), 0.05, 0.01) == function


def test_a_system_the_reference_solver_cannot_integrate_gives_way_to_a_removal():
    """The selected system's converged fit diverges under the reference solver (a −c₃·x2'³
    that only the search's coarse RK4 held back): of its one-term removals, the one the
    reference solver integrates with the smallest residual is reported; none: None."""
    from types import SimpleNamespace

    from gpjax._system_final import integrable, integrates

    def fit(rms):
        return SimpleNamespace(checks=(SimpleNamespace(rms_reference=rms),))

    key = (((X1, V1, X1 - X2), (U,)), ((X2 - X1, V2, V2 ** 3), ()))
    residuals = {(((X1, V1, X1 - X2), (U,)), ((X2 - X1, V2), ())): 0.02,  # no cubic: stable
                 (((X1, V1, X1 - X2), (U,)), ((X2 - X1, V2 ** 3), ())): 0.05}
    seen = []

    def fit_of(smaller):
        seen.append(smaller)
        if not smaller[0][1]:  # without the input the refit diverges
            return None
        return fit(residuals.get(smaller, np.inf))

    assert not integrates(fit(np.inf)) and integrates(fit(0.02))
    smaller, chosen = integrable(key, fit_of)
    assert smaller == (((X1, V1, X1 - X2), (U,)), ((X2 - X1, V2), ()))
    assert chosen.checks[-1].rms_reference == 0.02
    assert len(seen) == 7  # every term of both equations, the input too
    assert integrable(key, lambda smaller: fit(np.inf)) is None
