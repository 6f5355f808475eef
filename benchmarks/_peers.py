"""The physics benchmark's peers: PySINDy and pyoperon, each returning x'' = f(x, x', u) as
a sympy equation for the common scorer.

Both see the same data as gpjax — the measured response and measured input of the fit
record — and the same derivatives: a Savitzky–Golay filter (window
:data:`SAVGOL_WINDOW` samples, polynomial order :data:`SAVGOL_ORDER`) gives the smoothed
x, x' and x''. A peer that is not installed raises :class:`PeerUnavailable`.
"""

from __future__ import annotations

from importlib import metadata

import numpy as np
import sympy as sp
from scipy.signal import savgol_filter

X, X_DOT, X_DDOT, U = sp.symbols("x x_dot x_ddot u")
NAMES = ("x", "x_dot", "u")
SAVGOL_WINDOW, SAVGOL_ORDER = 21, 5
#: PySINDy's sequentially thresholded least squares: threshold on the coefficients in the
#: data's units (0.05 on unit-norm columns kept 15 spurious terms on the Duffing system,
#: 0.2 here kept 9, 0.5 kept 7 and would drop a 0.6 N·s/m damping).
SINDY_THRESHOLD = 0.2
#: Functions of one variable in PySINDy's library, beside polynomials of degree ≤ 3 in
#: (x, x', u): each name is the sympy text of the feature ({} is the variable).
SINDY_FUNCTIONS = {"sin({})": lambda y: np.sin(y), "cos({})": lambda y: np.cos(y),
                   "Abs({})": lambda y: np.abs(y), "sign({})": lambda y: np.sign(y),
                   "{0}*Abs({0})": lambda y: y * np.abs(y)}
OPERON_SYMBOLS = "add,sub,mul,div,constant,variable,sin,cos,abs,tanh,exp"
PEERS = ("pysindy", "pyoperon")


class PeerUnavailable(RuntimeError):
    """The peer's package is not installed."""


def versions() -> dict[str, str]:
    """Peer -> installed version, or the text "not installed"."""
    out = {}
    for name in PEERS:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def smoothed(measurement) -> np.ndarray:
    """(N, 4) columns x, x', x'', u: Savitzky–Golay of the measured response, measured u."""
    dt = measurement.dt
    x = measurement.response
    columns = [savgol_filter(x, SAVGOL_WINDOW, SAVGOL_ORDER, deriv=d, delta=dt)
               for d in (0, 1, 2)]
    return np.column_stack([*columns, measurement.inputs["u"]])


def fit_peer(name: str, measurement, *, seed: int) -> sp.Eq:
    """``Eq(x_ddot, f(x, x_dot, u))`` found by peer ``name`` on ``measurement``; pyoperon
    runs at its own defaults (population 1000, at most 1000 generations and 1e6
    evaluations; with gpjax's 100 × 3 of ``--quick`` it did not even find the u term).

    Raises:
        ValueError: an unknown peer.
        PeerUnavailable: its package is not installed.
    """
    if name not in PEERS:
        raise ValueError(f"unknown peer {name!r}; use one of {PEERS}")
    data = smoothed(measurement)
    try:
        if name == "pysindy":
            return _sindy(data, measurement.dt)
        return _operon(data, seed=seed)
    except ImportError as err:
        raise PeerUnavailable(f"{name} is not installed ({err}); pip install -e .[peers]") \
            from None


def _sindy(data: np.ndarray, dt: float) -> sp.Eq:
    import pysindy as ps

    functions = list(SINDY_FUNCTIONS.values())
    names = [lambda y, text=text: text.format(y) for text in SINDY_FUNCTIONS]
    library = ps.PolynomialLibrary(degree=3) + ps.CustomLibrary(
        library_functions=functions, function_names=names)
    model = ps.SINDy(optimizer=ps.STLSQ(threshold=SINDY_THRESHOLD),
                     feature_library=library)
    state, derivative = data[:, :2], data[:, 1:3]
    model.fit(state, t=dt, x_dot=derivative, u=data[:, 3:], feature_names=list(NAMES))
    symbols = {"x": X, "x_dot": X_DOT, "u": U, "sign": sp.sign, "Abs": sp.Abs}
    rhs = sp.Integer(0)
    for text, value in zip(model.get_feature_names(), model.coefficients()[1]):
        if value != 0.0:
            term = text.replace("^", "**").replace(" ", "*")
            rhs += float(value) * sp.sympify(term, locals=symbols)  # our own library's names
    return sp.Eq(X_DDOT, rhs)


def _operon(data: np.ndarray, *, seed: int) -> sp.Eq:
    from pyoperon.sklearn import SymbolicRegressor

    regressor = SymbolicRegressor(allowed_symbols=OPERON_SYMBOLS, random_state=seed,
                                  n_threads=1, max_length=30)
    inputs = np.column_stack([data[:, 0], data[:, 1], data[:, 3]])
    regressor.fit(inputs, data[:, 2])
    text = regressor.get_model_string(regressor.model_, 12, names=list(NAMES))
    symbols = {"x": X, "x_dot": X_DOT, "u": U, "abs": sp.Abs}
    return sp.Eq(X_DDOT, sp.sympify(text.replace("^", "**"), locals=symbols))  # operon's text
