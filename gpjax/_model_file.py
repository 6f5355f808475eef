"""The model file (``model.json``, format ``gpjax-model`` version 2), for any number of
coordinates; version 1 (one coordinate) and ``gpjax-system`` files are read too.

The file is plain JSON a person can write by hand. Only ``variables`` and ``canonical``
are needed to load it; everything else (equations, LaTeX, named constants, metrics) is
derived and written for reading. Feature strings are parsed by the whitelist parser of
:mod:`gpjax._expressions`, never evaluated. Version 2::

    {"format": "gpjax-model", "version": 2,
     "variables": {"time": "t", "responses": ["x1", "x2"], "inputs": ["u"]},
     "canonical": [{"mass": m1, "terms": [{"feature": "x1", "coefficient": k}, …],
                    "forcing": [{"feature": "u", "coefficient": 1.0}, …],
                    "parametric": […]}, …],            # one object per response
     "initial_conditions": [{"response": x0, "response_dot": v0}, …] or null,
     "third_law": false, "simulation": {…}, "uncertainty": {…}, "metrics": {…}, …}

Every equation is checked by the same rules whatever the number of coordinates: names
usable as identifiers and distinct; a non-zero finite mass; state terms of the
coordinate alone, of its velocity alone (eqs. 5–6) or of one relative coordinate
x_i − x_j or x_i' − x_j' alone; forcing terms of time and inputs alone; the §3 structure
rules (:func:`gpjax._canonical.check_structure`) on the coordinate's own terms; declared
time-varying terms g(t)·h(x_i) or g(t)·h(x_i'); with ``third_law``, each coupling term's
mirror in the other equation with the tied coefficient. With several coordinates the state
terms are powers or system-bank terms (tanh(θ·z), z·|z|, sin(z), cos(z) of one variable z;
:mod:`gpjax._system_bank`).
"""

from __future__ import annotations

import json
import keyword
import math
from pathlib import Path

import sympy as sp

from ._canonical import Symbols, check_structure
from ._convergence import MAX_SUBSTEPS
from ._data import INPUT_INTERPOLATIONS
from ._errors import ModelFileError, read_user_file
from ._system_bank import bank_of
from ._expressions import parse_expression
from ._model import Equation, Model
from ._reference import ReferenceSolver
from ._uncertainty import Uncertainty

FORMAT = "gpjax-model"
VERSION = 2
#: The format of the first multi-coordinate files, read as version 2.
SYSTEM_FORMAT = "gpjax-system"


def model_to_json(model: Model) -> dict:
    """The version-2 file's content (module docstring)."""
    def terms(items):
        return [{"feature": f, "coefficient": c} for f, c in items.items()]

    canonical = []
    for e in model.equations:
        canonical.append({"mass": e.mass, "terms": terms(e.state), "forcing": terms(e.forcing),
                          **({"parametric": terms(e.parametric)} if e.parametric else {})})
    states = model.initial_states
    return {
        "format": FORMAT, "version": VERSION,
        "equations": [str(model.equation(i)) for i in range(model.n_coordinates)],
        "equations_numeric": [str(model.equation(i, numeric=True))
                              for i in range(model.n_coordinates)],
        "latex": [model.latex(i) for i in range(model.n_coordinates)],
        "constants": model.constants(),
        "variables": {"time": model.time, "responses": list(model.coordinates),
                      "inputs": list(model.inputs)},
        "initial_conditions": None if states is None else [
            {"response": x, "response_dot": v} for x, v in states],
        "metrics": dict(model.metrics),
        "third_law": model.third_law,
        **({"couplings": [{"coordinates": [model.coordinates[i], model.coordinates[j]],
                           "force": str(force)} for (i, j), force in model.couplings().items()]}
           if model.third_law else {}),
        "canonical": canonical,
        "simulation": {"input_interpolation": model.input_interpolation,
                       "integrator": {"method": "rk4", "substeps": model.substeps},
                       "reference_solver": ReferenceSolver().to_json(),
                       **({"convergence": model.convergence} if model.convergence else {})},
        "provenance": model.provenance,
        **({"uncertainty": model.uncertainty.to_json()} if model.uncertainty else {}),
    }


