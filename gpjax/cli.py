"""Command line: ``gpjax demo``, ``gpjax fit``, ``gpjax fit-many``, ``gpjax diagnose``,
``gpjax simulate``.

User errors (bad file, column, configuration, model file, scheduler address) print one
line, ``gpjax: error: <problem>; <fix>``, exit with status 2 and leave no output behind.
``fit-many`` exits with 2 when any record failed, after writing every other record and
the summary. Where stderr is not a terminal (a log file, CI, ``nohup``, a cluster job),
every command writes its progress there, one line per generation and per stage
(:mod:`gpjax._progress`); stdout carries only the results.
"""

from __future__ import annotations

import argparse
import gc
import os
import shutil
import sys
import time
from pathlib import Path

from . import _progress
from ._config import INPUT_FORCINGS, WIDE_FUNCTIONS, GPConfig
from ._data import INPUT_INTERPOLATIONS
from ._errors import UserInputError
from ._report import check_out_folder

EXIT_USER_ERROR = 2


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, no usage block
        raise UserInputError(f"{message}; see 'gpjax {self.prog.split()[-1]} --help'"
                             if " " in self.prog else f"{message}; see 'gpjax --help'")


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="gpjax", description=(
        "Derive the Newton–Euler ODE of a dynamic system from its measured response by "
        "genetic programming (Ciglarič & Kidrič)."))
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    demo = commands.add_parser("demo", help="the paper's protocol on the bundled gear example")
    demo.add_argument("--out", default="gpjax-demo", help="run folder (default: gpjax-demo)")
    demo.add_argument("--seed", type=_non_negative, default=0, help="random seed (default: 0)")
    demo.add_argument("--population", type=int, help="individuals per generation (default 500)")
    demo.add_argument("--generations", type=int, help="maximum generations (default 10)")
    fit = commands.add_parser("fit", help="identify a model from a CSV file")
    fit.add_argument("data", help="CSV file with a header row")
    _fit_options(fit, out="gpjax-run")
    fit.add_argument("--resume", action="store_true", help="continue the run in --out")
    fit.add_argument("--diagnose", action="store_true",
                     help="after the GP, diagnose missing effects (report in OUT/diagnosis)")
    fit.add_argument("--islands", type=int, help="run K islands (the population shared "
                     "among them) on Dask, with migration")
    fit.add_argument("--migrate-every", type=int, dest="every",
                     help="generations between migrations (default 2)")
    fit.add_argument("--migrants", type=int, help="structures each island sends (default 2)")
    fit.add_argument("--topology", choices=("ring", "random"), help="who sends to whom "
                     "(default ring)")
    _scheduler_option(fit)
    fit.add_argument("--third-law", action="store_true", dest="third_law",
                     help="several responses: each coupling force acts on both of its "
                     "coordinates with opposite signs, its constants shared (Newton's third "
                     "law; or third_law = true in the config file)")
    _diagnose_options(fit)
    many = commands.add_parser("fit-many", help="fit every CSV file of a folder (or a glob), "
                               "one Dask task each; writes OUT/summary.csv")
    many.add_argument("source", help="folder of CSV files, or a quoted glob like 'data/*.csv'")
    _fit_options(many, out="gpjax-many")
    many.add_argument("--workers", type=int, help="local workers (default: one per core)")
    _scheduler_option(many)
    diagnose = commands.add_parser("diagnose", help="trace a model's residual to missing "
                                   "physical effects, add them and report")
    diagnose.add_argument("data", help="CSV file with a header row")
    diagnose.add_argument("--model", required=True, help="model.json (constants are refitted)")
    diagnose.add_argument("--time", required=True, help="name of the time column (seconds)")
    _response_option(diagnose)
    diagnose.add_argument("--input", action="extend", type=_names, default=[],
                          dest="inputs", help="name of an input column (repeat, or "
                          "separate by commas, for several)")
    diagnose.add_argument("--out", default="gpjax-diagnose",
                          help="report folder (default: gpjax-diagnose)")
    _diagnose_options(diagnose)
    simulate = commands.add_parser("simulate", help="simulate a saved model on new input "
                                   "with the reference solver (adaptive diffrax Dopri8)")
    simulate.add_argument("model", help="model.json")
    simulate.add_argument("data", help="CSV file with the model's time and input columns "
                          "(and its response column, unless --initial is given)")
    simulate.add_argument("--out", required=True, help="CSV file to write (time, response)")
    simulate.add_argument("--initial", nargs="+", type=_finite_float, metavar="X0 V0",
                          help="each response and its derivative at the first sample, "
                          "X0 V0 per coordinate in the model's order (default: the state "
                          "that best reproduces the data's response columns: eq. 13's "
                          "estimate refined by Gauss-Newton steps)")
    simulate.add_argument("--band", action="store_true",
                          help="add the 95%% band of each response from the constants' "
                          "uncertainty, from draws of the constants (columns "
                          "<response>_low, <response>_high)")
    simulate.add_argument("--seed", type=_non_negative, default=0,
                          help="seed of --band's draws (default 0)")
    return parser


