"""The physics benchmark's peers: PySINDy and pyoperon, each returning x'' = f(x, x', u) as
a sympy equation for the common scorer.

Both see the same data as gpjax — the measured response and measured input of the fit
record — and the same derivatives: a Savitzky–Golay filter (window
:data:`SAVGOL_WINDOW` samples, polynomial order :data:`SAVGOL_ORDER`) gives the smoothed
x, x' and x''. A peer that is not installed raises :class:`PeerUnavailable`.
"""

from __future__ import annotations

from importlib import metadata
from itertools import combinations_with_replacement

import numpy as np
import sympy as sp
from scipy.signal import savgol_filter

X, X_DOT, X_DDOT, U = sp.symbols("x x_dot x_ddot u")
NAMES = ("x", "x_dot", "u")
SAVGOL_WINDOW, SAVGOL_ORDER = 21, 5
#: PySINDy's sequentially thresholded least squares (unit-norm columns): the thresholds
#: tried, the one kept chosen by held-out validation (fit on the first
#: 1 − :data:`HOLDOUT` of the record, the lowest RMS error of x'' on the rest).
SINDY_THRESHOLDS = tuple(np.geomspace(1e-3, 1.0, 13))
HOLDOUT = 0.25
#: Dimensionless scales of the scaled families (a = scale / std of the variable), so that
#: the library can write tanh(a·x), sinh(a·x), exp(−(a·x')²)·sign(x') and tanh(a·x') for
#: the suite's truths to within a factor √2 of their inner constant.
SINDY_SCALES = tuple(2.0 ** np.arange(-2.0, 4.5, 0.5))
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


def fit_peer(name: str, measurement, *, seed: int, seconds: float | None = None) -> sp.Eq:
    """``Eq(x_ddot, f(x, x_dot, u))`` found by peer ``name`` on ``measurement``, each set up
    at its best (:func:`_sindy`, :func:`_operon`); ``seconds``: pyoperon's time budget (the
    physics suite gives it gpjax's time on the same record).

    Raises:
        ValueError: an unknown peer.
        PeerUnavailable: its package is not installed.
    """
    if name not in PEERS:
        raise ValueError(f"unknown peer {name!r}; use one of {PEERS}")
    data = smoothed(measurement)
    try:
        if name == "pysindy":
            return _sindy(data)
        return _operon(data, seed=seed, seconds=seconds)
    except ImportError as err:
        raise PeerUnavailable(f"{name} is not installed ({err}); pip install -e .[peers]") \
            from None


def sindy_library(data: np.ndarray) -> tuple[np.ndarray, list[sp.Expr]]:
    """(N, F) candidate columns and their sympy features: polynomials of degree ≤ 3 in
    (x, x', u); sin x, cos x, x'|x'|, sign x'; and at every scale of
    :data:`SINDY_SCALES`, tanh(a·x), sinh(a·x), tanh(a·x') and exp(−(a·x')²)·sign(x'), a the
    scale over the variable's standard deviation on ``data`` (x, x', x'', u columns)."""
    values = {X: data[:, 0], X_DOT: data[:, 1], U: data[:, 3]}
    features = [sp.Integer(1)] + [sp.Mul(*combo) for degree in (1, 2, 3)
                                  for combo in combinations_with_replacement((X, X_DOT, U), degree)]
    features += [sp.sin(X), sp.cos(X), X_DOT * sp.Abs(X_DOT), sp.sign(X_DOT)]
    for scale in SINDY_SCALES:
        a_x = sp.Float(scale / np.std(data[:, 0]), 6)
        a_v = sp.Float(scale / np.std(data[:, 1]), 6)
        features += [sp.tanh(a_x * X), sp.sinh(a_x * X), sp.tanh(a_v * X_DOT),
                     sp.exp(-(a_v * X_DOT) ** 2) * sp.sign(X_DOT)]
    function = sp.lambdify((X, X_DOT, U), features, "numpy")
    columns = [np.broadcast_to(np.asarray(c, dtype=float), data[:, 0].shape)
               for c in function(values[X], values[X_DOT], values[U])]
    return np.column_stack(columns), features


def _sindy(data: np.ndarray) -> sp.Eq:
    """PySINDy's STLSQ on :func:`sindy_library`'s columns (normalised), its threshold
    chosen by held-out validation of x''."""
    import pysindy as ps

    theta, features = sindy_library(data)
    target = data[:, 2]
    cut = int(round((1 - HOLDOUT) * target.size))

    def fitted(threshold, rows):
        optimizer = ps.STLSQ(threshold=threshold, normalize_columns=True)
        optimizer.fit(theta[rows], target[rows])
        return np.asarray(optimizer.coef_).reshape(-1)

    errors = []
    for threshold in SINDY_THRESHOLDS:
        coefficients = fitted(threshold, slice(0, cut))
        errors.append(float(np.sqrt(np.mean((theta[cut:] @ coefficients - target[cut:]) ** 2))))
    best = SINDY_THRESHOLDS[int(np.argmin(errors))]
    coefficients = fitted(best, slice(None))
    rhs = sum((float(c) * f for c, f in zip(coefficients, features) if c != 0.0),
              sp.Integer(0))
    return sp.Eq(X_DDOT, rhs)


def _operon(data: np.ndarray, *, seed: int, seconds: float | None) -> sp.Eq:
    """pyoperon at its defaults (population 1000, max length 50, model chosen from the
    final front by minimum description length) with its parsimony (objectives R² and
    length: NSGA-II), 10 Levenberg–Marquardt iterations per evaluation (its default 0 tunes
    no constant) and ``seconds`` of wall time."""
    from pyoperon.sklearn import SymbolicRegressor

    regressor = SymbolicRegressor(allowed_symbols=OPERON_SYMBOLS, random_state=seed,
                                  n_threads=1, objectives=["r2", "length"],
                                  optimizer_iterations=10,
                                  max_time=None if seconds is None else max(1, int(seconds)))
    inputs = np.column_stack([data[:, 0], data[:, 1], data[:, 3]])
    regressor.fit(inputs, data[:, 2])
    text = regressor.get_model_string(regressor.model_, 12, names=list(NAMES))
    symbols = {"x": X, "x_dot": X_DOT, "u": U, "abs": sp.Abs}
    return sp.Eq(X_DDOT, sp.sympify(text.replace("^", "**"), locals=symbols))  # operon's text
