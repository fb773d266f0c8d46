#!/usr/bin/env bash
# Run a command inside the repository's .venv, creating or updating it first when needed.
#
#   bash scripts/venv.sh python scripts/simulate_chain.py
#   bash scripts/venv.sh python -m pytest
#
# Debian packages first, where missing: gcc and Python's headers (python3.X-dev) to compile the package's
# kinematics (seqdex_drake/robots/_kinematics.c), and for pytest Chromium (tests/test_browser.py) and Valgrind
# (benchmarks/env_instructions.py), with apt-get (sudo where not root: passwordless, or asked on a terminal).
# Where they cannot be installed (no apt-get, not root and no sudo, or apt-get fails), one line says what is
# missing and what that costs, and the command goes on: without a compiler the package runs without its C
# extension, on Drake's kinematics (the same results, slower). That line is not repeated while the same packages
# are missing (.venv/.seqdex-missing-packages; delete it to try again). SEQDEX_STRICT_SETUP=1 (.ci/run) makes a
# missing package or an unbuilt extension an error instead.
#
# Idempotent: the venv is rebuilt only when pyproject.toml, this script or the C source changed since the last
# install, or when a compiler came since an install without the extension; a second run installs nothing and
# prints nothing. Torch: the CPU wheel torch==2.13.0 is installed first (on these machines it is a local file);
# an unpinned request would download a multi-GB CUDA build. See README for GPU installs.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$repo/.venv"
python_bin="${SEQDEX_PYTHON:-python3.11}"
if ! command -v "$python_bin" >/dev/null 2>&1; then
  python_bin=python3
fi
stamp="$venv/.seqdex-install-stamp"  # Line 1: the hash below; line 2: the build packages missing at that install.
noted="$venv/.seqdex-missing-packages"
strict="${SEQDEX_STRICT_SETUP:-0}"
extension_glob="$repo/seqdex_drake/robots/_kinematics.*.so"
want="$(cat "$repo/pyproject.toml" "$repo/scripts/venv.sh" "$repo/seqdex_drake/robots/_kinematics.c" | sha256sum \
  | cut -d' ' -f1)"

say() { echo "[venv.sh] $*" >&2; }

