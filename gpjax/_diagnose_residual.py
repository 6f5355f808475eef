"""Diagnosis: what a residual that no library effect explains looks like.

When the loop stops with the final residual far above its noise floor
(:func:`gpjax._diagnose_noise.noise_floor`: rms ≥ 1.5 σ̂ — in-band residual energy at least
1.25× the noise's — and the in-band excess significant at ``alpha``), the report says so and
describes the residual:

* **spectral lines** — the :data:`LINES` strongest significant sinusoids
  (:func:`gpjax._diagnose_noise.lines`, level ``alpha``), each related to the input's lines
  where it lies within one DFT bin of a harmonic k·f (k = 1 … 10) or of a sum or difference f_i ± f_j;
* **dependence on x and on x'** — the residual's mean in quantile bins of each, with the
  share of its variance those means hold (η²) and an F test whose denominator degrees of
  freedom are the residual's effective sample size n·γ0/LRV (its autocorrelation counted
  as in :func:`gpjax._diagnose_acceptance.long_run_variance`);
* **hysteresis** — the further share of variance held when each x bin is split by the sign
  of x' (two branches in the (x, residual) plane), with its F test.

From the significant features (the three dependence tests Bonferroni-corrected, α/3) a
kind of missing term, and the GP function set that would
search for it (``functions`` of the configuration), is suggested.
"""

from __future__ import annotations


import numpy as np
from scipy import special

from ._diagnose_acceptance import long_run_variance
from ._diagnose_noise import lines

#: Strongest residual lines described (found strongest first).
LINES = 6
#: Quantile bins of x and x' for the conditional mean.
BINS = 10
#: The residual is "far above" its noise floor from this RMS ratio (energy 1.25× the noise's
#: in band, on top of the noise itself).
FAR_ABOVE = 1.5


def describe_residual(residual: np.ndarray, *, x: np.ndarray, x_dot: np.ndarray, dt: float,
                      input_lines: list[float], alpha: float) -> dict:
    """Lines, dependence on x and x', hysteresis and suggestions (module docstring)."""
    n = residual.size
    variance, lrv = float(np.var(residual)), long_run_variance(residual - np.mean(residual))[0]
    n_eff = max(BINS + 2.0, n * variance / lrv) if lrv > 0 else float(n)
    found = (lines(residual, dt, alpha=alpha)[1] or [])[:LINES]
    step = 1.0 / (n * dt)
    described = [{"hz": f, "relation": _relation(f, input_lines, step)} for f in found]
    by_x = _binned(residual, [x], n_eff)
    by_v = _binned(residual, [x_dot], n_eff)
    both = _binned(residual, [x, np.sign(x_dot)], n_eff)
    hysteresis = {"eta2": max(0.0, both["eta2"] - by_x["eta2"]),
                  "p_value": _incremental_p(by_x, both, n_eff)}
    out = {"lines": described, "x": by_x, "x_dot": by_v, "hysteresis": hysteresis,
           "effective_samples": n_eff}
    out["suggestions"] = _suggestions(out, alpha)
    return out


def _relation(f: float, inputs: list[float], step: float) -> str:
    for fi in inputs:
        for k in range(1, 11):
            if abs(f - k * fi) <= step:
                return "input line" if k == 1 else f"{k}× the input line {fi:.4g} Hz"
    for i, fi in enumerate(inputs):
        for fj in inputs[i + 1:]:
            if abs(f - (fi + fj)) <= step:
                return f"sum of input lines {fi:.4g} + {fj:.4g} Hz"
            if abs(f - abs(fi - fj)) <= step:
                return f"difference of input lines {fi:.4g} − {fj:.4g} Hz"
    return "unrelated to the input's lines"


def _binned(residual: np.ndarray, keys: list[np.ndarray], n_eff: float) -> dict:
    """η² of the residual's mean in the cells of ``keys`` (the first in :data:`BINS`
    quantile bins, the others used as given), its F-test p-value and the bin means."""
    edges = np.quantile(keys[0], np.linspace(0, 1, BINS + 1)[1:-1])
    cells = np.searchsorted(edges, keys[0])
    for key in keys[1:]:
        cells = cells * 3 + (np.asarray(key) + 1).astype(int)
    labels, index = np.unique(cells, return_inverse=True)
    counts = np.bincount(index)
    means = np.bincount(index, weights=residual) / counts
    total = float(np.sum((residual - residual.mean()) ** 2))
    between = float(np.sum(counts * (means - residual.mean()) ** 2))
    eta2 = between / total if total > 0 else 0.0
    groups = labels.size
    p = _f_p(eta2, groups - 1, n_eff - groups)
    return {"eta2": eta2, "p_value": p, "groups": int(groups),
            "bin_means": [float(v) for v in means] if len(keys) == 1 else None}


def _f_p(eta2: float, df1: float, df2: float) -> float:
    if df1 <= 0 or df2 <= 0 or eta2 >= 1:
        return 0.0 if eta2 >= 1 else 1.0
    return float(special.fdtrc(df1, df2, max((eta2 / df1) / ((1 - eta2) / df2), 0.0)))


def _incremental_p(small: dict, large: dict, n_eff: float) -> float:
    df1 = large["groups"] - small["groups"]
    df2 = n_eff - large["groups"]
    gain = large["eta2"] - small["eta2"]
    if df1 <= 0 or df2 <= 0 or gain <= 0:
        return 1.0
    return float(special.fdtrc(df1, df2, max((gain / df1) / ((1 - large["eta2"]) / df2), 0.0)))


def _suggestions(d: dict, alpha: float) -> list[str]:
    alpha = alpha / 3  # Bonferroni over the three dependence tests
    out = []
    if d["hysteresis"]["p_value"] < alpha:
        out.append("hysteresis in the (x, residual) plane: a force that depends on the "
                   "direction of motion (dry friction, backlash): GP functions sign, abs, tanh")
    if d["x_dot"]["p_value"] < alpha and d["x_dot"]["eta2"] >= d["x"]["eta2"]:
        out.append("the residual depends on x': a dissipative term of another shape "
                   "(Stribeck friction, x'|x'|): GP functions sign, abs, tanh, exp")
    if d["x"]["p_value"] < alpha and d["x"]["eta2"] > d["x_dot"]["eta2"]:
        out.append("the residual depends on x: a restoring force of another shape "
                   "(saturating, piecewise, higher power): GP functions tanh, abs, exp")
    relations = [line["relation"] for line in d["lines"][:3]]  # the strongest three
    if any("×" in r for r in relations):
        out.append("lines at harmonics of the input's: a nonlinear restoring or damping "
                   "term (polynomial degree above 3; GP functions abs, tanh)")
    if any(r.startswith(("sum", "difference")) for r in relations):
        out.append("lines at sums or differences of the input's: a time-varying (parametric) "
                   "term g(t)·h(x): GP functions sin, cos")
    if any(r.startswith("unrelated") for r in relations):
        out.append("lines unrelated to the input: a time-varying stiffness or an unmeasured "
                   "periodic input at those frequencies (--frequency; GP functions sin, cos)")
    return out
