"""Standard errors and 95 % intervals of a fitted model's constants and initial state.

The reported constants θ̂ minimise the output error Σ_t ‖W(x_t(θ) − y_t)‖² (the simulated
response against the measured one, W the per-coordinate weights of refinement). Their
covariance is the sandwich

    Cov θ̂ = A⁻¹ S A⁻¹,   A = Σ_t J_tᵀW²J_t,   S = Var(Σ_t g_t),   g_t = J_tᵀW²r_t,

J_t = ∂x_t/∂θ from the variational equations at the converged step count
(:meth:`gpjax._refine.Refiner.sensitivity`), r_t the residual.

S is estimated in the frequency domain. The residual and the Jacobian are taken to the
real orthonormal Fourier basis (Parseval keeps A and the score unchanged); each rfft bin f
(its cosine and sine parts, all coordinates) is one cluster, whose scores are nearly
independent of the other bins' for any stationary residual, whatever its spectrum. S is the
cluster-robust sum over bins with each bin's leverage removed, CR3 (the jackknife form,
MacKinnon & White 1985): s_f = X_fᵀ(I − H_f)⁻¹u_f, H_f = X_f A⁻¹X_fᵀ. Intervals are
θ̂ ± t₀.₉₇₅(ν)·se, ν each constant's Satterthwaite degrees of freedom: its variance is a sum
over bins of scaled χ²₁ terms, ν = (Σ_f a_f)²/Σ_f a_f², with each bin's observed share a_f.

Why this estimator. The residual of a simulated response is autocorrelated, and not
simply: noise on the measured input passes through the dynamics and rings near the
resonance, a small narrow-band part under the white response noise. It sits in the band
where the sensitivities live, so it dominates the constants' error, and the fit absorbs
about half of it there. A Newey–West covariance with Andrews' AR(1) bandwidth chose 4–8
lags on Duffing records and gave intervals 2–3× too narrow (z-scores of the truth of
±3–6); batch means (20 batches) still gave sd(z) of 1.3–2.3. Bins in which the constants'
sensitivities are concentrated have high leverage; removing it puts back the part of the
residual the fit absorbed. A few bins carry most of a constant's information when its
sensitivity is narrow-band, and then ν is small and the t quantile widens the interval
accordingly. The zero bin is one real value per coordinate (its sine part is 0): its own
residual is a single χ²₁ draw, and a fitted static balance (a stiffness against the mean
force, or the initial state of an undamped oscillator, whose mean it sets) takes nearly
all of it, so leverage near 1 would inflate that one draw by (1 − h)⁻² (on the demo's
undamped eq. 14, h = 0.9998: k1's interval was 34 % where its spread over noise seeds is
0.3 %). Its residual variance is therefore always read from the lowest bins
(:data:`NEIGHBOURS`: the spectral density at zero frequency, as long-run variance
estimators take it), which also gives a constant force, fitted by the zero bin alone
(leverage 1, no residual left), its interval. Elsewhere, where a bin's leverage is 1 in
some direction (a sinusoid on one bin, where at a resonance the spectrum can peak between
its neighbours), the constants loading on that direction get an infinite variance (no
interval) rather than a ratio of rounding errors. A block bootstrap would refit the model
hundreds of times where this needs one Jacobian.

What the interval does not count: the input's reconstruction between samples (linear
interpolation of a band-limited input is a systematic error that moved the constants by
one to two standard errors on Duffing records; each such fit records the shift,
``reconstruction_shift``, and ``input_interpolation = "bandlimited"`` removes it) and a smoothed sign's width (:mod:`gpjax._sign_width`); inner constants of a
family (a sin's frequency, a tanh's width) get the same linearised interval, poor where the
objective is far from quadratic in them. ``benchmarks/interval_coverage.py`` measures how
often the intervals cover the truth.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from scipy import special

#: |correlation| from which two constants are reported as correlated.
HIGH_CORRELATION = 0.9
#: Eigenvalue of the column-normalised A, relative to its largest, below which a
#: combination of the constants is not identifiable from the record (the constants that
#: make it up get infinite standard errors).
RANK_TOLERANCE = 1e-12
#: A frequency bin's leverage within this of 1 in some direction (rounding: I − H_f is
#: singular) fits that direction alone: its residual there is 0 whatever the noise. Outside
#: the zero bin (whose variance is always read from the lowest :data:`NEIGHBOURS` bins) —
#: a sinusoid on one bin, at a resonance the local spectrum can peak — a constant loading
#: on such a direction by more than :data:`LOADING` (in units of its √[A⁻¹]ₖₖ) has no
#: estimable variance.
SATURATED, LOADING = 1e-13, 1e-9
#: The zero bin's residual variance comes from this many lowest bins without a saturated
#: direction (their 2·q cosine and sine parts): the spectral density at zero frequency
#: estimated from the lowest frequencies, q as in low-frequency long-run variance
#: estimation (Müller 2007, q = 12), so its relative standard error is about 1/√(2q) ≈ 0.2.
NEIGHBOURS = 12


@dataclasses.dataclass(frozen=True)
class Uncertainty:
    """Constants with standard errors, 95 % intervals and correlations.

    Attributes:
        names: constant names (the model's: m, k1, c1, … ; x(0), x'(0) for the initial
            state; ``k2.θ1`` for a family's inner constant).
        values: (k,) their values.
        covariance: (k, k) in the constants' units (inf on the diagonal where the record
            cannot identify them).
        dof: (k,) each standard error's effective degrees of freedom (its t quantile).
        n_samples: samples (times) of the fitted record.
        reconstruction_shift: (k,) for a fit with linearly interpolated inputs, how far
            each constant would move were the inputs reconstructed band-limited instead
            (one Gauss–Newton step), or ``None``: a systematic error the interval does not
            count.
        profile: name -> (low, high), the profile 95 % interval of a family's inner
            constant (:mod:`gpjax._profile`), which :meth:`interval` then gives.
    """

    names: tuple[str, ...]
    values: np.ndarray
    covariance: np.ndarray
    dof: np.ndarray
    n_samples: int
    reconstruction_shift: np.ndarray | None = None
    profile: dict[str, tuple[float, float]] = dataclasses.field(default_factory=dict)

    def quantile(self, name: str) -> float:
        """t₀.₉₇₅ with ``name``'s degrees of freedom: half its interval in standard errors."""
        return t_quantile(float(self.dof[self.names.index(name)]))

    @property
    def standard_errors(self) -> dict[str, float]:
        return dict(zip(self.names, np.sqrt(np.diag(self.covariance)).tolist()))

    def interval(self, name: str) -> tuple[float, float]:
        """95 % interval of constant ``name``: its profile interval if it has one, else
        value ± t·se (KeyError if it has none)."""
        if name in self.profile:
            return self.profile[name]
        value = float(self.values[self.names.index(name)])
        half = self.quantile(name) * self.standard_errors[name]
        return value - half, value + half

    def half_width(self, name: str) -> float | None:
        """Half the 95 % interval of ``name`` (of a profile interval: half its length), or
        ``None`` if it has none."""
        if name not in self.names:
            return None
        low, high = self.interval(name)
        return (high - low) / 2

    def __eq__(self, other) -> bool:
        return (isinstance(other, Uncertainty) and self.names == other.names
                and self.n_samples == other.n_samples
                and all(np.array_equal(a, b, equal_nan=True) for a, b in (
                    (self.values, other.values), (self.covariance, other.covariance),
                    (self.dof, other.dof))) and (
                        (self.reconstruction_shift is None) == (other.reconstruction_shift is None))
                and self.profile == other.profile
                and (self.reconstruction_shift is None or np.array_equal(
                    self.reconstruction_shift, other.reconstruction_shift)))

    __hash__ = None

    @property
    def correlation(self) -> np.ndarray:
        se = np.sqrt(np.diag(self.covariance))
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.covariance / np.outer(se, se)

    def reconstruction_warning(self) -> str | None:
        """A line naming the constants that band-limited input reconstruction would move by
        more than one standard error, or ``None``."""
        if self.reconstruction_shift is None:
            return None
        se = self.standard_errors
        moved = [f"{n} by {d / se[n]:+.1f} se" for n, d in zip(self.names,
                                                              self.reconstruction_shift)
                 if math.isfinite(se[n]) and abs(d) > se[n]]
        if not moved:
            return None
        return ("linear input interpolation: reconstructing the input band-limited would move "
                + ", ".join(moved) + "; if the input was anti-alias filtered, fit again with "
                "--input-interpolation bandlimited")

    def correlated(self, threshold: float = HIGH_CORRELATION) -> list[tuple[str, str, float]]:
        """Pairs of constants whose |correlation| ≥ ``threshold``."""
        rho = self.correlation
        return [(a, b, float(rho[i, j])) for i, a in enumerate(self.names)
                for j, b in enumerate(self.names)
                if j > i and math.isfinite(rho[i, j]) and abs(rho[i, j]) >= threshold]

    def to_json(self) -> dict:
        se = self.standard_errors
        rho = self.correlation
        return {"level": 0.95,
                "method": "sandwich: Gauss-Newton bread, frequency-domain CR3 meat, "
                          "t quantile with Satterthwaite degrees of freedom; inner "
                          "constants of a family: profile intervals at the sandwich's scale",
                "samples": self.n_samples,
                "constants": {n: {"value": float(v), "se": _finite(se[n]),
                                  "dof": float(f),
                                  "interval": "profile" if n in self.profile else "wald",
                                  "low": _finite(self.interval(n)[0]),
                                  "high": _finite(self.interval(n)[1])}
                              for n, v, f in zip(self.names, self.values, self.dof)},
                **({} if self.reconstruction_shift is None else {
                    "bandlimited_input_shift": dict(zip(self.names, map(
                        float, self.reconstruction_shift)))}),
                "correlation": [[_finite(x) for x in row] for row in rho.tolist()],
                "covariance": [[_finite(x) for x in row] for row in self.covariance.tolist()]}

    @classmethod
    def from_json(cls, data: dict) -> "Uncertainty":
        """Inverse of :meth:`to_json` (KeyError/TypeError/ValueError on a malformed one)."""
        names = tuple(data["constants"])
        covariance = np.array([[_number(x) for x in row] for row in data["covariance"]],
                              dtype=float)
        if covariance.shape != (len(names), len(names)):
            raise ValueError("the covariance matrix does not match the constants")
        return cls(names=names,
                   values=np.array([float(data["constants"][n]["value"]) for n in names]),
                   covariance=covariance,
                   dof=np.array([float(data["constants"][n]["dof"]) for n in names]),
                   n_samples=int(data["samples"]),
                   reconstruction_shift=None if "bandlimited_input_shift" not in data else
                   np.array([float(data["bandlimited_input_shift"][n]) for n in names]),
                   profile={n: (float(c["low"]), float(c["high"]))
                            for n, c in data["constants"].items()
                            if c.get("interval") == "profile"})


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None  # JSON has no inf/NaN: null