def _fit_options(parser, *, out: str) -> None:
    parser.add_argument("--time", required=True, help="name of the time column (seconds)")
    _response_option(parser)
    parser.add_argument("--input", action="extend", type=_names, default=[], dest="inputs",
                        help="name of an input column (repeat, or separate by commas, "
                        "for several)")
    parser.add_argument("--config", help="TOML file of settings (docs/configuration.md)")
    parser.add_argument("--population", type=int, help="individuals per generation")
    parser.add_argument("--generations", type=int, help="maximum generations")
    parser.add_argument("--functions", type=_names,
                        help="function set, comma-separated (default: the paper's "
                        "add,sub,mul; for friction, pendulums and saturation e.g. "
                        f"{','.join(WIDE_FUNCTIONS)})")
    parser.add_argument("--input-forcing", choices=INPUT_FORCINGS, dest="input_forcing",
                        help="how an input may enter the forcing: linear, as g·u (default); "
                        "any, any function of time and inputs (the paper's rule)")
    parser.add_argument("--seed", type=_non_negative, default=0,
                        help="random seed (default: 0)")
    parser.add_argument("--out", default=out, help=f"output folder (default: {out})")


def _response_option(parser) -> None:
    parser.add_argument("--response", action="extend", type=_names, required=True,
                        dest="responses", help="name of a measured response column (repeat, "
                        "or separate by commas, for the coordinates of a system with "
                        "several degrees of freedom)")


def _one_response(args) -> str:
    """The one ``--response`` of a command that identifies one coordinate."""
    if len(args.responses) > 1:
        raise UserInputError(f"gpjax {args.command} takes one --response, got "
                             f"{len(args.responses)} ({', '.join(args.responses)}); give one")
    return args.responses[0]


def _scheduler_option(parser) -> None:
    parser.add_argument("--scheduler", help="address of a running Dask scheduler, "
                        "tcp://HOST:PORT (default: start a local cluster)")


def _diagnose_options(parser) -> None:
    parser.add_argument("--frequency", action="append", default=[], type=_positive_float,
                        dest="frequencies", help="candidate frequency in Hz for time-varying "
                        "effects, e.g. the gear mesh frequency (repeat for several)")
    parser.add_argument("--holdout", type=_positive_float, default=0.25,
                        help="fraction of the record held out at its end (default 0.25)")
    parser.add_argument("--max-steps", type=_non_negative, default=4, dest="max_steps",
                        help="most effects added (default 4)")
    parser.add_argument("--alpha", type=_positive_float, default=0.05,
                        help="level of the acceptance test: the chance that a correct model "
                        "gains a spurious effect in a step (default 0.05)")
    parser.add_argument("--input-interpolation", choices=INPUT_INTERPOLATIONS,
                        dest="input_interpolation",
                        help="inputs between samples in the simulation: linear; "
                        "bandlimited for inputs with content near the Nyquist frequency; "
                        "hold for inputs applied by a DAC, each sample held for one period "
                        "(fit: the GP's too, default the config's; diagnose: default the "
                        "model's)")


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid number: {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text}")
    return value


def _finite_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid number: {text!r}") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def _non_negative(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {value}")
    return value


def _names(text: str) -> tuple[str, ...]:
    """A comma-separated list of names (blanks around them dropped)."""
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise argparse.ArgumentTypeError(f"expected comma-separated names, got {text!r}")
    return names