# The Debian packages the C extension's build lacks for interpreter $1: its compiler and its Python.h.
build_packages_missing() {
  "$1" - <<'PY'
import os, shlex, shutil, sys, sysconfig
compiler = shlex.split(os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc")[0]
missing = [] if shutil.which(compiler) else ["gcc"]
if not os.path.exists(os.path.join(sysconfig.get_path("include"), "Python.h")):
    missing.append("python%d.%d-dev" % sys.version_info[:2])
print(" ".join(missing))
PY
}

# The test tools pytest needs that are not installed.
test_packages_missing() {
  local missing=()
  command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || missing+=(chromium)
  command -v valgrind >/dev/null 2>&1 || missing+=(valgrind)
  echo "${missing[*]}"
}

# apt-get installs "$@" where this user can; sets `why` and returns 1 where not.
apt_install() {
  local sudo="" log
  if ! command -v apt-get >/dev/null 2>&1; then why="no apt-get"; return 1; fi
  if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1 && { sudo -n true 2>/dev/null || [ -t 0 ]; }; then
      sudo="sudo"
    else
      why="not root and no sudo"; return 1
    fi
  fi
  say "installing Debian packages: $* (apt-get${sudo:+ with sudo})"
  log="$(mktemp)"
  if ! { $sudo apt-get update -qq && $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@"; } \
      >"$log" 2>&1; then
    tail -n 5 "$log" >&2
    rm -f "$log"
    why="apt-get failed"; return 1
  fi
  rm -f "$log"
}

check_python="$python_bin"
[ -x "$venv/bin/python" ] && check_python="$venv/bin/python"
stale=0
{ [ -f "$stamp" ] && [ "$(sed -n 1p "$stamp")" = "$want" ] && [ -x "$venv/bin/python" ]; } || stale=1
built=0
compgen -G "$extension_glob" >/dev/null && built=1
if [ "$stale" = 1 ]; then
  "$python_bin" - <<'PY' || { say "error: Python >= 3.11 is required (set SEQDEX_PYTHON to one)."; exit 2; }
import sys
sys.exit(0 if sys.version_info >= (3, 11) else 1)
PY
fi

# Debian packages: the build's when the package is (re)installed or its extension is missing; pytest's tools.
build_missing="" test_missing=""
if [ "$stale" = 1 ] || [ "$built" = 0 ]; then build_missing="$(build_packages_missing "$check_python")"; fi
case " $* " in *" -m pytest "* | " pytest "*) test_missing="$(test_packages_missing)" ;; esac
read -r -a needed <<<"$build_missing $test_missing"
if [ ${#needed[@]} -gt 0 ] && { [ "$strict" = 1 ] || [ "${needed[*]}" != "$(cat "$noted" 2>/dev/null)" ]; }; then
  why=""
  apt_install "${needed[@]}" || true
  if [ -n "$build_missing" ]; then build_missing="$(build_packages_missing "$check_python")"; fi
  if [ -n "$test_missing" ]; then test_missing="$(test_packages_missing)"; fi
  read -r -a needed <<<"$build_missing $test_missing"
  costs=()
  [ -z "$build_missing" ] || costs+=("without $build_missing the package runs without its C extension, on Drake's \
kinematics (the same results, slower env steps)")
  [[ " $test_missing " != *" chromium "* ]] || costs+=("without chromium tests/test_browser.py fails")
  [[ " $test_missing " != *" valgrind "* ]] || costs+=("without valgrind the env_instructions benchmark's tests \
fail (tests/test_benchmarks.py, tests/test_docs.py)")
  if [ ${#needed[@]} -gt 0 ]; then
    cost="$(printf '%s; ' "${costs[@]}")"
    say "missing Debian packages ${needed[*]} (${why:-still missing after apt-get}): ${cost%; }. Install them \
(as root: apt-get install -y ${needed[*]}) and rerun."
    if [ "$strict" = 1 ]; then say "error: SEQDEX_STRICT_SETUP=1 needs them"; exit 1; fi
    mkdir -p "$venv"
    echo "${needed[*]}" >"$noted"
  fi
fi
[ ${#needed[@]} -gt 0 ] || rm -f "$noted"
# An install without the extension is redone once the build's packages are there.
if [ "$built" = 0 ] && [ -f "$stamp" ] && [ "$build_missing" != "$(sed -n 2p "$stamp")" ]; then stale=1; fi

if [ "$stale" = 1 ]; then
  echo "[venv.sh] setting up $venv (first run, or pyproject.toml, the C source or the build's packages changed)" >&2
  [ -x "$venv/bin/python" ] || "$python_bin" -m venv "$venv"
  "$venv/bin/python" -m pip install --quiet --upgrade pip
  if ! "$venv/bin/python" -c "import torch" >/dev/null 2>&1; then
    "$venv/bin/python" -m pip install --quiet "torch==2.13.0"
  fi
  # A failed (optional) build leaves no stale extension behind: the package then runs on Drake's kinematics.
  rm -f "$repo"/seqdex_drake/robots/_kinematics.*.so
  log="$(mktemp)"  # The build backend's warnings are noise; shown only when the install fails.
  "$venv/bin/python" -m pip install --quiet -e "$repo[dev,distributed]" >"$log" 2>&1 || { cat "$log" >&2; exit 1; }
  rm -f "$log"
  if ! compgen -G "$extension_glob" >/dev/null; then
    [ -n "$build_missing" ] || say "the C extension seqdex_drake/robots/_kinematics.c did not build (see \
\`$venv/bin/python -m pip install -v -e $repo\`): the package runs on Drake's kinematics (the same results, slower)"
    if [ "$strict" = 1 ]; then say "error: SEQDEX_STRICT_SETUP=1 needs the C extension"; exit 1; fi
  fi
  printf '%s\n%s\n' "$want" "$build_missing" >"$stamp"
fi
cd "$repo"
# The same bits on every x86-64 machine with AVX2 and FMA: OpenBLAS's, numpy's, Drake's and torch's AVX2 kernels
# (seqdex_drake/numerics.py, whose PINNED these must equal: tests/test_numerics.py), a variable already set kept.
if [ "$(uname -m)" = x86_64 ] && grep -qw avx2 /proc/cpuinfo && grep -qw fma /proc/cpuinfo; then
  export OPENBLAS_CORETYPE="${OPENBLAS_CORETYPE-Haswell}"
  export NPY_DISABLE_CPU_FEATURES="${NPY_DISABLE_CPU_FEATURES-X86_V4 AVX512F AVX512CD AVX512_KNL AVX512_KNM \
AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR}"
  export DRAKE_DISABLE_CPU_FEATURES="${DRAKE_DISABLE_CPU_FEATURES-AVX512F}"
  export ATEN_CPU_CAPABILITY="${ATEN_CPU_CAPABILITY-avx2}"
fi
exec "$venv/bin/$1" "${@:2}"
