#!/usr/bin/env bash
# Install what the tests need and run them: Debian's Chromium for the browser tests (never a
# downloaded browser), a virtualenv with the project and its test extras, then ruff and pytest.
# Idempotent: a second run installs nothing new. Extra arguments go to pytest. The tests run in one worker
# process per core (pytest-xdist, at most four): most are CPU-bound on simulated time, and none shares a
# port, a file or a browser with another; TEST_WORKERS=0 runs them in this process instead.
set -euo pipefail
cd "$(dirname "$0")/.."

if [ ! -x /usr/bin/chromium ]; then
  if [ "$(id -u)" -eq 0 ]; then
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
  elif command -v sudo >/dev/null; then
    sudo apt-get update -qq
    sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
  else
    echo "warning: /usr/bin/chromium is missing and cannot be installed; browser tests will fail" >&2
  fi
fi

python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[test]'
.venv/bin/ruff check .
exec .venv/bin/python -m pytest -n "${TEST_WORKERS:-auto}" --maxprocesses 4 "$@"
