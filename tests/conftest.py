"""Fixtures shared by test modules: each benchmark's quick run, made once per session.

``seqdex_drake`` is imported first, before any test module loads numpy or torch, so that its kernel pin
(``seqdex_drake/numerics.py``) holds for the whole session and recorded episodes replay bit for bit."""

import seqdex_drake  # noqa: F401, I001 - first: pins numpy's, OpenBLAS's and torch's kernels before they load.

import importlib.util
import os
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_ONE_THREAD = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


def _load_run_all():
    """benchmarks/run_all.py as a module (benchmarks/ is not a package)."""
    spec = importlib.util.spec_from_file_location("run_all", ROOT / "benchmarks" / "run_all.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def benchmark_run():
    """``benchmark_run(name)``: the record of benchmark ``name``'s quick run, made as ``benchmarks/run_all.py
    --test`` makes it (``run_all.run``: its declared test arguments; its last-line JSON under ``result``, None if
    it failed, with the tail of its stderr under ``error``), with one BLAS/OpenMP thread per process. Each
    benchmark runs at most once per session: tests/test_benchmarks.py checks its figures and tests/test_docs.py
    that it prints every key docs/performance.md names, from the same run."""
    run_all = _load_run_all()
    benchmarks = {benchmark.name: benchmark for benchmark in run_all.BENCHMARKS}
    records = {}

    def run(name: str) -> dict:
        if name not in records:
            if name == "env_instructions" and shutil.which("valgrind") is None:
                pytest.fail("valgrind is not installed (benchmarks/env_instructions.py needs it): run the tests as "
                            "`bash scripts/venv.sh python -m pytest` (it installs it), or apt-get install -y valgrind")
            saved = {key: os.environ.get(key) for key in _ONE_THREAD}
            os.environ.update(_ONE_THREAD)
            try:
                records[name] = run_all.run(benchmarks[name], test=True, timeout=900.0)
            finally:
                for key, value in saved.items():
                    if value is None:
                        os.environ.pop(key, None)
                    else:
                        os.environ[key] = value
        return records[name]

    return run
