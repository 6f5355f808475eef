"""gpjax: derive the Newton–Euler ODE of a dynamic system from its measured response.

Genetic programming (Ciglarič & Kidrič) over expression trees; candidates canonicalised
with sympy, whole populations integrated by one compiled fixed-step RK4 call, constants
refined with optimistix, the reported model checked against an adaptive diffrax solve. Importing the numerical parts enables float64 in JAX.

Names are imported on first use, so the command line can reject bad input before JAX,
diffrax and sympy load.
"""

from importlib import import_module

__version__ = "0.1.0"

_EXPORTS = {
    "CanonicalForm": "_canonical", "StructureCheck": "_canonical", "Symbols": "_canonical",
    "check_structure": "_canonical", "check_tree": "_canonical", "tree_to_sympy": "_canonical",
    "GPConfig": "_config",
    "Measurement": "_data", "load_csv": "_data",
    "ConfigError": "_errors", "DataError": "_errors", "ModelFileError": "_errors",
    "UserInputError": "_errors",
    "Identifier": "_estimator",
    "Population": "_evaluator", "PopulationEvaluator": "_evaluator", "Scores": "_evaluator",
    "objective_parts": "_evaluator",
    "parse_expression": "_expressions",
    "Model": "_model", "simulate_model": "_model",
    "Diagnosis": "_diagnose", "diagnose": "_diagnose", "write_report": "_diagnose",
    "Effect": "_effects", "Parameter": "_effects", "Terms": "_effects",
    "effects": "_effects", "register_effect": "_effects",
    "load_silverbox": "_silverbox", "segment_rms": "_silverbox",
    "silverbox_segments": "_silverbox",
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
