"""The estimator users hold: ``Identifier(config).fit(measurement)``.

Writes (when given a run folder): ``model.json``, ``history.csv``, ``equations.csv`` and
``equations.json`` (the Pareto table, as text and as model files), ``fit.png``,
``config.json`` and ``checkpoint.json`` (rewritten atomically after every generation, so
``fit(..., resume=True)`` continues a killed run exactly).
"""

from __future__ import annotations

import dataclasses
import json
import math
import signal
import threading
import time
import warnings
from pathlib import Path

import numpy as np

from . import _progress
from ._aot import compile_ledger, compiled_since
from ._config import GPConfig
from ._convergence import Convergence, check_line, fit_converged
from ._data import Measurement
from ._errors import UserInputError
from ._evolve import Evolution, RunState, evolution_for
from ._evaluator import OK
from ._fitness import Fitness, Record
from ._model import Model
from ._objective import stop_objective
from ._report import fit_figure, history_csv, write_bytes_atomic, write_text_atomic
from ._select import pareto_front, select
from ._uncertainty import fitted_uncertainty
from ._sign_width import (NARROWING, check_width, fitted_signs, narrowed, next_narrowing,
                          sharpened, why_stopped, width_line)

CHECKPOINT = "checkpoint.json"
#: Columns of history.csv and equations.csv that hold text, not numbers.
TEXT_COLUMNS = ("equation", "best_key", "constants")