def save_model(model: Model, path: str | Path) -> None:
    """Write ``model`` as a version-2 file, atomically."""
    from ._report import write_text_atomic
    write_text_atomic(Path(path), json.dumps(model_to_json(model), indent=2) + "\n")


def load_model(path: str | Path) -> Model:
    """Read a model file of any version; any problem is a :class:`ModelFileError`."""
    text = read_user_file(path, "model file", ModelFileError)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise ModelFileError(f"model file {path} is not valid JSON ({err}); fix the syntax") from None
    except (ValueError, RecursionError):  # a number of thousands of digits, deep nesting
        raise ModelFileError(f"model file {path} holds a number or nesting too large to read; "
                             "write numbers as ordinary floats") from None
    return model_from_json(data, source=str(path))


def model_from_json(data: dict, *, source: str = "model") -> Model:
    """A :class:`Model` from a file's content: version 2, version 1 (``variables.response``
    and one ``canonical`` object) or ``gpjax-system`` (``system``: one object per response).

    Raises:
        ModelFileError: a missing or malformed field, an expression outside the whitelist,
            or an equation that breaks the rules of the module docstring.
    """
    def fail(message: str):
        raise ModelFileError(f"{source}: {message}")

    if not isinstance(data, dict):
        fail("the top level must be a JSON object")
    kind, version = data.get("format", FORMAT), data.get("version", 1)
    if kind not in (FORMAT, SYSTEM_FORMAT) or not isinstance(version, int) or not (
            1 <= version <= (VERSION if kind == FORMAT else 1)):
        fail(f"format {kind!r} version {version!r} is not one this gpjax reads "
             f"({FORMAT!r} 1 … {VERSION}, {SYSTEM_FORMAT!r} 1); upgrade gpjax")
    time, coordinates, inputs = _variables(data.get("variables"), fail)
    names = {time, *inputs, *(n for c in coordinates for n in (c, f"{c}_dot", f"{c}_ddot"))}
    canonical = data.get("system" if "system" in data else "canonical")
    if isinstance(canonical, dict) and len(coordinates) == 1 and "responses" not in data.get(
            "variables", {}):
        canonical = [canonical]  # version 1
    if not isinstance(canonical, list) or len(canonical) != len(coordinates):
        fail('missing "canonical": one {"mass", "terms", "forcing"} object per response')
    equations = tuple(_equation(item, i, coordinates, time, inputs, names, fail, source)
                      for i, item in enumerate(canonical))
    simulation = data.get("simulation") or {}
    if not isinstance(simulation, dict):
        fail('"simulation" must be an object')
    third_law = data.get("third_law", False)
    if not isinstance(third_law, bool):
        fail('"third_law" must be true or false')
    metrics = data.get("metrics") or {}
    if not isinstance(metrics, dict):
        fail('"metrics" must be an object')
    provenance = data.get("provenance") or {}
    convergence = simulation.get("convergence")
    model = Model(coordinates=coordinates, time=time, inputs=inputs, equations=equations,
                  initial_states=_initial_states(data.get("initial_conditions"),
                                                 len(coordinates), fail),
                  metrics={k: v for k, v in metrics.items()
                           if isinstance(v, (int, float, dict)) and not isinstance(v, bool)},
                  provenance=provenance if isinstance(provenance, dict) else {},
                  input_interpolation=_interpolation(simulation, fail),
                  substeps=_substeps(simulation, fail),
                  convergence=convergence if isinstance(convergence, dict) else None,
                  uncertainty=_uncertainty(data.get("uncertainty"), fail),
                  third_law=third_law)
    if model.n_coordinates > 1:
        _check_system_basis(model, fail)
    _check_ties(model, fail)
    return model