def _config(args, base: GPConfig) -> GPConfig:
    overrides = {k: getattr(args, k) for k in ("population", "generations", "functions",
                                               "input_interpolation", "input_forcing")
                 if getattr(args, k, None) is not None}
    return base.replace(**overrides) if overrides else base


def _demo(args) -> int:
    config = _config(args, GPConfig.paper())
    check_out_folder(Path(args.out))
    from .gear import load_bundled_example

    measurement, truth = load_bundled_example()
    identifier = _run(config, measurement, args.seed, Path(args.out), resume=False)
    constants = identifier.model_.constants()
    structure = sorted(identifier.model_.state), sorted(identifier.model_.forcing)
    print(identifier)
    _print_residuals(identifier.model_, config.functions)
    print(f"\nTruth (bundled generator): J = {truth['J']}, K1 = {truth['K1']}, K2 = {truth['K2']}")
    if structure == (["phi", "phi**2"], ["T"]):
        for name, key in (("J", "m"), ("K1", "k1"), ("K2", "k2")):
            error = 100 * (constants[key] / truth[name] - 1)
            print(f"  {name}: found {constants[key]:.6g}  ({error:+.2f} % from truth)")
    else:
        print("  found another structure than eq. 14: " + str(identifier.model_.equation()))
    _timings(identifier, args.out)
    return 0


def _process_started() -> float:
    """When this process started (s since the epoch, as ``time.time()``): on Linux from its
    start in clock ticks since boot (``/proc/self/stat``) and the boot-time clock, to a
    tick; psutil's ``create_time`` adds the boot time in whole seconds, up to 1 s off."""
    try:
        with open("/proc/self/stat", encoding="ascii") as stat:
            ticks = int(stat.read().rsplit(")", 1)[1].split()[19])  # field 22, starttime
        since = time.clock_gettime(time.CLOCK_BOOTTIME) - ticks / os.sysconf("SC_CLK_TCK")
        return time.time() - since
    except (OSError, ValueError, IndexError, AttributeError):  # not Linux
        import psutil

        return psutil.Process().create_time()


def _timings(identifier, out) -> None:
    """Print where the whole process's seconds went: parts that add up to the whole, from
    the process's start (start-up: Python, imports, reading the data) to this line."""
    t = identifier.timings_
    now = time.time()
    started = _process_started()
    seconds = [row["seconds"] for row in identifier.history_]
    later = (f", then {sum(seconds[1:]) / len(seconds[1:]):.2f} s a generation"
             if len(seconds) > 1 else "")
    parts = [("start-up and reading the data", t["finished_at"] - t["total_s"] - started),
             (f"search ({len(seconds)} generation{'s' * (len(seconds) != 1)}: generation 0 "
              f"{seconds[0]:.2f} s"
              f"{later})", t["search_s"]),
             ("final model selection", t["selection_s"]),
             ("convergence check", t["convergence_s"]),
             *([("standard errors and residuals", t["intervals_s"])] if "intervals_s" in t
               else []),
             ("writing results", t["writing_s"]), ("printing", now - t["finished_at"])]
    print(f"\nStopped by {identifier.stopped_by} after generation {t['generations']}. "
          f"{now - started:.1f} s in all: "
          + "; ".join(f"{name} {value:.1f} s" for name, value in parts)
          + f". Of these, {t['compile_s']:.1f} s compiling or loading {t['compiles']} "
          f"programs (evaluators, refiners, reference solves). Results in {out}/")


