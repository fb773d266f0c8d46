"""The same bits on every x86-64 machine: numpy's, OpenBLAS's and torch's CPU kernels pinned to one level.

numpy, the OpenBLAS inside its wheel and torch each choose their kernels from the CPU they run on (numpy's ufunc
loops and OpenBLAS's GEMM/GEMV: AVX2 or AVX-512 versions; torch's vectorized ops likewise), and the versions
round differently in the last bits. A chain episode is chaotic (a last-bit change in one action or one 3 x 3
product moves the whole episode), so episode records made on one machine did not replay on another: on one
development machine the same tool-chain episode came out three ways under three kernel settings
(``tests/test_numerics.py``). :func:`pin` therefore selects, before numpy or torch is loaded, the AVX2 + FMA
kernels that every x86-64 machine since 2013 has (OpenBLAS ``OPENBLAS_CORETYPE=Haswell``, numpy without its
AVX-512 dispatch targets, torch ``ATEN_CPU_CAPABILITY=avx2``), so that the same seed gives the same episode
whatever the machine's own top instruction set. The cost is the AVX-512 kernels' speed on machines that have
them, which the batch-1 products of the simulation loop hardly use.

``scripts/venv.sh`` exports :data:`PINNED` for every command it runs (the README's, CI's), and ``import
seqdex_drake`` calls :func:`pin` first thing. Neither changes a variable already set (the user's choice wins) or
does anything on a CPU without AVX2 and FMA, or not x86-64 (other kernels then: such machines give their own
bits). Where numpy or torch was imported before seqdex_drake (a script run without venv.sh that imports numpy
first), :func:`pin` still sets the environment, so worker processes started afterwards are pinned, but this
process keeps the kernels it loaded (:func:`status` says so).
"""

from __future__ import annotations

import os
import platform
import sys

#: numpy's dispatch targets above AVX2 (the names of numpy 2.0-2.4; unknown names are ignored by numpy).
NUMPY_AVX512_TARGETS = ("X86_V4 AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL "
                        "AVX512_ICL AVX512_SPR")
PINNED = {"OPENBLAS_CORETYPE": "Haswell", "NPY_DISABLE_CPU_FEATURES": NUMPY_AVX512_TARGETS,
          "DRAKE_DISABLE_CPU_FEATURES": "AVX512F",
          "ATEN_CPU_CAPABILITY": "avx2"}
"""The environment :func:`pin` sets: one kernel level for OpenBLAS, numpy and torch."""


def _cpuinfo_field(name: str) -> str | None:
    """The first ``name : value`` line's value in /proc/cpuinfo (Linux); None elsewhere or when absent."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as stream:
            for line in stream:
                if line.startswith(name):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return None


def _cpu_flags() -> set[str]:
    """The CPU's feature flags from /proc/cpuinfo (Linux); empty elsewhere."""
    return set((_cpuinfo_field("flags") or "").split())


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (Linux), else :func:`platform.processor`: records carry it because
    the pinned kernels still give different bits on different CPU models (Drake's contact solve on AMD EPYC did not
    replay records made on the previous development machine)."""
    return _cpuinfo_field("model name") or platform.processor() or platform.machine() or "unknown"


def pinnable() -> bool:
    """Whether this machine runs the pinned kernels: x86-64 with AVX2 and FMA."""
    return platform.machine().lower() in ("x86_64", "amd64") and {"avx2", "fma"} <= _cpu_flags()


def pin() -> dict[str, str]:
    """Sets :data:`PINNED` in the environment where unset, if the machine can run them; returns what it set
    (empty when it set nothing). It pins this process only if numpy and torch are not loaded yet."""
    if not pinnable():
        return {}
    chosen = {name: value for name, value in PINNED.items() if name not in os.environ}
    os.environ.update(chosen)
    return chosen


#: The environment as this module first saw it, before :func:`pin` (numpy and torch read it when they load).
_AT_IMPORT = ({name: os.environ.get(name) for name in PINNED}, "numpy" in sys.modules or "torch" in sys.modules)


def status() -> str:
    """One line on whether this process's numerics are pinned, for records and error messages."""
    if not pinnable():
        return "not pinned: this CPU is not x86-64 with AVX2 and FMA (its own kernels; bits may differ elsewhere)"
    environment, loaded_before = _AT_IMPORT
    if loaded_before and any(environment[name] != value for name, value in PINNED.items()):
        return "not pinned: numpy or torch was loaded before seqdex_drake (run through scripts/venv.sh)"
    differing = {name: os.environ.get(name) for name, value in PINNED.items() if os.environ.get(name) != value}
    if differing:
        return f"not pinned: {differing} set otherwise (the user's choice)"
    return "pinned to AVX2 kernels (OpenBLAS Haswell, numpy and Drake without AVX-512, torch avx2)"


def machine() -> str:
    """One line for a record: the CPU model and whether the numerics are pinned (what an exact replay needs)."""
    return f"CPU {cpu_model()}; numerics {status()}"
