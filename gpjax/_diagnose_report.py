"""The diagnosis' output: ``report.json``, ``report.md``, ``model.json`` and three figures.

Figures are ``matplotlib.figure.Figure`` objects rendered by the Agg canvas
(:func:`gpjax._report.png_bytes`), so no backend is switched.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ._diagnose import CRITERION, Diagnosis
from ._objective import amplitude_spectrum
from ._system_diagnose import input_noise_words
from ._report import png_bytes, write_bytes_atomic, write_text_atomic


def write_report(diagnosis: Diagnosis, out) -> None:
    """Write report.json, report.md, model.json and three figures into folder ``out``:
    residual_time.png, residual_spectrum.png, measured_vs_simulated.png."""
    out = Path(out)
    report = diagnosis.to_json()
    write_text_atomic(out / "report.json", json.dumps(finite(report), indent=2) + "\n")
    write_text_atomic(out / "report.md", report_markdown(diagnosis))
    diagnosis.model().save(out / "model.json")
    for name, figure in _figures(diagnosis).items():
        write_bytes_atomic(out / name, figure)


def finite(value):
    """``value`` (JSON-like) with every non-finite float as ``None`` (JSON has no NaN)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [finite(v) for v in value]
    return value


def _number(value) -> str:
    return "–" if value is None else f"{value:.4g}"


