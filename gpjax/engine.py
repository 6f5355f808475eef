"""The engine under :class:`gpjax.Identifier`, for users who build on it.

* structure rules and canonical forms (sympy): :class:`Symbols`, :func:`check_structure`,
  :func:`check_tree`, :func:`tree_to_sympy`, :class:`CanonicalForm`,
  :class:`StructureCheck`, :func:`parse_expression` (the whitelist parser of model files);
* one model's constants: :class:`Coefficients`, and as arrays :class:`Population`,
  :func:`to_population`, :func:`from_population`, :class:`FlatLayout`;
* the batched simulator and objective: :class:`PopulationEvaluator`, :class:`Scores`,
  :class:`Status`, :func:`objective_parts`, and :func:`simulate_model` (a model by the
  evaluator's fixed-step RK4).
"""

from ._canonical import (CanonicalForm, StructureCheck, Symbols, check_structure, check_tree,
                         tree_to_sympy)
from ._coefficients import (Coefficients, FlatLayout, Population, from_population,
                            to_population)
from ._evaluator import PopulationEvaluator, Scores, Status
from ._expressions import parse_expression
from ._model import simulate_model
from ._objective import objective_parts

__all__ = ["CanonicalForm", "Coefficients", "FlatLayout", "Population", "PopulationEvaluator",
           "Scores", "Status", "StructureCheck", "Symbols", "check_structure", "check_tree",
           "from_population", "objective_parts", "parse_expression", "simulate_model",
           "to_population", "tree_to_sympy"]
