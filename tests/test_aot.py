"""Compiled programs kept on disk (gpjax._aot): a second process loads the executable
instead of tracing and compiling, a changed key compiles afresh, a damaged file is
replaced, and switching the cache off writes nothing."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gpjax import _aot
from gpjax._integrate import enable_float64

SCRIPT = textwrap.dedent("""
    import sys, jax.numpy as jnp
    from gpjax import _aot
    from gpjax._integrate import enable_float64
    enable_float64()  # as gpjax does before it computes: float64 and JAX's own cache
    traced = []
    def f(x, y):
        traced.append(1)
        z = jnp.sin(x[:, None] / (1.0 + y[None, :])).sum(0)
        return z, jnp.linalg.solve(jnp.eye(3) + x[:3, None] * x[None, :3], x[:3])
    program = _aot.Program(f, name="test", key=_aot.fingerprint(sys.argv[1]))
    a, b = program(jnp.linspace(0, 1, 5), jnp.linspace(1, 2, 7))
    print(len(traced), float(a.sum()), float(b.sum()))
""")


def _run(folder, key, **variables):
    env = dict(os.environ, GPJAX_CACHE_DIR=str(folder), GPJAX_COMPILATION_CACHE="on",
               JAX_PLATFORMS="cpu", **variables)
    out = subprocess.run([sys.executable, "-c", SCRIPT, key], env=env, capture_output=True,
                         text=True, check=True)
    traced, *values = out.stdout.split()
    return int(traced), [float(v) for v in values]


def test_a_second_process_loads_the_program_without_tracing_it(tmp_path):
    first = _run(tmp_path, "record-a")
    files = sorted((tmp_path / _aot.PROGRAMS).iterdir())
    second = _run(tmp_path, "record-a")
    assert first[0] == 1 and second[0] == 0  # traced once, then loaded (LAPACK call too)
    assert first[1] == second[1]
    assert sorted((tmp_path / _aot.PROGRAMS).iterdir()) == files and len(files) == 1
    other = _run(tmp_path, "record-b")  # another key: traced and stored beside it
    assert other[0] == 1 and len(list((tmp_path / _aot.PROGRAMS).iterdir())) == 2


def test_programs_stored_while_jax_holds_the_same_executables_still_load(tmp_path):
    """JAX's own cache (same folder) has the program; gpjax's file of it is gone. The
    file written then must run in a third process (an executable JAX's cache loaded
    would have been stored without its kernels)."""
    first = _run(tmp_path, "record-a")
    for path in (tmp_path / _aot.PROGRAMS).iterdir():
        path.unlink()
    assert _run(tmp_path, "record-a")[0] == 1
    assert _run(tmp_path, "record-a") == (0, first[1])


def test_a_program_of_one_device_loads_where_there_are_several_host_devices(tmp_path):
    """With two host devices (``XLA_FLAGS``, as the docs suggest on a 2-core machine), a
    program compiled for one device was loaded for both and asked for two shards of
    every argument: the second run of a fit failed in its reference solve."""
    flags = {"XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    first = _run(tmp_path, "record-a", **flags)
    assert first[0] == 1
    assert _run(tmp_path, "record-a", **flags) == (0, first[1])


def test_a_damaged_program_file_is_compiled_again_and_replaced(tmp_path):
    _run(tmp_path, "record-a")
    (path,) = (tmp_path / _aot.PROGRAMS).iterdir()
    path.write_bytes(b"\x02\x00\x00\x00\x01\x00\x00\x00\x00\x00\x00\x00not an executable")
    traced, values = _run(tmp_path, "record-a")
    assert traced == 1 and np.isfinite(values).all()
    assert _run(tmp_path, "record-a")[0] == 0


def test_switched_off_the_cache_keeps_programs_in_memory(tmp_path, monkeypatch):
    enable_float64()
    monkeypatch.setenv("GPJAX_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("GPJAX_COMPILATION_CACHE", "off")
    calls = []

    def f(x):
        calls.append(1)
        return (2 * x,)

    program = _aot.Program(f, name="off", key="k")
    assert float(program(jnp.ones(3))[0].sum()) == 6.0
    assert float(program(jnp.ones(3))[0].sum()) == 6.0
    program(jnp.ones(4))  # a new shape is a new executable
    assert len(calls) == 2 and not (tmp_path / _aot.PROGRAMS).exists()


def test_fingerprint_tells_arrays_and_settings_apart():
    base = _aot.fingerprint(np.arange(3.0), {"substeps": 2}, "x")
    assert base == _aot.fingerprint(np.arange(3.0), {"substeps": 2}, "x")
    assert base != _aot.fingerprint(np.arange(3.0) + 1e-12, {"substeps": 2}, "x")
    assert base != _aot.fingerprint(np.arange(3.0), {"substeps": 3}, "x")
    assert base != _aot.fingerprint(np.arange(3.0).astype(np.float32), {"substeps": 2}, "x")


@pytest.mark.parametrize("change", ["bucket", "substeps"])
def test_evaluators_on_another_length_bucket_or_settings_have_other_keys(change):
    """The key holds shapes and settings, not samples: another record of the same length
    bucket shares it (tests/test_record.py), another bucket or setting does not."""
    from gpjax import Symbols
    from gpjax._evaluator import PopulationEvaluator
    from gpjax.gear import load_bundled_example

    measurement, _ = load_bundled_example()  # 1,334 samples: the 1,536 bucket
    symbols = Symbols("phi", "t", ("T",))
    base = PopulationEvaluator(measurement, symbols, max_degree=2, batch=4)
    if change == "bucket":
        other = measurement.segment(0, 1280)
        other_ev = PopulationEvaluator(other, symbols, max_degree=2, batch=4)
    else:
        other_ev = PopulationEvaluator(measurement, symbols, max_degree=2, batch=4, substeps=2)
    assert base.key != other_ev.key
    assert base.key == PopulationEvaluator(measurement, symbols, max_degree=2, batch=4).key
    shorter = PopulationEvaluator(measurement.segment(3, 1300), symbols, max_degree=2, batch=4)
    assert shorter.key == base.key
    other_bins = PopulationEvaluator(measurement, symbols, max_degree=2, batch=4, n_bins=200)
    assert other_bins.key != base.key and other_bins.time_key == base.time_key  # the refiner's


def test_bypassing_the_persistent_cache_restores_the_settings(tmp_path):
    enabled = jax.config.jax_enable_compilation_cache
    compiled = _aot._compile_bypassing_persistent_cache(
        lambda: jax.jit(lambda x: (x + 1,)).lower(jnp.ones(2)).compile())
    assert float(compiled(jnp.ones(2))[0].sum()) == 4.0
    assert jax.config.jax_enable_compilation_cache == enabled


def test_the_programs_folder_keeps_its_most_recently_used_files_within_its_bound(tmp_path):
    """Every change of gpjax's source or settings keys new program files: storing one
    deletes the least recently used beyond the folder's bound (never the file just
    stored), and loading a file marks it used."""
    sizes = {"old": 400, "used": 300, "mid": 300, "new": 500}
    for age, name in enumerate(["old", "used", "mid", "new"]):
        path = tmp_path / f"{name}.bin"
        path.write_bytes(b"x" * sizes[name])
        os.utime(path, (1_000_000 + age, 1_000_000 + age))
    _aot._touch(tmp_path / "used.bin")  # a load: now the most recent
    (tmp_path / "other.txt").write_bytes(b"y" * 10_000)  # not a program: never counted
    _aot.prune(tmp_path, keep=tmp_path / "new.bin", max_bytes=1_000)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.bin", "other.txt", "used.bin"]
    _aot.prune(tmp_path, keep=tmp_path / "new.bin", max_bytes=100)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.bin", "other.txt"]
