"""Many records: ``gpjax fit-many FOLDER`` fits every CSV file as its own Dask task.

Each record is read on the client (a file that cannot be read is a failed row at once),
fitted on a worker into a temporary folder whose files come back with the result, and
written to ``OUT/<record>/``; ``OUT/summary.csv`` has one row per record (record,
equation, constants, rms, seconds, compile_s, error; several coordinates: equations joined
by ``;`` and the RMS per coordinate; ``compile_s``: of ``seconds``, those compiling or
loading programs, only loading where an earlier record of the cache folder had the same
shapes and settings),
rewritten as results arrive. A record that
fails gets its one-line error in the ``error`` column; the others go on.
"""

from __future__ import annotations

import glob
import os
import tempfile
import time
from pathlib import Path
from typing import Sequence

from . import _progress
from ._cluster import dask_client
from ._config import GPConfig
from ._data import Measurement, load_csv
from ._errors import UserInputError
from ._report import check_out_folder, history_csv, write_bytes_atomic, write_text_atomic

SUMMARY = "summary.csv"
COLUMNS = ("record", "equation", "constants", "rms", "seconds", "compile_s", "error")


def record_paths(source: str | Path) -> list[Path]:
    """The CSV files of a folder, or those a glob pattern names, sorted.

    Raises:
        UserInputError: no CSV file found, or two records with the same name.
    """
    text = str(source)
    if Path(text).is_dir():
        paths = sorted(p for p in Path(text).iterdir() if p.suffix.lower() == ".csv")
    elif any(c in text for c in "*?["):
        paths = sorted(Path(p) for p in glob.glob(text) if Path(p).is_file())
    else:
        paths = [Path(text)] if Path(text).is_file() else []
    if not paths:
        raise UserInputError(f"no CSV files in {text}; give a folder holding .csv files or a "
                             "quoted glob such as 'data/*.csv'")
    stems = [p.stem for p in paths]
    twice = sorted({s for s in stems if stems.count(s) > 1})
    if twice:
        raise UserInputError(f"two records are named {twice[0]!r}; give each CSV file its own "
                             "name (run folders are named after the files)")
    return paths


def fit_record(measurement: Measurement, config: GPConfig, seed: int) -> dict:
    """Dask task: fit one record; its run folder's files (name -> bytes) and summary
    fields, or ``error`` (the one-line message of a user-input error)."""
    from ._estimator import Identifier

    began = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="gpjax-record-") as folder:
        try:
            identifier = Identifier(config).fit(measurement, seed=seed, out=folder,
                                                progress=False)
        except UserInputError as err:
            return {"error": " ".join(str(err).split())}
        files = {p.name: p.read_bytes() for p in Path(folder).iterdir() if p.is_file()}
    model = identifier.model_
    rms = model.metrics.get("rms_reference", model.metrics["rms"])
    return {"files": files,
            "equation": "; ".join(str(model.equation(i)) for i in range(model.n_coordinates)),
            "constants": "; ".join(f"{k}={v!r}" for k, v in model.constants().items()),
            "rms": ("; ".join(f"{k}=diverged" if v is None else f"{k}={v:.6g}"
                              for k, v in rms.items())
                    if isinstance(rms, dict) else rms),
            "seconds": time.perf_counter() - began,
            "compile_s": identifier.timings_["compile_s"], "error": ""}


def fit_many(source: str | Path, *, time: str, response: str | Sequence[str],
             inputs: tuple[str, ...] = (),
             config: GPConfig | None = None, seed: int = 0, out: str | Path = "gpjax-many",
             scheduler: str | None = None, workers: int | None = None) -> list[dict]:
    """Fit every record of ``source`` (a folder of CSV files or a glob), one Dask task each.

    Args:
        source: folder or glob of CSV files, all with the named columns.
        time, response, inputs: column names, as for :func:`gpjax.load_csv`; several
            responses (a list) are the coordinates of a system.
        config: run settings for every record; seed: the seed of every record's run.
        out: folder for one run folder per record and ``summary.csv``.
        scheduler: a running Dask scheduler's address; ``None`` starts a LocalCluster of
            ``workers`` processes (default: one per core, at most one per record).

    Returns:
        The summary rows (dicts with :data:`COLUMNS`), in record order.

    Raises:
        UserInputError: no records, ``out`` is a file, bad ``workers`` or scheduler.
    """
    paths = record_paths(source)
    out = Path(out)
    check_out_folder(out)
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise UserInputError(f"workers must be a positive integer, got {workers!r}")
    from distributed import as_completed  # after the checks: a bad request fails at once
    config = config or GPConfig()
    responses = [response] if isinstance(response, str) else list(response)
    rows = {p.stem: dict.fromkeys(COLUMNS, "") | {"record": p.stem} for p in paths}
    data = {}
    for path in paths:
        try:
            data[path.stem] = load_csv(path, time=time, responses=responses, inputs=inputs)
        except UserInputError as err:
            rows[path.stem]["error"] = " ".join(str(err).split())
    count = workers or max(1, min(len(data), os.cpu_count() or 1))
    with dask_client(scheduler, workers=count) as client:
        futures = {client.submit(fit_record, m, config, seed, pure=False,
                                 key=f"gpjax-record-{name}-{os.urandom(4).hex()}"): name
                   for name, m in data.items()}
        unread = len(paths) - len(data)
        _progress.stage(f"fitting {len(data)} record(s) on Dask, one task each"
                        + (f"; {unread} could not be read" if unread else ""))
        for done, future in enumerate(as_completed(futures), start=1):
            name = futures[future]
            try:
                result = future.result()
            except Exception as err:  # a bug or a lost cluster: that record's row
                result = {"error": f"{type(err).__name__}: {' '.join(str(err).split())}"}
            for file_name, content in result.pop("files", {}).items():
                write_bytes_atomic(out / name / file_name, content)
            rows[name].update(result)
            outcome = f"failed: {result['error']}" if result["error"] else "fitted"
            _progress.stage(f"record {name} {outcome} ({done}/{len(futures)})")
            write_text_atomic(out / SUMMARY, history_csv(list(rows.values())))
    write_text_atomic(out / SUMMARY, history_csv(list(rows.values())))
    return list(rows.values())