class Identifier:
    """Derives a Newton–Euler ODE from a measured response by genetic programming.

    Args:
        config: run settings (:class:`GPConfig`); keyword overrides are applied on top.

    After :meth:`fit`: ``model_`` (the reported :class:`Model`), ``equations_`` (the Pareto
    table of complexity — fitted constants — vs objective, one dict per row; :meth:`sympy`
    and :meth:`latex` take a row index), ``history_`` (per generation),
    ``stopped_by`` (``"epsilon"``, ``"generations"`` or ``"interrupted"``), timings in
    ``timings_`` (seconds: ``total_s``, ``compile_s``, ``selection_s`` the final model
    selection, ``convergence_s``, ``intervals_s`` the standard errors and residual
    statistics (a system's ``convergence_s`` holds them), ``writing_s``; ``compiles``,
    ``generations``), and ``convergence_``: each check of the reported model's RK4
    integration (:class:`~gpjax._convergence.Convergence`; its ``estimate`` says whether
    against the reference solve or, on a failed rung of the step ladder, RK4's
    step-doubling estimate), the last one the reference's and passed unless a fixed
    ``substeps`` was too coarse (then a warning says so); the model's smoothed-sign width
    check (:mod:`gpjax._sign_width`) is ``model_.convergence["sign_width"]``.
    """

    def __init__(self, config: GPConfig | None = None, **overrides):
        config = config or GPConfig()
        self.config = config.replace(**overrides) if overrides else config
        self.model_: Model | None = None
        self.equations_: list[dict] = []
        self.history_: list[dict] = []
        self.stopped_by = ""
        self.timings_: dict[str, float] = {}
        self.measurement_: Measurement | None = None
        self.convergence_: list[Convergence] = []
        self._equation_models: list[Model] = []
        self._front: list[Record] = []
        self._chosen: Record | None = None
        self._reference: np.ndarray | None = None
        self._provenance: dict = {}  # added to the model file's provenance (island runs)

    # --- fitting ----------------------------------------------------------------------
    def fit(self, measurement: Measurement, *, seed: int = 0, out: str | Path | None = None,
            resume: bool = False, progress: bool | None = None, islands: int | None = None,
            scheduler: str | None = None, migration=None) -> "Identifier":
        """Run GP on ``measurement``.

        Args:
            measurement: the data.
            seed: seed of the run's random generator (same seed and data: same model).
            out: run folder for outputs and checkpoints (created if needed).
            resume: continue from ``out/checkpoint.json`` instead of starting afresh.
            progress: show a progress bar (default: only where stderr is a terminal);
                each generation and stage is also logged on the ``gpjax`` logger
                (:mod:`gpjax._progress`; the command line prints it where there is no bar).
            islands: run K sub-populations (``population`` shared among them) on Dask with
                migration (:mod:`gpjax._islands`); ``None``: one population in this process.
            scheduler: address of a running Dask scheduler (``tcp://HOST:PORT``) for the
                islands; ``None`` starts a ``distributed.LocalCluster``.
            migration: a :class:`gpjax.Migration` (default: ring, every 2
                generations, 2 migrants).

        Several responses are a system, one equation per coordinate
        (:class:`gpjax._system_search.SystemEvolution`, run by the same loop, checkpoints
        and islands; reported by :mod:`gpjax._estimator_systems`).

        Raises:
            UserInputError: resuming without a checkpoint, or with other data or settings;
                bad island settings or an unreachable scheduler.
        """
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise UserInputError(f"seed must be a non-negative integer, got {seed!r}")
        if islands is not None or scheduler is not None or migration is not None:
            from ._islands import fit_islands

            return fit_islands(self, measurement, seed=seed, out=out, resume=resume,
                               islands=islands, scheduler=scheduler, migration=migration,
                               progress=progress)
        began, compiled = time.perf_counter(), compile_ledger()
        out = Path(out) if out is not None else None
        evolution = evolution_for(measurement, self.config)
        fingerprint = measurement.fingerprint()
        if resume:
            state, seed = self._load_checkpoint(out, evolution, fingerprint)
            _progress.stage(f"resuming {out / CHECKPOINT} after generation {state.generation}")
        else:
            state = evolution.start(seed)
        self.measurement_ = measurement

        def finished(state: RunState) -> None:
            """Checkpoint (with a run folder) and log a finished generation."""
            if out is not None:
                payload = {"config": self.config.to_dict(), "seed": seed, "data": fingerprint,
                           "state": evolution.state_json(state)}
                write_text_atomic(out / CHECKPOINT, json.dumps(payload))
            last = state.history[-1]
            _progress.generation(last.generation, self.config.generations,
                                 last.best_objective, last.seconds)

        bar = _progress.bar(self.config.generations, initial=state.generation,
                            progress=progress)
        finished(state)
        with _StopOnInterrupt() as stop:
            try:
                while not state.done and not stop.requested:
                    state = evolution.step(state)
                    finished(state)
                    bar.update(1)
                    bar.set_postfix(best=f"{state.history[-1].best_objective:.4g}")
            finally:
                bar.close()
        return self._conclude(evolution, seed, state, began=began, compiled=compiled,
                              out=out, interrupted=stop.requested)

    def _conclude(self, evolution, seed: int, state: RunState, *, began: float,
                  compiled: tuple[float, int], out: Path | None,
                  interrupted: bool) -> "Identifier":
        """The reported model of a finished search by ``evolution`` (one coordinate:
        :meth:`_finish`; several: :func:`gpjax._estimator_systems.finish_system`); the run
        began at ``began`` (``time.perf_counter``) with ``compiled``
        (:func:`gpjax._aot.compile_ledger`) behind it."""
        if isinstance(evolution, Evolution):
            return self._finish(evolution.fitness, seed, state, began=began,
                                compiled=compiled, out=out, interrupted=interrupted)
        from ._estimator_systems import finish_system

        finish_system(self, evolution, seed, state, began=began, compiled=compiled, out=out,
                      interrupted=interrupted)
        return self

    def _finish(self, fitness: Fitness, seed: int, state: RunState, *, began: float,
                compiled: tuple[float, int], out: Path | None,
                interrupted: bool) -> "Identifier":
        """Select, convergence-check and write the reported model of a finished search
        (``fitness`` holds every scored record; shared by one-process and island runs)."""
        last = state.history[-1]
        self.stopped_by = ("interrupted" if interrupted else
                           "epsilon" if last.best_objective <= stop_objective(
                               fitness.measurement, self.config)
                           else "generations")
        selecting = time.perf_counter()
        self._select(fitness, seed, state)
        converging = time.perf_counter()
        fitness = self._converge(fitness, seed, state)
        intervals = time.perf_counter()
        self._set_uncertainty(fitness)
        self._set_residuals()
        writing = time.perf_counter()
        if out is not None:
            self._write(out, fitness)
        ended = time.perf_counter()
        # The parts add up to total_s: each is the time between two of the marks above.
        self.timings_ = {"total_s": ended - began,
                         "search_s": selecting - began,
                         "selection_s": converging - selecting,
                         "convergence_s": intervals - converging,
                         "intervals_s": writing - intervals,  # standard errors, residuals
                         "writing_s": ended - writing, **compiled_since(compiled),
                         "generations": state.generation, "finished_at": time.time()}
        return self

    def _load_checkpoint(self, out: Path | None, evolution, fingerprint: str):
        if out is None or not (out / CHECKPOINT).is_file():
            raise UserInputError(f"no checkpoint to resume in {out}; run without --resume first")
        try:
            payload = json.loads((out / CHECKPOINT).read_text(encoding="utf-8"))
            if "islands" in payload:
                raise UserInputError(f"{out / CHECKPOINT} was written by an island run; resume "
                                     f"with --islands {len(payload['islands'])}")
            if payload["data"] != fingerprint:
                raise UserInputError(f"{out / CHECKPOINT} was written for other data; resume "
                                     "with the same CSV and columns")
            if payload["config"] != self.config.to_dict():
                raise UserInputError(f"{out / CHECKPOINT} was written with other settings; resume "
                                     "with the same configuration")
            return evolution.load_state(payload["state"]), int(payload["seed"])
        except (KeyError, TypeError, ValueError, json.JSONDecodeError) as err:
            if isinstance(err, UserInputError):
                raise
            raise UserInputError(f"{out / CHECKPOINT} is damaged ({err}); start the run afresh "
                                 "without --resume") from None

    def _converge(self, fitness: Fitness, seed: int, state: RunState) -> Fitness:
        """Check the reported model's integration against the reference solve, and its
        smoothed signs' width (:mod:`gpjax._sign_width`); with ``substeps="auto"``, refit
        the Pareto front and the reported model at more RK4 steps
        (:func:`gpjax._convergence.fit_converged`, the loop systems and the diagnosis use),
        or the reported model at a narrower sign, until both pass, the steps reach
        :data:`MAX_SUBSTEPS`, the sign its narrowest
        (:data:`~gpjax._sign_width.MAX_NARROWINGS`) or the width check's own rate of
        convergence (:attr:`~gpjax._sign_width.WidthCheck.narrowings_needed`) says that
        narrowing does not converge, or a narrower sign would need more than MAX_SUBSTEPS
        steps for a stable RK4 step (:func:`gpjax._convergence.stable_substeps`). Once the
        sign is narrowed, only the reported model is refitted (a sign's width changes the
        constants of the models that have one, not the ranking; refitting the front at every
        width cost a Coulomb fit of 8,000 samples 13 minutes); the front's other rows keep
        their fit. Returns the fitness in use."""
        tolerance = self.config.convergence_tolerance
        auto = self.config.substeps == "auto"
        run = {"fitness": fitness, "refits": 0, "front_too": True}

        def refit(steps: int, sign_width: float) -> bool:
            """Refit the front (or, once the sign is narrowed, the reported model alone) at
            ``steps`` RK4 steps and ``sign_width``; False where the reported model's refit
            failed. The structures were ranked at the coarser step or wider sign (the
            ranking, unlike the constants, barely moves)."""
            old, front_too = run["fitness"], run["front_too"]
            run["refits"] += 1
            _progress.stage(f"refitting {'the Pareto front' if front_too else 'the reported model'}"
                            f" at {steps} substeps, smoothed-sign width {sign_width:.3g}")
            new = Fitness(self.measurement_, self.config, substeps=steps, sign_width=sign_width,
                          single=not front_too)
            carried = {r.key: narrowed(r, old, new)
                       for r in (self._front if front_too else []) + [self._chosen]}
            adopted = {r.key: r for r in new.adopt(list(carried.values()))}
            chosen = adopted.get(carried[self._chosen.key].key)
            if chosen is None or not (chosen.valid and chosen.status == OK):
                return False
            if new.sign_width != old.sign_width:
                new.refine([chosen], to_convergence=True)  # constants the width check compares
            run["fitness"] = new
            if front_too:
                self._report(new, pareto_front([r for r in adopted.values() if r.status == OK]),
                             chosen, seed, state)
            else:
                self._replace_chosen(new, chosen, seed, state)
            return True

        def fit_at(steps: int, previous: Model | None) -> Model | None:
            # the first fit of each ladder is the model in hand (the search's, or the last
            # narrowing's); later ones are refits at more steps, same sign width
            if previous is not None and not refit(steps, run["fitness"].sign_width):
                run["failed"] = True
                return None
            _progress.stage(f"convergence check at {steps} substeps")
            return self.model_

        narrowings, stopped = 0, "converged"
        while True:
            width = None
            _, checks, self._reference = fit_converged(
                fit_at, self.measurement_, substeps=None if auto else self.model_.substeps,
                tolerance=tolerance, first=self.model_.substeps)
            self.convergence_.extend(checks)
            check = checks[-1]
            if run.pop("failed", False):
                stopped = "refit failed"
                break
            if not check.converged:
                stopped = "substeps cap" if auto else "fixed substeps"
                break
            width = check_width(self.model_, self._reference, check.rms_reference,
                                run["fitness"], tolerance=tolerance)
            if width is None or width.converged:
                break
            step = (next_narrowing(width, narrowings,
                                   lambda factor: sharpened(self.model_, factor,
                                                            fitted_signs(run["fitness"])),
                                   run["fitness"].measurement, tolerance=tolerance)
                    if auto else "fixed substeps")
            if isinstance(step, str):
                stopped = step
                break
            jump, steps = step
            narrowings, run["front_too"] = narrowings + jump, False
            if not refit(steps, run["fitness"].sign_width / NARROWING ** jump):
                stopped = "refit failed"
                break
        fitness, refits = run["fitness"], run["refits"]
        widths = {"sign_width": width.to_json()} if width is not None else {}
        self.model_ = dataclasses.replace(
            self.model_, convergence=check.to_json() | widths | {"refits": refits,
                                                                 "stopped": stopped},
            metrics=self.model_.metrics | {"rms_reference": check.rms_reference})
        why = why_stopped(stopped)
        if why and width is not None and not width.converged:
            why += f" ({_projection(width)})"
        if not check.converged:
            unstable = (f"; RK4 is stable on it from {check.stable_substeps} steps per sample"
                        if check.substeps < check.stable_substeps else "")
            warnings.warn(f"the reported model's RK4 response differs from the reference "
                          f"solve by {check.ratio:.1%} of its RMS residual at "
                          f"{check.substeps} steps per sample (tolerance "
                          f"{tolerance:.1%}){unstable}: {why}", stacklevel=3)
        elif width is not None and not width.converged:
            warnings.warn(f"the reported model's response changes by {width.ratio:.1%} of its "
                          f"RMS residual when its smoothed sign (width {width.fraction:.2g} × "
                          f"RMS of its variable) is narrowed {NARROWING}×, at {check.substeps} "
                          f"steps per sample (tolerance {tolerance:.1%}): {why}; its friction "
                          f"constants depend on the smoothing", stacklevel=3)
        return fitness

    def _set_uncertainty(self, fitness: Fitness) -> None:
        """Give the reported model (and its row of the equations table) the standard
        errors of its constants at the converged steps (:mod:`gpjax._uncertainty`)."""
        _progress.stage("standard errors of the reported constants")
        row = [r.key for r in self._front].index(self._chosen.key)
        self.model_ = dataclasses.replace(self.model_, uncertainty=fitted_uncertainty(
            fitness, self._chosen, self.model_))
        self._equation_models[row] = self.model_
        self.equations_[row] = _row(self._chosen, self.model_, self._chosen)

    def _set_residuals(self) -> None:
        """Give the reported model the statistics of its residual against the noise floor
        (:func:`gpjax._system_diagnose.residual_statistics`, as several coordinates get
        them), from the reference solve where the convergence check covered the whole
        record, else from the converged RK4 response."""
        from ._system_diagnose import residual_statistics

        if self._reference.size != self.measurement_.n_samples:
            self._reference = self.simulate(solver="rk4")  # converged: checked on a window
        residuals = residual_statistics(self.model_, self.measurement_,
                                        simulated=self._reference)
        row = [r.key for r in self._front].index(self._chosen.key)
        self.model_ = dataclasses.replace(
            self.model_, metrics=self.model_.metrics | {"residuals": residuals})
        self._equation_models[row] = self.model_

    def _select(self, fitness: Fitness, seed: int, state: RunState) -> None:
        valid = [r for r in fitness.records.values() if r.valid and r.status == OK]
        if not valid:
            raise UserInputError(
                "no candidate model could be simulated (all invalid or diverged); check that "
                "the response and input columns are right, or widen the function/terminal sets")
        front = pareto_front(valid)
        _progress.stage(f"final model selection: refining the {len(front)} models of the "
                        "Pareto front")
        fitness.refine(front)
        chosen, _ = select(fitness, pareto_front(front), self.config.selection_alpha)
        self._report(fitness, pareto_front([r for r in fitness.records.values()
                                            if r.valid and r.status == OK]), chosen, seed, state)

    def _report(self, fitness: Fitness, front: list[Record], chosen: Record, seed: int,
                state: RunState) -> None:
        """Set the equations table (``front``, with ``chosen`` marked, in place of the
        front's row of its complexity), history and model."""
        front = sorted([r for r in front if r.complexity != chosen.complexity] + [chosen],
                       key=lambda r: (r.complexity, r.objective))
        self._front, self._chosen = front, chosen
        self._equation_models = [self._to_model(r, fitness, seed, state) for r in front]
        self.equations_ = [_row(r, model, chosen)
                           for r, model in zip(front, self._equation_models)]
        self.history_ = [dict(vars(h)) for h in state.history]
        self.model_ = self._equation_models[[r.key for r in front].index(chosen.key)]

    def _replace_chosen(self, fitness: Fitness, chosen: Record, seed: int,
                        state: RunState) -> None:
        """Put ``chosen`` (refitted on ``fitness``) in the reported model's row of the
        equations table; the other rows stay as they are."""
        row = [r.key for r in self._front].index(self._chosen.key)
        self._front[row], self._chosen = chosen, chosen
        self._equation_models[row] = self.model_ = self._to_model(chosen, fitness, seed, state)
        self.equations_[row] = _row(chosen, self.model_, chosen)

    def _to_model(self, record: Record, fitness: Fitness, seed: int, state: RunState) -> Model:
        return Model.from_coefficients(
            fitness.symbols, record.coefficients,
            input_interpolation=self.config.input_interpolation,
            substeps=fitness.evaluator.substeps,
            metrics={"rms": record.rms, "f_time": record.f_time, "f_freq": record.f_freq,
                     "objective": record.objective, "n_bins": fitness.evaluator.n_bins},
            provenance={"seed": seed, "generations": state.generation,
                        "stopped_by": self.stopped_by, "population": self.config.population,
                        "coefficients": self.config.coefficients,
                        "data": fitness.measurement.fingerprint()} | self._provenance)

    def _write(self, out: Path, fitness: Fitness) -> None:
        _progress.stage(f"writing results to {out}/")
        self.model_.save(out / "model.json")
        write_text_atomic(out / "history.csv", history_csv(self.history_))
        write_text_atomic(out / "equations.csv", history_csv(self.equations_))
        write_text_atomic(out / "equations.json", json.dumps(
            [m.to_json() for m in self._equation_models], indent=1) + "\n")
        write_text_atomic(out / "config.json", json.dumps(self.config.to_dict(), indent=2) + "\n")
        calculated = self._reference  # the whole record's (:meth:`_set_residuals`)
        m = self.model_.metrics
        title = (f"{self.model_}\nRMS = {m['rms']:.4g}, f = {m['objective']:.4g} "
                 f"(f_time {m['f_time']:.4g} + f_freq {m['f_freq']:.4g})")
        write_bytes_atomic(out / "fit.png", fit_figure(
            self.measurement_.time, self.measurement_.response, calculated,
            response_name=self.measurement_.response_name, n_bins=fitness.evaluator.n_bins,
            title=title))

    # --- using a fitted model -----------------------------------------------------------
    def _need_model(self) -> Model:
        if self.model_ is None:
            raise UserInputError("this Identifier has no model yet; call fit() or load() first")
        return self.model_

    def simulate(self, time=None, inputs: dict[str, np.ndarray] | None = None,
                 x0=None, *, solver: str = "reference") -> np.ndarray:
        """The model's response ((N,), or (N, D) for several coordinates), by the
        reference solve (adaptive diffrax Dopri8) or ``solver="rk4"`` (the run's
        fixed-step integrator; :meth:`Model.simulate`).

        Args:
            time: sample times (N,) in seconds, uniform, with ``inputs`` (name -> (N,)) a
                new excitation; or a :class:`Measurement` (its time and inputs); default:
                the fitting data.
            inputs: the model's inputs by name (with ``time`` as an array).
            x0: (x, x') at the first sample, or (D, 2). Default: the fitted initial state on the
                fitting data and for new inputs; estimated from the first samples
                (eq. 13) for another Measurement.

        Raises:
            UserInputError: no model yet, or no data (``load`` without a measurement).
            ModelFileError: an input of the model is missing.
        """
        model = self._need_model()
        if time is None:
            if self.measurement_ is None:
                raise UserInputError("no data to simulate on; pass time and inputs or a "
                                     "Measurement")
            time = self.measurement_
            x0 = model.initial_states if x0 is None else x0
        if isinstance(time, Measurement):
            return model.simulate(time, initial_conditions=x0, solver=solver)
        if inputs is None:
            raise UserInputError("simulate(time, inputs): give the inputs by name with time")
        x0 = model.initial_states if x0 is None else x0
        if x0 is None:
            raise UserInputError("the model has no initial state; pass x0=(x, x')")
        return model.simulate_inputs(time, inputs, x0)

    def score(self, measurement: Measurement | None = None) -> float:
        """Coefficient of determination R² of the response simulated by the reference
        solve (1 is perfect; several coordinates: the mean of theirs); its RMS error is
        ``model_.metrics["rms_reference"]`` on the fitting data."""
        data = measurement or self.measurement_
        simulated = np.reshape(self.simulate(measurement), data.responses.shape)
        residual = np.sum((data.responses - simulated) ** 2, axis=0)
        spread = np.sum((data.responses - data.responses.mean(axis=0)) ** 2, axis=0)
        return float(np.mean(1.0 - residual / spread))

    def _equation_model(self, index: int | None) -> Model:
        if index is None:
            return self._need_model()
        if not self._equation_models:
            raise UserInputError("this Identifier has no equations table; call fit() or "
                                 "load() a run folder that has equations.json")
        return self._equation_models[index]

    def sympy(self, index: int | None = None):
        """The reported equation, or row ``index`` of ``equations_``, with its constants."""
        return self._equation_model(index).sympy()

    def latex(self, index: int | None = None, *, numeric: bool = False) -> str:
        """LaTeX of the reported equation, or of row ``index`` of ``equations_``;
        ``numeric``: with the constants' values (± half of the 95 % interval where known)."""
        return self._equation_model(index).latex(numeric=numeric)

    def __str__(self) -> str:
        if self.model_ is None:
            return f"Identifier(unfitted, population={self.config.population})"
        m = self.model_.metrics
        rms = m.get("rms", float("nan"))
        rms = (", ".join(f"{k} {'diverged' if v is None else f'{v:.4g}'}"  # None: diverged
                         for k, v in rms.items()) if isinstance(rms, dict) else f"{rms:.4g}")
        lines = [f"{self.model_}",
                 f"  RMS {rms}   f = {m.get('objective', float('nan')):.4g}"
                 f"   stopped by {self.stopped_by or 'n/a'}"]
        check = self.model_.convergence
        if check:
            lines.append(f"  {check_line(check)}")
            width = check.get("sign_width")
            if width:
                lines.append(width_line(width, check.get("stopped")))
        lines += _scale_lines(self.model_)
        band = self.model_.uncertainty
        if band is not None:
            lines.append("  ±: half of each constant's 95 % interval (output error, "
                         "frequency-domain sandwich)" + "".join(
                             f"; {a}, {b} correlated ρ = {r:+.2f}" for a, b, r in band.correlated()))
            if band.reconstruction_warning():
                lines.append(f"  {band.reconstruction_warning()}")
        if self.equations_:
            lines.append("  complexity  objective     equation")
            for row in self.equations_:
                mark = "*" if row["selected"] else " "
                lines.append(f"{mark} {row['complexity']:>9}  {row['objective']:<12.5g}  "
                             f"{row['equation']}")
        return "\n".join(lines)

    @classmethod
    def load(cls, run_dir: str | Path, measurement: Measurement | None = None) -> "Identifier":
        """Reload a finished run from its folder (model, config, history, equations), so
        :meth:`simulate`, :meth:`score`, :meth:`sympy` and :meth:`latex` work again.

        Args:
            run_dir: the run folder.
            measurement: the data the run was fitted to, for ``simulate()`` and
                ``score()`` without arguments.

        Raises:
            UserInputError: not a run folder, or ``measurement`` is not the run's data.
        """
        run_dir = Path(run_dir)
        config_path = run_dir / "config.json"
        try:
            config = GPConfig.from_dict(json.loads(config_path.read_text(encoding="utf-8")),
                                        source=str(config_path))
        except FileNotFoundError:
            raise UserInputError(f"{config_path} does not exist; give a gpjax run folder") from None
        except json.JSONDecodeError as err:
            raise UserInputError(f"{config_path} is not valid JSON ({err})") from None
        identifier = cls(config)
        identifier.model_ = Model.load(run_dir / "model.json")
        identifier.stopped_by = identifier.model_.provenance.get("stopped_by", "")
        identifier.history_ = _read_csv(run_dir / "history.csv")
        identifier.equations_ = _read_csv(run_dir / "equations.csv")
        if (run_dir / "equations.json").is_file():
            identifier._equation_models = [
                Model.from_json(item, source=str(run_dir / "equations.json"))
                for item in json.loads((run_dir / "equations.json").read_text("utf-8"))]
        if measurement is not None:
            expected = identifier.model_.provenance.get("data")
            if expected is not None and measurement.fingerprint() != expected:
                raise UserInputError(f"the measurement is not the data {run_dir} was fitted "
                                     "to; pass that data, or simulate new data with simulate()")
            identifier.measurement_ = measurement
        return identifier