def _variables(variables, fail) -> tuple[str, tuple[str, ...], tuple[str, ...]]:
    """(time, responses, inputs) of ``"variables"``, every name checked."""
    if not isinstance(variables, dict):
        fail('missing "variables" object {"time", "responses", "inputs"}')
    time, inputs = variables.get("time", "t"), variables.get("inputs", [])
    responses = variables.get("responses", [variables.get("response")])
    if not (isinstance(time, str) and isinstance(inputs, list) and isinstance(responses, list)
            and responses and all(isinstance(n, str) for n in [*responses, *inputs])):
        fail('"variables" needs "time" (a name), "responses" (a list of names, or one '
             '"response") and "inputs" (a list of names)')
    names = [time, *responses, *inputs]
    for name in names:
        if not name.isidentifier() or keyword.iskeyword(name) or name.startswith("_"):
            fail(f"variable name {name!r} is not usable; use letters, digits and _")
        if name.endswith("_dot") or name.endswith("_ddot"):
            fail(f"variable name {name!r} ends in _dot/_ddot, reserved for derivatives")
    if len(set(names)) != len(names):
        fail(f"variable names must differ, got {names}")
    return time, tuple(responses), tuple(inputs)


def _equation(item, i: int, coordinates, time: str, inputs, names, fail, source) -> Equation:
    """Equation ``i`` of the file, checked by the rules of the module docstring."""
    where = f"equation {i + 1} ({coordinates[i]})" if len(coordinates) > 1 else "canonical"
    if not isinstance(item, dict):
        fail(f"{where} must be an object {{\"mass\", \"terms\", \"forcing\"}}")
    mass = _number(item.get("mass", 1.0), f"{where}.mass", fail)
    state, forcing, parametric = (_terms(item.get(k, []), f"{where}.{k}", fail)
                                  for k in ("terms", "forcing", "parametric"))
    symbols = Symbols(coordinates[i], time, tuple(inputs))
    own = mass * symbols.x_ddot
    exogenous = {symbols.t, *symbols.u}
    for text, value in state.items():
        feature = _parse(text, names, source)
        kind = _state_kind(feature, i, coordinates)
        if kind is None:
            others = " or of x_i - x_j, x_i_dot - x_j_dot alone" if len(coordinates) > 1 else ""
            fail(f"term feature {text!r} of {where} must depend on {symbols.x} alone or on "
                 f"{symbols.x_dot} alone{others} (eqs. 5–6); move time/input terms to "
                 "\"forcing\"")
        if kind == "own":
            own += value * feature
    for text, value in forcing.items():
        feature = _parse(text, names, source)
        if not feature.free_symbols <= exogenous:
            fail(f"forcing feature {text!r} of {where} may depend only on time and inputs; "
                 "move it to \"terms\"")
        own -= value * feature
    for text in parametric:
        _check_parametric(_parse(text, names, source), text, symbols, fail)
    check = check_structure(own, symbols)
    if not check.valid:
        fail(f"{where} breaks the structure rules: {check.reason}")
    return Equation(mass, state, forcing, parametric)


def _state_kind(feature: sp.Expr, i: int, coordinates) -> str | None:
    """``"own"`` for a function of x_i alone or x_i' alone, ``"relative"`` for one of
    x_i − x_j or x_i' − x_j' alone (j ≠ i), else ``None``."""
    used = feature.free_symbols
    for suffix in ("", "_dot"):
        mine = sp.Symbol(f"{coordinates[i]}{suffix}")
        if used == {mine}:
            return "own"
        for j, other in enumerate(coordinates):
            theirs = sp.Symbol(f"{other}{suffix}")
            if j != i and used == {mine, theirs}:
                shift = sp.Dummy("s")
                moved = sp.simplify(feature.subs(mine, shift + theirs))
                if moved.free_symbols == {shift}:
                    return "relative"
    return None


def _check_system_basis(model: Model, fail) -> None:
    """With several coordinates, every state feature is a power or a bank term
    (:mod:`gpjax._system_bank`) of x_i, x_i', x_i − x_j or x_i' − x_j' (the system
    evaluator's basis, :func:`gpjax._evaluator.system_state_features`)."""
    try:
        bank_of(model.coordinates, [list(c.state) for c in model.system])
    except ValueError as error:
        fail(str(error))


