"""The engine under :class:`gpjax.Identifier`, for users who build on it.

* structure rules and canonical forms (sympy): :class:`Symbols`, :func:`check_structure`,
  :func:`check_tree`, :func:`tree_to_sympy`, :class:`CanonicalForm`,
  :class:`StructureCheck`, :func:`parse_expression` (the whitelist parser of model files);
* one model's constants: :class:`Coefficients`, and as arrays :class:`Population`,
  :func:`to_population`, :func:`from_population`, :class:`FlatLayout`;
* the batched simulator and objective: :class:`PopulationEvaluator`, :class:`Scores`,
  :class:`Status`, :func:`objective_parts`, and :func:`simulate_model` (a model by the
  evaluator's fixed-step RK4);
* systems of several coordinates (issue 14): :func:`to_system_population`,
  :func:`from_system_population`, :func:`system_state_features`,
  :func:`fit_system` (constants of a given system structure, converged),
  :func:`weak_form_start` (the GP over systems is :class:`gpjax.Identifier`'s); a system is a
  :class:`gpjax.Model` of several coordinates, read by :func:`load_model` (any version of
  the model file).
"""

from ._canonical import (CanonicalForm, StructureCheck, Symbols, check_structure, check_tree,
                         tree_to_sympy)
from ._coefficients import (Coefficients, FlatLayout, Population, from_population,
                            from_system_population, to_population, to_system_population)
from ._evaluator import PopulationEvaluator, Scores, Status, system_state_features
from ._expressions import parse_expression
from ._model import simulate_model
from ._objective import objective_parts
from ._model_file import load_model
from ._system_fit import SystemFit, fit_system, weak_form_start

__all__ = ["CanonicalForm", "Coefficients", "FlatLayout", "Population", "PopulationEvaluator",
           "Scores", "Status", "StructureCheck", "Symbols", "check_structure", "check_tree",
           "SystemFit", "fit_system", "from_population",
           "load_model",
           "from_system_population", "objective_parts", "parse_expression", "simulate_model",
           "system_state_features", "to_population", "to_system_population",
           "tree_to_sympy", "weak_form_start"]