def _fit(args) -> int:
    from ._data import load_csv

    config = _config(args, GPConfig.from_toml(args.config) if args.config else GPConfig())
    several = len(args.responses) > 1
    if args.third_law:
        if not several:
            raise UserInputError("--third-law couples the equations of several responses; "
                                 "give one --response per coordinate, or drop it")
        config = config.replace(third_law=True)
    _check_diagnose_options(args)
    if several and args.diagnose:
        _check_system_diagnosis(args)
    islands = {}
    if any(getattr(args, k) is not None for k in ("islands", "scheduler", "every", "migrants",
                                                  "topology")):
        from ._island_settings import Migration, island_plan

        settings = {k: getattr(args, k) for k in ("every", "migrants", "topology")
                    if getattr(args, k) is not None}
        _, migration = island_plan(config, args.islands, scheduler=args.scheduler,
                                   migration=Migration(**settings))
        islands = dict(islands=args.islands, scheduler=args.scheduler, migration=migration)
    measurement = load_csv(args.data, time=args.time, responses=args.responses,
                           inputs=args.inputs)
    check_out_folder(Path(args.out))
    identifier = _run(config, measurement, args.seed, Path(args.out), resume=args.resume,
                      **islands)
    print(identifier)
    _print_residuals(identifier.model_, identifier.config.functions, diagnosing=args.diagnose)
    _timings(identifier, args.out)
    if identifier.stopped_by == "interrupted":
        return 130
    if args.diagnose:
        fitted = time.time()
        model = identifier.model_
        del identifier  # the fit's arrays and evaluators go before the diagnosis builds its own
        _release_fit()
        diagnosis = _run_diagnosis(args, measurement, model, Path(args.out) / "diagnosis")
        now = time.time()
        print(f"Whole process {now - _process_started():.1f} s: the fit as above, "
              f"then {now - fitted:.1f} s: the diagnosis as above ({diagnosis:.1f} s) and "
              "printing.")
    return 0


def _release_fit() -> None:
    """The memory a finished fit held, back to the system (:func:`gpjax._memory.release_memory`)."""
    from ._memory import release_memory
    from ._model import release_evaluators

    release_evaluators()
    release_memory()


def _print_residuals(model, functions: tuple[str, ...], *, diagnosing: bool = False) -> None:
    """Each coordinate's residual against its noise floor (with the hint where one misses
    something, unless the diagnosis follows); ``functions``: the run's function set."""
    from ._system_diagnose import hint, summary_line

    print("Residuals per coordinate (reference solve):")
    residuals = model.metrics["residuals"]
    for name, statistics in residuals.items():
        print(summary_line(name, statistics, functions))
    if any(s["unexplained"] is not None for s in residuals.values()):
        print("  the diagnosis follows" if diagnosing else f"  hint: {hint(functions)}")


def _check_diagnose_options(args) -> None:
    if not 0.05 <= args.holdout <= 0.5:
        raise UserInputError(f"--holdout must lie in [0.05, 0.5], got {args.holdout}; "
                             "use e.g. 0.25")
    if not args.alpha < 1:
        raise UserInputError(f"--alpha must lie in (0, 1), got {args.alpha}; use e.g. 0.05")


def _diagnose(args) -> int:
    from ._data import load_csv

    _check_diagnose_options(args)
    out = Path(args.out)
    check_out_folder(out)
    from ._model import Model

    model = Model.load(args.model)
    if model.n_coordinates > 1:
        _check_system_diagnosis(args)
        measurement = load_csv(args.data, time=args.time, responses=args.responses,
                               inputs=args.inputs)
    else:
        measurement = load_csv(args.data, time=args.time, response=_one_response(args),
                               inputs=args.inputs)
    _run_diagnosis(args, measurement, model, out)
    return 0


def _check_system_diagnosis(args) -> None:
    if args.frequencies:
        raise UserInputError("--frequency offers time-varying effects, which a system of "
                             "several coordinates cannot hold yet; drop it")


def _run_diagnosis(args, measurement, model, out: Path) -> float:
    """Diagnose ``model``, write the report to ``out`` and print its summary; returns
    the diagnosis's seconds (its stages, report included)."""
    if model.n_coordinates > 1:
        return _run_system_diagnosis(args, measurement, model, out)
    from ._convergence import check_line
    from ._diagnose import diagnose
    from ._diagnose_report import sign_cautions, write_report

    with _progress.stage_clock("the inputs' spectral lines and the weak form") as stages:
        result = diagnose(measurement, model, frequencies=tuple(args.frequencies),
                          holdout=args.holdout, max_steps=args.max_steps, alpha=args.alpha,
                          input_interpolation=args.input_interpolation)
        _progress.stage(f"diagnosis: writing the report to {out}/")
        write_report(result, out)
    before, after = result.before.metrics, result.after.metrics
    print(f"Diagnosis ({result.mode}): effects added: {', '.join(result.effects_added) or 'none'}")
    model = result.model()
    print(f"  RMS {before['rms']:.4g} -> {after['rms']:.4g}; model: {model.sympy()}")
    print("  constants (± half the 95 % interval): " + ", ".join(
        f"{name} = {text}" for name, text in model.constant_texts().items()))
    for step in result.steps:
        tied = [t["effect"] for t in step.get("indistinguishable", [])]
        if tied:
            change = (step.get("separating_input") or {}).get("change")
            print(f"  cannot be told apart on this record: {step['effect']} and "
                  f"{', '.join(tied)}" + (f"; a record with the input changed by {change} "
                                           "would separate them" if change else ""))
    if result.convergence:
        c = result.convergence
        print(f"  {check_line(c)}")
    for caution in sign_cautions(result):
        print(f"  caution: {caution}")
    print(f"Report in {out}/ (report.md, report.json, model.json, figures)")
    print(_progress.stage_summary("Diagnosis", stages))
    return sum(seconds for _, seconds in stages)