def _number(x) -> float:
    """A JSON number back: null was a non-finite value (an unidentifiable constant's)."""
    return math.inf if x is None else float(x)


def sandwich_covariance(residual: np.ndarray, jacobian: np.ndarray,
                        weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(covariance (k, k) of least-squares constants, each constant's effective degrees of
    freedom (k,)) from the residual (N,) or (N, D), its Jacobian by the constants (N, k)
    or (N, D, k) and per-coordinate weights (D,): the frequency-domain CR3 sandwich of the
    module docstring. Constants the record cannot identify get an infinite variance."""
    n = residual.shape[0]
    d = residual.size // n
    k = jacobian.shape[-1]
    w = np.ones(d) if weights is None else np.asarray(weights, dtype=float)
    u = _orthonormal_fourier(residual.reshape(n, d) * w)            # (F, 2, D)
    x = _orthonormal_fourier(jacobian.reshape(n, d, k) * w[None, :, None])  # (F, 2, D, k)
    bins = u.shape[0]
    u, x = u.reshape(bins, 2 * d), x.reshape(bins, 2 * d, k)
    bread = np.einsum("fmk,fml->kl", x, x)
    norm = np.sqrt(np.diag(bread))
    if not np.all(norm > 0):
        return np.diag(np.where(norm > 0, np.nan, np.inf)), np.ones(k)
    unit = bread / np.outer(norm, norm)
    # Directions of the constants the record does not determine (eigenvalues of the
    # column-normalised A below RANK_TOLERANCE of the largest) are left out of the inverse;
    # the constants that make up such a combination (a share of it at least 1/k of the
    # largest share) have no interval, the others keep theirs (two inputs whose measured
    # records are nearly proportional leave a gear's masses and stiffness determined).
    eigenvalues, basis = np.linalg.eigh(unit)
    null = eigenvalues < RANK_TOLERANCE * eigenvalues[-1]
    if null.all():
        return np.diag(np.full(k, np.inf)), np.ones(k)
    shares = basis[:, null] ** 2
    undetermined = np.any(shares >= shares.max(axis=0, initial=0.0) / k, axis=1)
    inverse = ((basis[:, ~null] / eigenvalues[~null]) @ basis[:, ~null].T
               / np.outer(norm, norm))
    # Each bin's leverage H_f = X_f A⁻¹ X_fᵀ; its residual inflated by (I − H_f)⁻¹ (CR3).
    # A direction with leverage 1 is fitted by that bin alone: its residual is 0 and the
    # jackknife cannot estimate its variance there; the constants that load on it get none
    # (infinite). The zero bin's variance is read from the lowest bins instead
    # (:func:`_zero_bin`), where there are any.
    leverage = np.einsum("fmk,kl,fnl->fmn", x, inverse, x)
    eigenvalues, vectors = np.linalg.eigh((leverage + np.swapaxes(leverage, 1, 2)) / 2)
    saturated = eigenvalues > 1.0 - SATURATED
    shrink = np.where(saturated, 0.0, 1.0 / np.where(saturated, 1.0, 1.0 - eigenvalues))
    inflated = np.einsum("fmn,fn->fm", vectors,
                         shrink * np.einsum("fnm,fn->fm", vectors, u))
    per_bin = np.einsum("fmk,fm->fk", x, inflated) @ inverse       # (F, k): A⁻¹X_fᵀũ_f
    clean = np.flatnonzero(~saturated.any(axis=1))
    near = clean[clean > 0][:NEIGHBOURS]  # the zero bin's neighbours (:func:`_zero_bin`)
    interior = saturated.copy()
    interior[0] &= near.size == 0  # with no neighbour the zero bin has no estimate either
    loading = np.abs(np.einsum("fmk,fmn->fnk", x, vectors) @ inverse)[interior]  # (S, k)
    unknown = np.any(loading > LOADING * np.sqrt(np.diag(inverse)), axis=0) | undetermined
    # Satterthwaite: a constant's variance is Σ_f a_f, a_f the square of one normal
    # combination of bin f (a scaled χ²₁), so its degrees of freedom are
    # (Σ E a)²/Σ (E a)²/ν_f, here with each bin's observed share for E a (module
    # docstring); ν_f = 1, and 2q for the zero bin read from its q neighbours (at most
    # NEIGHBOURS: a short record has fewer).
    if near.size:
        per_bin = per_bin[1:]
        zero, zero_share = _zero_bin(x[0, :d], inflated[near], inverse, d)
    else:
        zero, zero_share = np.zeros((k, k)), np.zeros((0, k))
    covariance = per_bin.T @ per_bin + zero
    share = np.concatenate([per_bin ** 2, zero_share])
    spread = (np.sum(per_bin ** 4, axis=0)
              + np.sum(zero_share ** 2, axis=0) / (2 * max(near.size, 1)))
    with np.errstate(invalid="ignore", divide="ignore"):
        dof = np.nan_to_num(share.sum(axis=0) ** 2 / spread, nan=1.0)
    covariance = (covariance + covariance.T) / 2
    covariance[unknown, :] = covariance[:, unknown] = 0.0
    covariance[unknown, unknown] = np.inf
    return covariance, np.where(unknown, 1.0, dof)


def _zero_bin(x0: np.ndarray, near: np.ndarray, inverse: np.ndarray,
              d: int) -> tuple[np.ndarray, np.ndarray]:
    """The zero bin's covariance (k, k) and its shares (D, k). ``x0`` (D, k): its
    Jacobian rows (the cosine part; the sine part is 0); ``near``: the inflated residuals ũ
    (cosine and sine parts, D each) of the :data:`NEIGHBOURS` lowest bins without a
    saturated direction, which estimate the spectral matrix C = E[ũ_c ũ_cᵀ + ũ_s ũ_sᵀ] near
    zero frequency. In the orthonormal transform each part of white noise of variance σ²
    has variance σ², the zero bin's one part too, so its residual has covariance ½C and
    adds L·½C·Lᵀ, L = A⁻¹X₀ᵀ. Each eigen-direction of ½C (variance λ_j along e_j) is one
    share λ_j·(L e_j)²."""
    parts = near.reshape(near.shape[0], 2, d)
    spectral = 0.5 * np.einsum("fpa,fpb->ab", parts, parts) / near.shape[0]
    variances, directions = np.linalg.eigh(spectral)
    variances = np.maximum(variances, 0.0)[:, None]              # rounding can give −0
    loadings = (inverse @ x0.T @ directions).T                    # (D, k): L e_j
    return loadings.T @ (variances * loadings), variances * loadings ** 2


def _orthonormal_fourier(a: np.ndarray) -> np.ndarray:
    """The real orthonormal Fourier transform of ``a`` along its first axis (N, …) as
    (F, 2, …): cosine and sine parts of each rfft bin, scaled so the transform keeps sums
    of products (Parseval); the sine part of the zero (and Nyquist) bin is 0."""
    n = a.shape[0]
    spectrum = np.fft.rfft(a, axis=0)
    scale = np.full(spectrum.shape[0], math.sqrt(2.0 / n))
    scale[0] = math.sqrt(1.0 / n)
    if n % 2 == 0:
        scale[-1] = math.sqrt(1.0 / n)
    scale = scale.reshape((-1,) + (1,) * (a.ndim - 1))
    return np.stack([spectrum.real * scale, -spectrum.imag * scale], axis=1)


def fitted_uncertainty(fitness, record, model) -> Uncertainty:
    """The :class:`Uncertainty` of a search's ``record`` on ``fitness``'s record and
    evaluator (``model``: the record as a :class:`gpjax.Model`, whose names it uses)."""
    return uncertainty_of(fitness.refiner, fitness.population([record]),
                          *fitness.held([record]), names=lambda sensitivity: model_names(
                              sensitivity, model, fitness.evaluator, [record.coefficients]))


def uncertainty_of(refiner, population, fixed_forcing, held_inner=None, *, names,
                   ties=None) -> Uncertainty:
    """The :class:`Uncertainty` of the one model of ``population`` fitted on
    ``refiner``'s record; ``fixed_forcing``, ``held_inner`` and ``ties`` as
    :meth:`gpjax._refine.Refiner.refine` takes them, ``names(sensitivity)`` the name of
    each of its constants. Constants refinement holds (the normalised one, snapped inner
    constants, tied ones, those past its ``max_free``) have none."""
    evaluator = refiner.evaluator
    sensitivity = refiner.sensitivity(population, fixed_forcing, held_inner, ties=ties)
    measured = evaluator.measurement.responses
    residual = sensitivity.response - (measured[:, 0] if sensitivity.response.ndim == 1
                                       else measured)
    weights = 1.0 / np.asarray(evaluator.time_record.noise_scale)
    covariance, dof = sandwich_covariance(residual, sensitivity.jacobian, weights)
    named = tuple(names(sensitivity))
    profile = {} if ties is not None else _profiles(
        refiner, population, fixed_forcing, held_inner, sensitivity, named, covariance, dof,
        weights)
    shift = None
    if evaluator.input_interpolation == "linear":
        other = refiner.sensitivity(population, fixed_forcing, held_inner, ties=ties,
                                    forcing_basis=evaluator.forcing_basis_as("bandlimited"))
        change = other.response - sensitivity.response
        if np.all(np.isfinite(change)) and np.all(np.isfinite(sensitivity.jacobian)):
            shift = _gauss_newton_shift(change, sensitivity.jacobian, weights)
    return Uncertainty(names=named, values=np.asarray(sensitivity.values, dtype=float),
                       covariance=covariance, dof=dof, n_samples=int(measured.shape[0]),
                       reconstruction_shift=shift, profile=profile)


def _profiles(refiner, population, fixed_forcing, held_inner, sensitivity, names,
              covariance, dof, weights) -> dict[str, tuple[float, float]]:
    """The profile intervals (:mod:`gpjax._profile`) of the inner constants among
    ``sensitivity``'s constants ``names``, at the sandwich's ``covariance`` and ``dof``."""
    from ._profile import profile_bounds

    scaled = _weighted_rows(sensitivity.jacobian, weights)
    with np.errstate(divide="ignore", invalid="ignore"):
        naive = np.sqrt(np.diag(np.linalg.pinv(scaled.T @ scaled)))
    se = np.sqrt(np.diag(covariance))
    inner = {}
    for i, column in enumerate(sensitivity.columns):
        part, _, slot = sensitivity.layout.part(int(column))
        if part == "inner" and np.isfinite(se[i]) and se[i] > 0 and naive[i] > 0:
            inner[names[i]] = {"slot": slot, "value": float(sensitivity.values[i]),
                               "se": float(se[i]), "naive_se": float(naive[i]),
                               "quantile": t_quantile(dof[i])}
    measured = refiner.evaluator.measurement.responses.reshape(sensitivity.response.shape)

    def objective(models):
        paths = np.asarray(refiner.evaluator.simulate(models)[0])  # (P, N) or (P, D, N)
        paths = paths.reshape(paths.shape[0], -1, paths.shape[-1])  # each as (N,) or (N, D):
        return np.array([np.sum(_weighted_rows(path.T.reshape(measured.shape) - measured,
                                               weights) ** 2) for path in paths])

    fitted = float(np.sum(_weighted_rows(sensitivity.response - measured, weights) ** 2))
    return profile_bounds(refiner, population, fixed_forcing, held_inner, inner=inner,
                          objective=objective, fitted=fitted)


def t_quantile(dof: float) -> float:
    """t₀.₉₇₅ with ``dof`` degrees of freedom (at least 1): half a 95 % interval in
    standard errors."""
    return float(special.stdtrit(max(float(dof), 1.0), 0.975))


def _weighted_rows(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """A response-shaped array (N,) or (N, D), or its Jacobian (N, k) or (N, D, k), as rows
    (N·D,) or (N·D, k) scaled by the per-coordinate ``weights`` (D,)."""
    w = np.asarray(weights, dtype=float).reshape(-1)
    n = values.shape[0]
    if values.size == n * w.size:
        return (values.reshape(n, w.size) * w).reshape(-1)
    k = values.shape[-1]
    return (values.reshape(n, w.size, k) * w[None, :, None]).reshape(-1, k)


def _gauss_newton_shift(change: np.ndarray, jacobian: np.ndarray,
                        weights: np.ndarray) -> np.ndarray:
    """(k,) the constants' move that offsets a change (N,) or (N, D) of the simulated
    response to first order: −(weighted least squares of ``change`` on ``jacobian``)."""
    return -np.linalg.lstsq(_weighted_rows(jacobian, weights), _weighted_rows(change, weights),
                            rcond=None)[0]


def model_names(sensitivity, model, columns, equations=None) -> list[str]:
    """The name in ``model`` (a :class:`gpjax.Model`, any number of coordinates, on the
    evaluator ``columns``) of each constant of ``sensitivity``; ``equations`` as
    :func:`constant_columns` takes them."""
    names = constant_columns(sensitivity.layout, model, columns, equations)
    return [names[int(column)] for column in sensitivity.columns]


def constant_columns(layout, model, columns, equations=None) -> dict[int, str]:
    """Flat column of ``layout`` -> the name in ``model`` (a :class:`gpjax.Model` on the
    evaluator ``columns``; ``equations``: the :class:`Coefficients` the population was
    packed from, default ``model.system`` — their features' order sets a family member's
    inner slots) of the constant it holds, for every column that holds one:
    ``m``, the state and forcing constants' names (:meth:`gpjax.Model.constant_names`;
    a normalising input by its feature), ``k2.θ1`` for a family's inner constant,
    ``x(0)`` and ``x'(0)``; with several coordinates prefixed, ``x2.m``, ``x2.u``,
    ``x2(0)``."""
    named = {(i, part, feature): name
             for name, (i, part, feature) in model.constant_names().items()}
    several = model.n_coordinates > 1
    at: dict[tuple[str, int, int], str] = {}
    for e, coefficients in enumerate(equations or model.system):
        prefix = f"{model.coordinates[e]}." if several else ""
        at[("mass", e, 0)] = named[(e, "mass", "")]
        features = list(coefficients.state)
        placed = ([(columns.equation_index(f, e), slice(0, 0), ()) for f in features]
                  if several else columns.state_columns(features))
        for f, (column, slots, _) in zip(features, placed):
            name = named.get((e, "state", str(f))) or named[(e, "parametric", str(f))]
            at[("state", e, column)] = name
            at |= {("inner", 0, slot): f"{name}.θ{slot - slots.start + 1}"
                   for slot in range(slots.start, slots.stop)}
        for f in coefficients.forcing:
            at[("forcing", e, columns.forcing_index(f))] = named.get(
                (e, "forcing", str(f)), f"{prefix}{f}")
        coordinate = model.coordinates[e]
        at |= {("y0", e, 0): f"{coordinate}(0)", ("y0", e, 1): f"{coordinate}'(0)"}
    names = {}
    for column in range(layout.width):
        name = at.get(layout.part(column))
        if name is not None:
            names[column] = name
    return names
