#!/usr/bin/env bash
# Installs poevp_optics into .venv on a fresh Debian machine.
#  1. Debian's libllvm19 (Mitsuba's llvm_* variants crash with libLLVM 14/15:
#     "Cannot select ... fminimum"); installed with apt when missing and we are root.
#     Debian's chromium likewise (the headless report.html test).
#  2. torch==2.13.0 CPU build first, so nothing pulls the CUDA wheels.
#  3. the package itself (editable) with its test extras.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if ! ls /usr/lib/x86_64-linux-gnu/libLLVM.so.19* >/dev/null 2>&1 && ! ldconfig -p 2>/dev/null | grep -q 'libLLVM.so.19'; then
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
        echo "setup: installing Debian libllvm19 for Mitsuba's llvm variants"
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
    else
        echo "setup: WARNING libllvm19 missing and cannot apt-get (not root): Mitsuba falls back to scalar_spectral" >&2
    fi
fi
if ! command -v chromium >/dev/null 2>&1; then     # tests/unit/test_report_html.py opens report.html headless
    if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
        echo "setup: installing Debian chromium for the report.html test"
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
    else
        echo "setup: WARNING chromium missing and cannot apt-get (not root): the report.html browser test is skipped" >&2
    fi
fi
if [ ! -x .venv/bin/python ]; then
    "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
if ! .venv/bin/python -c "import torch, sys; sys.exit(0 if torch.__version__.startswith('2.13.0') else 1)" 2>/dev/null; then
    .venv/bin/python -m pip install -q "torch==2.13.0"
fi
# setuptools' editable build says "Editable installation ... be careful with folders named like your
# package" (an InformationOnly, a UserWarning) on every install: not ours to act on, so not printed.
PYTHONWARNINGS="ignore::UserWarning" .venv/bin/python -m pip install -q -e ".[test]"
.venv/bin/poevp info --short