def report_markdown(diagnosis: Diagnosis) -> str:
    """The report as Markdown: the table effect → evidence → term → coefficient → errors."""
    d = diagnosis
    unit = "response units" if d.mode == "simulation" else "force units (equation error)"
    lines = [f"# Diagnosis of {d.symbols.response}", "",
             f"Mode: **{d.mode}** — {CRITERION[d.mode]}.", "",
             f"Inputs between samples in the simulation: "
             f"{d.settings['input_interpolation']} interpolation.", "",
             f"Starting model: `{d.before.model(d.symbols, {}).sympy()}`", "",
             f"Final model: `{d.model().sympy()}`", "",
             *_interval_lines(d),
             f"Effects added: {', '.join(d.effects_added) or 'none'}", "",
             f"RMS in {unit}; f = f_time + f_freq (eqs. 7–9); spectral error = f_freq.", "",
             f"Whole record (the starting and the final structure refitted on all of it once "
             f"chosen): RMS {_number(d.before.metrics.get('rms'))} → "
             f"{_number(d.after.metrics.get('rms'))}, f {_number(d.before.metrics.get('objective'))}"
             f" → {_number(d.after.metrics.get('objective'))}, spectral error "
             f"{_number(d.before.metrics.get('spectral_error'))} → "
             f"{_number(d.after.metrics.get('spectral_error'))}.", "",
             *_convergence_lines(d),
             f"Steps: fitted on the first {d.n_train} of {d.measurement.n_samples} samples; "
             "the held-out rest decided.", "",
             *_noise_lines(d),
             "| effect | evidence | term | coefficient | p (adjusted) | RMS before | RMS after | "
             "f before | f after | spectral before | spectral after | held-out RMS before | "
             "after |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for s in d.steps:
        lines.append(f"| {s['effect']} | {s['evidence']} | {s['term']} | {s['coefficient']:.6g} "
                     f"| {_number(s['test']['p_adjusted'])} | {_number(s['rms_before'])} | "
                     f"{_number(s['rms_after'])} | "
                     f"{_number(s['objective_before'])} | {_number(s['objective_after'])} | "
                     f"{_number(s['spectral_error_before'])} | {_number(s['spectral_error_after'])} "
                     f"| {_number(s['rms_holdout_before'])} | {_number(s['rms_holdout_after'])} |")
    lines += _ambiguity_lines(d)
    for caution in sign_cautions(d):
        lines += ["", f"**Caution:** {caution}"]
    lines += _stop_lines(d) + _unexplained_lines(d)
    lines += ["", "## Evidence per round (best first)", "",
              "Simulation mode: held-out RMS with the effect refitted alone (/ predicted with "
              "its best partner); equation-error mode: share of the weak-form equation-error "
              "residual energy the effect explains.", ""]
    for i, ranking in enumerate(d.rankings, start=1):
        lines.append(f"{i}. " + ", ".join(map(_evidence_cell, ranking)))
    lines += ["", "Figures: residual_time.png, residual_spectrum.png, measured_vs_simulated.png.",
              ""]
    return "\n".join(lines)


def _ambiguity_lines(d: Diagnosis) -> list[str]:
    """Per step with effects the record cannot separate from it: the set, and the input
    change that would separate them (:mod:`gpjax._diagnose_ambiguity`)."""
    lines = []
    for s in d.steps:
        tied = s.get("indistinguishable")
        if not tied:
            continue
        others = ", ".join(f"{t['effect']} (p = {_number(t['p_value'])})" for t in tied)
        lines += ["", f"**Cannot be told apart on this record:** {s['effect']} (accepted) and "
                      f"{others} predict the held-out segment equally well; this record cannot "
                      "separate them."]
        proposal = s.get("separating_input")
        if proposal and proposal["change"]:
            gaps = proposal["separation"]
            lines.append(f"A record with the input changed by **{proposal['change']}** would: "
                         f"their responses would differ by {_number(gaps[proposal['change']])}× "
                         f"the accepted model's held-out RMS residual, against "
                         f"{_number(gaps['this record'])}× on this record's input.")
    return lines


def _interval_lines(d: Diagnosis) -> list[str]:
    """The final model's constants with half their 95 % interval; those whose interval
    holds 0 are named (the record does not tell them from zero)."""
    band = d.uncertainty
    if band is None:
        return ["Constants' intervals: not computed (the final fit is not finite).", ""]
    basis = ("output error on the whole record" if d.mode == "simulation" else
             "weak-form equation error on the whole record; noise in the smoothed derivatives "
             "biases these constants and the interval does not count it")
    cells, zero = [], []
    for name, value in zip(band.names, band.values):
        low, high = band.interval(name)
        cells.append(f"{name} = {value:.6g} ± {band.half_width(name):.2g}")
        if low <= 0 <= high and not name.endswith("(0)"):
            zero.append(name)
    lines = [f"Constants (± half the 95 % interval, {basis}): "
             + ", ".join(cells) + ".", ""]
    if zero:
        lines += [f"**Not distinguishable from zero** (the interval holds 0): "
                  f"{', '.join(zero)}.", ""]
    return lines + [f"{a} and {b} are correlated, ρ = {rho:+.2f}." for a, b, rho in
                    band.correlated()] + ([""] if band.correlated() else [])


def _noise_lines(d: Diagnosis) -> list[str]:
    """The noise the data show: measured inputs reduced to lines, the noise floor."""
    out = []
    for name, entry in (d.settings.get("input_noise") or {}).items():
        if entry["denoised"]:
            out += [f"Input {name}: reduced to {len(entry['lines_hz'])} significant spectral "
                    f"lines (level {d.settings['alpha']}); noise removed: σ = "
                    f"{entry['sigma']:.4g}.", ""]
    floor = (d.noise or {}).get("after") or (d.noise or {}).get("response")
    if floor is None:
        return out + ["Noise floor: not estimated (too few bins outside the response's "
                      "band).", ""]
    if d.mode != "simulation":
        return out + [f"Noise floor of {d.symbols.response} (spectrum above "
                      f"{floor['band_hz']:.4g} Hz): σ̂ = {floor['sigma']:.4g} (response units; "
                      "the residual here is a force).", ""]
    verdict = ("the residual is at the noise floor" if floor["p_excess"] >= d.settings["alpha"]
               else "the residual's in-band excess over the floor is significant")
    return out + [f"Noise floor (the final residual's spectrum above {floor['band_hz']:.4g} "
                  f"Hz): σ̂ = {floor['sigma']:.4g}; final RMS {floor['rms']:.4g} = "
                  f"{floor['ratio']:.3g} σ̂{input_noise_words(floor)} (in-band excess p = "
                  f"{floor['p_excess']:.3g}: {verdict}).", ""]


def _stop_lines(d: Diagnosis) -> list[str]:
    """Why the loop stopped: the last round's best p-value."""
    tested = [e for e in d.rankings[-1] if "test" in e] if d.rankings else []
    if not tested or any(e["test"]["passed"] for e in tested):
        return []
    best = min(tested, key=lambda e: e["test"]["p_adjusted"])
    test = best["test"]
    parts = (f": held-out {test['p_holdout']:.3g}, score {test['score']['p_adjusted']:.3g}"
             if "score" in test else "")
    return ["", f"Stopped: no candidate passed the test at level {d.settings['alpha']}; the "
            f"best, {best['effect']}, had adjusted p = {test['p_adjusted']:.3g}{parts} "
            f"({len(tested)} tested)."]


def _unexplained_lines(d: Diagnosis) -> list[str]:
    """The residual no library effect explains, described (:mod:`_diagnose_residual`)."""
    u = d.unexplained
    if u is None:
        return []
    lines_hz = ", ".join(f"{line['hz']:.4g} Hz ({line['relation']})" for line in u["lines"])
    out = ["", "## Unexplained residual", "",
           "No library effect explains the final residual, and it stays far above the noise "
           "floor. It shows:", "",
           f"- spectral lines: {lines_hz or 'none significant'}",
           f"- dependence on {d.symbols.response}: η² = {u['x']['eta2']:.3g} "
           f"(p = {u['x']['p_value']:.3g}); on its rate: η² = {u['x_dot']['eta2']:.3g} "
           f"(p = {u['x_dot']['p_value']:.3g})",
           f"- hysteresis (branches by the sign of the rate): η² = "
           f"{u['hysteresis']['eta2']:.3g} (p = {u['hysteresis']['p_value']:.3g})", ""]
    if u["suggestions"]:
        out += ["Suggested:", ""] + [f"- {s}" for s in u["suggestions"]]
    else:
        out += ["No structure is significant. The excess is either noise the floor does not "
                "see (input noise, coloured sensor noise) or a force outside the model class, "
                "such as one in which position and velocity multiply (a damping that grows "
                "with the displacement, x²·x'; see Known limitations)."]
    return out


def _convergence_lines(d: Diagnosis) -> list[str]:
    """The final model's integration check, for the report."""
    c = d.convergence
    if c is None:
        return []
    verdict = "converged" if c["converged"] else "**not converged**"
    return [f"Integration: RK4 with {c['substeps']} step(s) per sample. Reference solve "
            f"(adaptive diffrax Dopri8, rtol 1e-10): RMS {_number(c['rms_reference'])}; the "
            f"two responses differ by {c['ratio']:.2%} of it ({verdict}, tolerance "
            f"{c['tolerance']:.0%}).", ""]


def sign_cautions(diagnosis: Diagnosis) -> list[str]:
    """One sentence per added effect fitted with the opposite sign of its physical meaning
    (:attr:`gpjax._effects.Effect.sign`), e.g. a friction force along the velocity."""
    return [f"{s['effect']} was fitted with coefficient {s['coefficient']:.4g}, the opposite "
            "sign of the effect it names (for a loss: a force that feeds energy in); read it "
            "as an unmodelled force of that shape, not as that effect"
            for s in diagnosis.steps if s.get("sign_as_meant") is False]


def _evidence_cell(entry: dict) -> str:
    predicted = entry.get("predicted")
    if predicted is None:
        return f"{entry['effect']} {100 * entry['explained']:.1f} %"
    cell = f"{entry['effect']} {_number(predicted['holdout_rms_alone'])}"
    if predicted["partner"]:
        cell += f" / {_number(predicted['holdout_rms_with_partner'])} with {predicted['partner']}"
    return cell


def _figures(d: Diagnosis) -> dict[str, bytes]:
    from matplotlib.figure import Figure

    m, time = d.measurement, d.measurement.time
    out = {}
    fig = Figure(figsize=(9, 6))
    axes = fig.subplots(2, 1, sharex=True)
    for label, fit in (("before", d.before), ("after", d.after)):
        if fit.simulated is not None:
            axes[0].plot(time, m.response - fit.simulated, lw=0.7, label=label)
    axes[0].axvline(time[d.n_train - 1], color="k", ls=":", label="held out in the selection →")
    axes[0].set_ylabel(f"{m.response_name} measured − simulated")
    axes[0].legend(loc="upper right")
    for label, fit in (("before", d.before), ("after", d.after)):
        axes[1].plot(time, fit.force, lw=0.7, label=label)
    axes[1].set_ylabel("equation-error residual\n(generalised force)")
    axes[1].set_xlabel(f"{m.time_name} [s]")
    axes[1].legend(loc="upper right")
    out["residual_time.png"] = png_bytes(fig, dpi=110)

    fig = Figure(figsize=(9, 4))
    ax = fig.subplots()
    frequency = np.fft.rfftfreq(m.n_samples, m.dt)
    for label, fit in (("before", d.before), ("after", d.after)):
        signal = (m.response - fit.simulated) if fit.simulated is not None else fit.force
        ax.semilogy(frequency[1:], amplitude_spectrum(signal)[1:] + 1e-300, lw=0.7, label=label)
    for f in d.frequencies:
        ax.axvline(f, color="grey", ls=":", lw=0.8)
    ax.set_xlabel("frequency [Hz] (dotted: candidate frequencies)")
    ax.set_ylabel("residual amplitude")
    ax.legend()
    out["residual_spectrum.png"] = png_bytes(fig, dpi=110)

    fig = Figure(figsize=(9, 4))
    ax = fig.subplots()
    ax.plot(time, m.response, "k", lw=0.8, label="measured")
    for label, fit in (("before", d.before), ("after", d.after)):
        if fit.simulated is not None:
            ax.plot(time, fit.simulated, lw=0.8, ls="--", label=f"simulated {label}")
    ax.set_xlabel(f"{m.time_name} [s]")
    ax.set_ylabel(m.response_name)
    ax.legend()
    out["measured_vs_simulated.png"] = png_bytes(fig, dpi=110)
    return out

