#!/usr/bin/env bash
# Installs everything bayes-brdf needs into ./.venv (idempotent; re-run is cheap).
#  - the system LLVM 19 runtime that Mitsuba's CPU variant (llvm_ad_rgb) needs
#  - torch==2.13.0 (pinned: never let pip choose a torch build)
#  - the package itself, editable, with all extras (mitsuba, docs, dev, arviz, ray)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
VENV=${VENV:-.venv}

llvm_present() {  # any one of the usual places (ls of both fails when either glob matches nothing)
  for f in /usr/lib/*/libLLVM.so.19* /usr/lib/llvm-19/lib/libLLVM*.so*; do [ -e "$f" ] && return 0; done
  return 1
}
if ! llvm_present; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "setup: installing libllvm19 (Mitsuba's llvm_ad_rgb needs it)"
    apt-get update -qq >/dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
  else
    echo "setup: warning: libLLVM 19 not found and not root; Mitsuba features will be unavailable" >&2
  fi
fi

if [ ! -x "$VENV/bin/python" ]; then
  echo "setup: creating $VENV"
  "$PY" -m venv "$VENV"
fi
stamp="$VENV/.bayes_brdf_installed"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ scripts/setup.sh -nt "$stamp" ]; then
  echo "setup: installing torch==2.13.0 and bayes-brdf[all] into $VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q "torch==2.13.0"
  "$VENV/bin/python" -m pip install -q -e ".[all]"
  touch "$stamp"
fi
echo "setup: ready ($VENV)"
