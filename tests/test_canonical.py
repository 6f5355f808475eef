import pytest
import sympy as sp

from gpjax import Symbols, check_structure
from gpjax.engine import tree_to_sympy

S = Symbols("phi", "t", ("T",))
phi, phi_dot, phi_ddot, T, t = S.x, S.x_dot, S.x_ddot, S.u[0], S.t


def test_accepts_eq14_and_normalises_the_input():
    check = check_structure(7.918e-5 * phi_ddot + 413.191 * phi + 51721 * phi**2 - T, S)
    assert check.valid, check.reason
    form = check.canonical
    assert form.mass == pytest.approx(7.918e-5)
    assert dict(form.state) == {phi: pytest.approx(413.191), phi**2: pytest.approx(51721)}
    assert dict(form.forcing) == {T: 1.0}


def test_accepts_eq23_written_as_an_equation_with_the_input_scaled():
    J1, r1, km = 2e-3, 0.038, 3e8
    check = check_structure(sp.Eq(2 * (J1 * phi_ddot + r1 * km * phi), 2 * T), S)
    assert check.valid, check.reason
    assert check.canonical.mass == pytest.approx(J1)
    assert dict(check.canonical.state)[phi] == pytest.approx(r1 * km)


@pytest.mark.parametrize("expression, words", [
    (phi_ddot * phi + phi - T, "constant inertia"),
    (phi * phi_dot + phi_ddot - T, "cross term"),
    (phi + phi**2 - T, "no phi_ddot"),
    (phi_ddot + phi * T, "cross term"),
    (phi_ddot**2 + phi - T, "other than as a constant"),
    (phi_ddot + phi * t, "cross term"),
])
def test_rejects_with_a_reason(expression, words):
    check = check_structure(expression, S)
    assert not check.valid
    assert words in check.reason


def test_expansion_reveals_hidden_cross_terms_and_cancellations():
    # (phi_ddot + phi)(1 + phi) hides phi*phi_ddot; (phi + 1)**2 - phi**2 - 1 cancels to 2*phi.
    assert not check_structure((phi_ddot + phi) * (1 + phi) - T, S).valid
    check = check_structure(phi_ddot + (phi + 1) ** 2 - phi**2 - 1 - T, S)
    assert check.valid and dict(check.canonical.state) == {phi: 2.0}


def test_max_degree_limits_bloat():
    assert check_structure(phi_ddot + phi**5 - T, S).valid
    assert not check_structure(phi_ddot + phi**5 - T, S, max_degree=4).valid


def test_without_input_the_mass_is_one():
    check = check_structure(3 * phi_ddot + 6 * phi + 1.5 * phi_dot**3, S)
    assert check.valid
    assert check.canonical.mass == 1.0
    assert dict(check.canonical.state) == {phi: 2.0, phi_dot**3: 0.5}


def test_tree_to_sympy_uses_constant_values_and_protected_division():
    tree = ("add", ("mul", ("c", "J"), ("x_ddot",)),
            ("sub", ("div", ("x",), ("sub", ("t",), ("t",))), ("u", 0)))
    expression = tree_to_sympy(tree, S, {"J": 2.0})
    assert sp.simplify(expression - (2.0 * phi_ddot + 1 - T)) == 0


def test_abs_of_exp_stays_real():
    """|exp(u)| is exp(u) for a real signal (sympy alone writes exp(re(u)), which no tree,
    model file or evaluator can hold); a fit once crashed on it."""
    tree = ("sub", ("x_ddot",), ("abs", ("exp", ("mul", ("n", 2.0), ("u", 0)))))
    expression = tree_to_sympy(tree, S, {})
    assert not expression.has(sp.re)
    assert sp.simplify(expression - (phi_ddot - sp.exp(2.0 * T))) == 0