class _StopOnInterrupt:
    """Turns the first Ctrl-C into a request to stop after the current generation.

    A second Ctrl-C raises KeyboardInterrupt as usual. Outside the main thread (where
    signal handlers cannot be set) it does nothing.
    """

    def __init__(self):
        self.requested = False
        self._previous = None

    def _handle(self, signum, frame):
        self.requested = True
        signal.signal(signal.SIGINT, signal.default_int_handler)

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc):
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
        return False


def _projection(width) -> str:
    """How fast the width check converged, for the warning of an unconverged sign."""
    if not math.isfinite(width.rate):
        return "the check one narrowing further could not be made"
    if math.isinf(width.narrowings_needed):
        return (f"its change did not fall as the sign narrowed: {width.ratio:.1%}, then "
                f"{width.next_ratio:.1%}")
    return (f"its change falls {width.rate:.2g}× per narrowing: about "
            f"{width.narrowings_needed} more narrowing(s) would pass")


def _scale_lines(model: Model) -> list[str]:
    """The printout's note on equations identified only up to a factor (no input)."""
    names = [model.coordinates[i] for i in model.unscaled()]
    if not names:
        return []
    hint = ("; --third-law carries the input's units to an equation through its "
            "coupling forces" if model.n_coordinates > 1 and not model.third_law else "")
    return [f"  no input in the equation of {', '.join(names)}: identified up to a factor, "
            f"its constants are per unit of its mass (m held at 1){hint}"]


def _row(record: Record, model: Model, chosen: Record) -> dict:
    return {"complexity": record.n_constants, "objective": record.objective, "rms": record.rms,
            "f_time": record.f_time, "f_freq": record.f_freq,
            "equation": str(model.sympy()), "selected": record.key == chosen.key,
            "constants": ", ".join(f"{k} = {v}" for k, v in model.constant_texts().items())}


def _read_csv(path: Path) -> list[dict]:
    import csv

    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    for row in rows:
        for key, value in row.items():
            if key == "selected":
                row[key] = value == "True"
            elif key not in TEXT_COLUMNS:
                row[key] = float(value) if value != "" else None  # "": no valid candidate
    return rows