def _run_system_diagnosis(args, measurement, model, out: Path) -> float:
    from ._convergence import check_line
    from ._diagnose import diagnose
    from ._system_diagnose import summary_line

    with _progress.stage_clock("setting up") as stages:
        result = diagnose(measurement, model, holdout=args.holdout, max_steps=args.max_steps,
                          alpha=args.alpha, input_interpolation=args.input_interpolation)
        _progress.stage(f"diagnosis: writing the report to {out}/")
        result.write(out)
    print(f"Diagnosis (simulation, {model.n_coordinates} coordinates): effects added: "
          f"{', '.join(result.effects_added) or 'none'}")
    final = result.model()
    for i, name in enumerate(final.coordinates):
        print(f"  equation {i + 1} ({name}): {final.sympy(i)}")
    print("  constants (± half the 95 % interval): " + ", ".join(
        f"{name} = {text}" for name, text in final.constant_texts().items()))
    for name, statistics in result.residuals.items():
        print(summary_line(name, statistics, alpha=args.alpha))
    c = result.after.checks[-1].to_json()
    print(f"  {check_line(c)}")
    print(f"Report in {out}/ (report.md, report.json, model.json)")
    print(_progress.stage_summary("Diagnosis", stages))
    return sum(seconds for _, seconds in stages)


def _simulate(args) -> int:
    import numpy as np

    from ._band import prediction_band
    from ._data import Measurement, check_time, read_columns
    from ._model import fitted_initial_state, measurement_scale
    from ._model_file import load_model
    from ._report import write_text_atomic

    out = Path(args.out)
    if out.is_dir():
        raise UserInputError(f"--out {out} is a folder; give a CSV file name")
    model = load_model(args.model)
    coordinates = model.coordinates
    if args.initial is not None and len(args.initial) != 2 * len(coordinates):
        raise UserInputError(f"--initial takes X0 V0 for each of the model's "
                             f"{len(coordinates)} coordinates ({', '.join(coordinates)}): "
                             f"{2 * len(coordinates)} numbers, got {len(args.initial)}")
    data = read_columns(args.data, [model.time, *model.inputs], optional=coordinates)
    check_time(data[model.time])
    time, inputs = data[model.time], {u: data[u] for u in model.inputs}
    if all(c in data for c in coordinates):
        measurement = Measurement(time=time, responses=[data[c] for c in coordinates],
                                  inputs=inputs, time_name=model.time,
                                  response_names=coordinates)
        initial = (np.reshape(args.initial, (-1, 2)) if args.initial else fitted_initial_state(
            model, measurement, model.estimated_initial_states(measurement)))
        scale = measurement_scale(measurement)
    elif args.initial is None:
        missing = [c for c in coordinates if c not in data]
        raise UserInputError(f"{args.data} has no column {missing[0]!r} to estimate the "
                             "initial state from; give --initial X0 V0"
                             + (" per coordinate" if len(coordinates) > 1 else ""))
    else:
        initial, scale = np.reshape(args.initial, (-1, 2)), None
    header = [model.time, *coordinates]

    def by_coordinate(values):
        return list(np.reshape(values, (time.size, -1)).T)
    if args.band:
        band = prediction_band(model, time, inputs, initial, scale=scale, seed=args.seed)
        columns = by_coordinate(band.response)
        for c, low, high in zip(coordinates, by_coordinate(band.low), by_coordinate(band.high)):
            columns += [low, high]
            header += [f"{c}_low", f"{c}_high"]
    else:
        columns = by_coordinate(model.simulate_inputs(time, inputs, initial, scale=scale))
    if not np.all(np.isfinite(columns[0])):
        raise UserInputError("the model diverged on this input (the reference solve failed); "
                             "check the input's units and the initial state")
    lines = [",".join(header)] + [",".join(map(repr, map(float, row)))
                                  for row in zip(time, *columns)]
    write_text_atomic(out, "\n".join(lines) + "\n")
    equations = "; ".join(str(model.sympy(i)) for i in range(len(coordinates)))
    print(f"Simulated {equations} on {time.size} samples (reference solve); wrote {out}")
    if args.band:
        print(f"  {band.level:.0%} band from {band.draws} draws of the constants "
              f"({', '.join(band.constants)}; seed {args.seed}; initial state held)")
        if band.diverged:
            print(f"  caution: {band.diverged} of {band.draws} draws diverged on this input; "
                  "the band is that of the others, and the model may diverge within its "
                  "intervals")
    return 0


