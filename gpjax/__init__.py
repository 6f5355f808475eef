"""gpjax: derive the Newton–Euler ODE of a dynamic system from its measured response.

Genetic programming (Ciglarič & Kidrič) over expression trees; candidates canonicalised
with sympy, whole populations integrated in one compiled diffrax solve, constants refined
with optimistix. Enables float64 in JAX on import.
"""

from ._canonical import CanonicalForm, StructureCheck, Symbols, check_structure, tree_to_sympy
from ._config import GPConfig
from ._data import Measurement, load_csv
from ._errors import ConfigError, DataError, ModelFileError, UserInputError
from ._estimator import Identifier
from ._evaluator import Population, PopulationEvaluator, Scores, objective_parts
from ._expressions import parse_expression
from ._model import Model, simulate_model

__version__ = "0.1.0"

__all__ = [
    "CanonicalForm", "ConfigError", "DataError", "GPConfig", "Identifier", "Measurement",
    "Model", "ModelFileError", "Population", "PopulationEvaluator", "Scores", "StructureCheck",
    "Symbols", "UserInputError", "check_structure", "load_csv", "objective_parts",
    "parse_expression", "simulate_model", "tree_to_sympy",
]
