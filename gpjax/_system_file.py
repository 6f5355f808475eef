"""The model file of a system (several coordinates) and loading either kind of model file.

A system file is plain JSON like a one-coordinate ``model.json``, with ``variables.responses``
(the coordinates, in order) and ``system``: one ``{"mass", "terms", "forcing"}`` object per
coordinate, meaning ``mass·x_i'' + Σ coefficient·feature = Σ coefficient·feature(t, inputs)``.
Equation i's features are powers of x_i, x_i', x_i − x_j and x_i' − x_j' (j ≠ i); they are
read by the whitelist parser (nothing is evaluated as code). ``third_law`` (default false)
marks Newton's third law (:mod:`gpjax._system_couplings`): every coupling term is written in
both of its equations, and ``couplings`` lists each coupled pair's force once (for
reading; the file is checked to hold each mirror term with the tied coefficient). A file
without ``system`` is a one-coordinate model (:class:`gpjax.Model`), read as before.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from ._coefficients import Coefficients
from ._errors import ModelFileError, read_user_file
from ._evaluator import system_state_features
from ._expressions import parse_expression
from ._reference import ReferenceSolver
from ._system_fit import SystemModel

FORMAT = "gpjax-system"


def system_to_json(model: SystemModel, metrics: dict | None = None,
                   convergence: dict | None = None, uncertainty: dict | None = None) -> dict:
    """The system file's content (module docstring); ``uncertainty``: the constants'
    intervals (:meth:`gpjax._uncertainty.Uncertainty.to_json`), written for reading."""
    return {
        "format": FORMAT, "version": 1,
        "equations": [str(e) for e in model.sympy()],
        "latex": model.latex(),
        "variables": {"time": model.time_name, "responses": list(model.coordinates),
                      "inputs": list(model.input_names)},
        "initial_conditions": [{"response": e.y0[0], "response_dot": e.y0[1]}
                               for e in model.equations],
        "metrics": dict(metrics or {}),
        "third_law": model.third_law,
        "couplings": [{"coordinates": [model.coordinates[i], model.coordinates[j]],
                       "force": str(force)} for (i, j), force in model.couplings().items()],
        "system": [{"mass": e.mass,
                    "terms": [{"feature": str(f), "coefficient": v} for f, v in e.state.items()],
                    "forcing": [{"feature": str(f), "coefficient": v}
                                for f, v in e.forcing.items()]} for e in model.equations],
        "simulation": {"input_interpolation": model.input_interpolation,
                       "integrator": {"method": "rk4", "substeps": model.substeps},
                       "max_degree": model.max_degree,
                       "reference_solver": ReferenceSolver().to_json(),
                       **({"convergence": convergence} if convergence else {})},
        **({"uncertainty": uncertainty} if uncertainty else {}),
    }


def system_from_json(data: dict, *, source: str = "model") -> SystemModel:
    """A :class:`SystemModel` from a system file's content.

    Raises:
        ModelFileError: a missing or malformed field, an expression outside the whitelist,
            or a feature outside its equation's basis.
    """
    def fail(message: str):
        raise ModelFileError(f"{source}: {message}")

    variables = data.get("variables")
    if not isinstance(variables, dict):
        fail('missing "variables" object {"time", "responses", "inputs"}')
    time, responses = variables.get("time", "t"), variables.get("responses")
    inputs = variables.get("inputs", [])
    if not (isinstance(time, str) and isinstance(responses, list) and isinstance(inputs, list)
            and all(isinstance(n, str) and n.isidentifier() for n in [time, *responses, *inputs])):
        fail('"variables" needs "time" (a name), "responses" and "inputs" (lists of names)')
    equations = data.get("system")
    if not isinstance(equations, list) or len(equations) != len(responses) or not responses:
        fail('"system" must be a list of one equation per response')
    simulation = data.get("simulation") or {}
    degree = int((simulation.get("max_degree") or 0))
    names = {time, *inputs, *responses, *(f"{r}_dot" for r in responses)}
    parsed = []
    ic = data.get("initial_conditions") or [None] * len(responses)
    for i, equation in enumerate(equations):
        if not isinstance(equation, dict):
            fail(f"equation {i + 1} must be an object with mass, terms and forcing")
        state, forcing = (_terms(equation.get(k, []), names, f"system[{i}].{k}", fail)
                          for k in ("terms", "forcing"))
        mass = equation.get("mass")
        if not isinstance(mass, (int, float)) or not math.isfinite(mass) or mass <= 0:
            fail(f"system[{i}].mass must be a positive number")
        for feature in state:
            base, power = feature.as_base_exp()
            degree = max(degree, int(power) if power.is_Integer else 0)
        y0 = ic[i] if isinstance(ic, list) and i < len(ic) and isinstance(ic[i], dict) else {}
        parsed.append(Coefficients(float(mass), state, forcing,
                                   (float(y0.get("response", math.nan)),
                                    float(y0.get("response_dot", math.nan)))))
    basis = system_state_features(tuple(responses), max(degree, 1))
    for i, equation in enumerate(parsed):
        for feature in equation.state:
            if feature not in basis[i]:
                fail(f"feature {feature} of equation {i + 1} is not a power of "
                     f"{responses[i]}, {responses[i]}_dot or of their differences to the "
                     "other coordinates (x_i - x_j, x_i_dot - x_j_dot)")
    third_law = data.get("third_law", False)
    if not isinstance(third_law, bool):
        fail('"third_law" must be true or false')
    integrator = simulation.get("integrator") or {}
    model = SystemModel(tuple(responses), time, tuple(inputs), tuple(parsed),
                        simulation.get("input_interpolation", "linear"),
                        int(integrator.get("substeps", 1)), max(degree, 1), third_law)
    for tie in model.ties():
        (i, feature), (j, mirror) = tie.source, tie.mirror
        value, other = parsed[i].state[feature], parsed[j].state.get(mirror)
        if other is None or not math.isclose(other, tie.sign * value, rel_tol=1e-9):
            fail(f"with third_law, equation {j + 1} needs the term {mirror} with coefficient "
                 f"{tie.sign * value!r} (equation {i + 1}'s {feature} mirrored)")
    return model


def _terms(items, names, where, fail) -> dict:
    if not isinstance(items, list):
        fail(f"{where} must be a list of {{feature, coefficient}}")
    out = {}
    for item in items:
        if not isinstance(item, dict) or not isinstance(item.get("coefficient"), (int, float)):
            fail(f"{where}: every entry needs a feature and a numeric coefficient")
        out[parse_expression(item.get("feature"), names)] = float(item["coefficient"])
    return out


def save_system(model: SystemModel, path: str | Path, **extra) -> None:
    from ._report import write_text_atomic
    write_text_atomic(Path(path), json.dumps(system_to_json(model, **extra), indent=2) + "\n")


def load_model(path: str | Path):
    """A model file of either kind: a :class:`SystemModel` for a system file, else a
    :class:`gpjax.Model`.

    Raises:
        ModelFileError: unreadable or malformed file.
    """
    from ._model import Model

    text = read_user_file(path, "model file", ModelFileError)
    try:
        data = json.loads(text)
    except json.JSONDecodeError:
        return Model.load(path)  # its own message for malformed JSON
    if isinstance(data, dict) and "system" in data:
        return system_from_json(data, source=str(path))
    return Model.load(path)