def _fit_many(args) -> int:
    from ._fit_many import SUMMARY, fit_many

    config = _config(args, GPConfig.from_toml(args.config) if args.config else GPConfig())
    rows = fit_many(args.source, time=args.time, response=args.responses,
                    inputs=tuple(args.inputs), config=config, seed=args.seed, out=args.out,
                    scheduler=args.scheduler, workers=args.workers)
    for row in rows:
        print(f"{row['record']}: " + (f"error: {row['error']}" if row["error"] else
                                      f"{row['equation']}  ({row['constants']}), "
                                      f"RMS {_rms_text(row['rms'])}, {row['seconds']:.1f} s"))
    failed = sum(bool(row["error"]) for row in rows)
    if failed:
        print(f"gpjax: error: {failed} of {len(rows)} records failed (see "
              f"{Path(args.out) / SUMMARY}); fix those records and fit them again",
              file=sys.stderr)
        return EXIT_USER_ERROR
    print(f"Summary in {Path(args.out) / SUMMARY}")
    return 0


def _rms_text(rms) -> str:
    """A summary row's RMS: a number, or (several coordinates) already text."""
    return rms if isinstance(rms, str) else f"{rms:.4g}"


def _run(config, measurement, seed, out: Path, *, resume: bool, **islands):
    from ._estimator import Identifier

    created = not out.exists()
    try:
        return Identifier(config).fit(measurement, seed=seed, out=out, resume=resume,
                                      **islands)
    except (UserInputError, KeyboardInterrupt):
        if created and out.exists():
            shutil.rmtree(out)
        raise


def console() -> int:
    """The ``gpjax`` console script and ``python -m gpjax``: :func:`main`'s exit status,
    run on the CPU unless ``JAX_PLATFORMS`` names a platform, with the interpreter's last
    garbage collection skipped (:func:`gc.freeze`).

    The CPU: the engine's RK4 scan is sequential in time and each step's work is small,
    so on a GPU every step costs a kernel launch, and a fit at the defaults runs slower
    there than on the CPU (docs/performance.md: the GPU wins only from P ≈ 2,000 on short
    records). ``JAX_PLATFORMS=cuda`` asks for the GPU; set before JAX starts, the choice
    reaches the Dask workers of ``--islands`` and ``fit-many`` too (they inherit the
    environment).

    The collection: at exit it would traverse every object the run left behind (sympy's
    caches, the compiled programs): about 0.5 s of a 5 s ``gpjax demo``. Every file is
    written and closed before :func:`main` returns, and the memory goes back with the
    process."""
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    status = main()
    gc.freeze()
    return status


def main(argv: list[str] | None = None) -> int:
    """The command line ``argv`` (default ``sys.argv[1:]``) run in this process; returns
    the exit status."""
    try:
        args = _parser().parse_args(argv)
        handler = {"demo": _demo, "fit": _fit, "fit-many": _fit_many, "diagnose": _diagnose,
                   "simulate": _simulate}[args.command]
        with _progress.lines_on_stderr():
            return handler(args)
    except UserInputError as err:
        message = " ".join(str(err).split("\n"))  # one line, whatever a name holds
        print(f"gpjax: error: {message}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("gpjax: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # stdout's reader closed it (`gpjax fit … | head`): no traceback
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # nor at exit's flush
        return 1