def _check_parametric(feature: sp.Expr, text: str, symbols: Symbols, fail) -> None:
    """A declared time-varying term must be g(t)·h(x) or g(t)·h(x') (no inputs, no x'')."""
    response, time = feature.as_independent(symbols.t, as_Add=False)
    if not (isinstance(feature, sp.Mul) and time.free_symbols == {symbols.t}
            and response.free_symbols in ({symbols.x}, {symbols.x_dot})):
        fail(f"parametric feature {text!r} is not g({symbols.t})·h({symbols.x}) or "
             f"g({symbols.t})·h({symbols.x_dot}); write it as a function of {symbols.t} alone "
             f"times a function of {symbols.x} alone or {symbols.x_dot} alone, e.g. "
             f"cos(100*{symbols.t})*{symbols.x}")


def _check_ties(model: Model, fail) -> None:
    for tie in model.ties():
        (i, feature), (j, mirror) = tie.source, tie.mirror
        value, other = model.system[i].state[feature], model.system[j].state.get(mirror)
        if other is None or not math.isclose(other, tie.sign * value, rel_tol=1e-9):
            fail(f"with third_law, equation {j + 1} needs the term {mirror} with coefficient "
                 f"{tie.sign * value!r} (equation {i + 1}'s {feature} mirrored)")


def _initial_states(ic, count: int, fail):
    if ic is None:
        return None
    ic = [ic] if isinstance(ic, dict) and count == 1 else ic
    if not isinstance(ic, list) or len(ic) != count or not all(isinstance(s, dict) for s in ic):
        fail('"initial_conditions" must be a list of {"response": x0, "response_dot": v0}, '
             'one per response, or null')
    return tuple((_number(s.get("response"), "initial_conditions.response", fail),
                  _number(s.get("response_dot"), "initial_conditions.response_dot", fail))
                 for s in ic)


def _interpolation(simulation: dict, fail) -> str:
    interpolation = simulation.get("input_interpolation", "linear")
    if interpolation not in INPUT_INTERPOLATIONS:
        fail(f'"simulation" must be {{"input_interpolation": one of '
             f'{list(INPUT_INTERPOLATIONS)}}}, got {simulation!r}')
    return interpolation


def _substeps(simulation: dict, fail) -> int:
    integrator = simulation.get("integrator") or {"method": "rk4", "substeps": 1}
    substeps = integrator.get("substeps") if isinstance(integrator, dict) else None
    if (not isinstance(integrator, dict) or integrator.get("method", "rk4") != "rk4"
            or isinstance(substeps, bool) or not isinstance(substeps, int)
            or not 1 <= substeps <= MAX_SUBSTEPS):
        fail(f'"simulation.integrator" must be {{"method": "rk4", "substeps": 1 … '
             f'{MAX_SUBSTEPS}}}, got {integrator!r}')
    return substeps


def _uncertainty(data, fail) -> Uncertainty | None:
    if data is None:
        return None
    try:
        return Uncertainty.from_json(data)
    except (KeyError, TypeError, ValueError, AttributeError):
        fail('"uncertainty" is malformed; delete it (it is derived) or rewrite it as '
             'gpjax writes it')


def _parse(text: str, names: set[str], source: str) -> sp.Expr:
    try:
        return parse_expression(text, names)
    except ModelFileError as err:
        raise ModelFileError(f"{source}: {err}") from None


def _number(value, where: str, fail) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        fail(f"{where} must be a finite number, got {value!r}")
    return float(value)


def _terms(items, where: str, fail) -> dict[str, float]:
    if not isinstance(items, list):
        fail(f"{where} must be a list of {{\"feature\", \"coefficient\"}} objects")
    out: dict[str, float] = {}
    for item in items:
        if not isinstance(item, dict) or not isinstance(item.get("feature"), str):
            fail(f"{where} entries need a \"feature\" string and a \"coefficient\" number")
        if item["feature"] in out:
            fail(f"{where} lists feature {item['feature']!r} twice")
        out[item["feature"]] = _number(item.get("coefficient"), f"{where}[{item['feature']}]", fail)
    return out
