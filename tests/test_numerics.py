"""Machine-independent numerics (``seqdex_drake/numerics.py``): the kernel pin reaches numpy, OpenBLAS, Drake and
torch through the environment, scripts/venv.sh exports the same pin, and the chain's numpy inference gives the same
bits whatever kernels numpy and OpenBLAS were allowed (each setting in a fresh interpreter)."""

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from seqdex_drake import numerics
from seqdex_drake.controller.inference_blocks import erf, exp, matmul

ROOT = Path(__file__).resolve().parents[1]
PINNABLE = numerics.pinnable()
NOT_X86 = "the pin applies to x86-64 CPUs with AVX2 and FMA only; this machine is not one"

# In a fresh interpreter: the shipped tool Grasp policy and F^reorient (attention, GELU, softmax) on fixed inputs,
# through the chain's numpy snapshots; prints a digest of the output bits.
SNAPSHOT_DIGEST = """
import hashlib, numpy as np
import seqdex_drake
from seqdex_drake.chaining.feasibility_io import load_feasibility
from seqdex_drake.controller.inference import PolicySnapshot, snapshot_feasibility
from seqdex_drake.rl.policy_loading import load_policy
root = "checkpoints/tool_positioning/"
policy = PolicySnapshot(load_policy(root + "stages/tool_grasp/best.pt").model)
f = snapshot_feasibility(load_feasibility(root + "feasibility/tool_reorient.pt").model)
rng = np.random.default_rng(0)
actions = np.stack([policy(o) for o in rng.normal(0, 1, (50, policy.obs_dim)).astype(np.float32)])
scores = np.array([f(h) for h in rng.normal(0, 1, (20, 10, policy.obs_dim)).astype(np.float32)])
print(hashlib.sha256(actions.tobytes() + scores.tobytes()).hexdigest())
"""


def _run(code: str, **environment) -> str:
    env = {key: value for key, value in os.environ.items() if key not in numerics.PINNED}
    env.update(environment)
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                            timeout=300, check=True)
    return result.stdout.strip().splitlines()[-1]


def test_venv_script_exports_the_same_pin():
    text = (ROOT / "scripts" / "venv.sh").read_text().replace("\\\n", "")
    exported = dict(re.findall(r'export (\w+)="\$\{\w+-([^}]*)\}"', text))
    assert exported == numerics.PINNED


@pytest.mark.skipif(not PINNABLE, reason=NOT_X86)
def test_importing_the_package_first_pins_every_library():
    report = json.loads(_run(
        "import json, os, seqdex_drake, numpy\n"
        "from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__\n"
        "from seqdex_drake import numerics\n"
        "avx512 = [t for t in __cpu_dispatch__ if t.startswith(('X86_V4', 'AVX512')) and __cpu_features__.get(t)]\n"
        "print(json.dumps({'env': {k: os.environ.get(k) for k in numerics.PINNED}, 'avx512': avx512,\n"
        "                  'status': numerics.status()}))"))
    assert report["env"] == numerics.PINNED and report["avx512"] == []
    assert report["status"].startswith("pinned")
    # numpy first: this process keeps its kernels and says so; the user's own setting is never overridden.
    late = _run("import numpy, seqdex_drake\nfrom seqdex_drake import numerics\nprint(numerics.status())")
    assert late.startswith("not pinned: numpy or torch was loaded before")
    mine = _run("import os, seqdex_drake\nprint(os.environ['OPENBLAS_CORETYPE'])", OPENBLAS_CORETYPE="Sandybridge")
    assert mine == "Sandybridge"


@pytest.mark.skipif(not PINNABLE, reason=NOT_X86)
def test_chain_inference_bits_do_not_depend_on_the_kernels_allowed():
    pinned = _run(SNAPSHOT_DIGEST)
    # The oldest OpenBLAS kernels and numpy's baseline loops only (no AVX2 dispatch): the same bits.
    oldest = _run(SNAPSHOT_DIGEST, OPENBLAS_CORETYPE="Prescott",
                  NPY_DISABLE_CPU_FEATURES=numerics.PINNED["NPY_DISABLE_CPU_FEATURES"] + " X86_V3 AVX2 FMA3")
    assert pinned == oldest


def test_exp_and_erf_from_exact_operations_are_accurate():
    x = np.linspace(-30.0, 30.0, 4001)
    reference = np.array([math.exp(v) for v in x])
    assert np.max(np.abs(exp(x) / reference - 1.0)) < 5e-16
    assert exp(np.float32([0.5])).dtype == np.float32
    low, high = exp(np.array([-800.0, 800.0]))  # Clipped to the float64 range: no overflow warnings.
    assert 0.0 <= low < 1e-320 and np.isfinite(high) and high > 1e307
    z = np.linspace(-6.0, 6.0, 2001)
    assert np.max(np.abs(erf(z) - np.array([math.erf(v) for v in z]))) < 1.6e-7  # Abramowitz & Stegun 7.1.26.


def test_matmul_is_numpys_product_without_blas():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(3, 5, 7)), rng.normal(size=(7, 4))
    stack = rng.normal(size=(3, 7, 2))
    np.testing.assert_allclose(matmul(a, b), a @ b, rtol=1e-12)
    np.testing.assert_allclose(matmul(a, stack), a @ stack, rtol=1e-12)
    np.testing.assert_allclose(matmul(a[0, 0], stack), a[0, 0] @ stack, rtol=1e-12)
