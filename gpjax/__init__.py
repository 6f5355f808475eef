"""gpjax: derive the Newton–Euler ODE of a dynamic system from its measured response.

Genetic programming (Ciglarič & Kidrič) over expression trees; candidates canonicalised
with sympy, whole populations integrated by one compiled fixed-step RK4 call, constants
refined with optimistix, the reported model checked against an adaptive diffrax solve.

Names are imported on first use, so the command line can reject bad input before JAX,
diffrax and sympy load. ``__all__`` is the user API; the engine underneath is documented in
:mod:`gpjax.engine`, the Silverbox benchmark tools in :mod:`gpjax.silverbox` and gear
physics in :mod:`gpjax.gear`. Importing gpjax changes no global state; JAX is switched to
float64 when gpjax first computes (:func:`gpjax._integrate.enable_float64`).
"""

from importlib import import_module

__version__ = "0.1.0"

_EXPORTS = {
    "GPConfig": "_config", "Identifier": "_estimator",
    "Measurement": "_data", "load_csv": "_data", "Migration": "_island_settings",
    "fit_many": "_fit_many", "refit": "_refit",
    "Band": "_band", "prediction_band": "_band",
    "Model": "_model", "Equation": "_model", "Symbols": "_canonical",
    "check_structure": "_canonical",
    "Diagnosis": "_diagnose", "diagnose": "_diagnose", "write_report": "_diagnose_report",
    "SystemDiagnosis": "_system_effects",
    "Effect": "_effects", "Parameter": "_effects", "Terms": "_effects",
    "effects": "_effects", "register_effect": "_effects",
    "ConfigError": "_errors", "DataError": "_errors", "ModelFileError": "_errors",
    "UserInputError": "_errors",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'gpjax' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + __all__)
