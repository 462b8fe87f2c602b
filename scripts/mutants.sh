#!/usr/bin/env bash
# Mutation testing of the modules where a silent bug is dangerous (issue 14): mutmut on each module with a
# fast, relevant subset of the tests, in scratch copies under out/mutants/, then a table of scores and the
# surviving mutants (their diffs in out/mutants/MODULE/survivors.txt). About half an hour on 2 cores.
# Not part of CI (CI runs the tests); mutmut comes with the dev extra: pip install -e '.[test,dev]'.
# Usage: ./scripts/mutants.sh [MODULE ...] [--jobs N] [--report]   (modules: scripts/mutants.py --help)
# PYTHON=/path/to/python picks the interpreter (default: .venv/bin/python of this checkout).
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-.venv/bin/python}
if [ ! -x "$PYTHON" ]; then
  python3 -m venv .venv
  PYTHON=.venv/bin/python
  "$PYTHON" -m pip install -q --upgrade pip
  "$PYTHON" -m pip install -q -e '.[test,dev]'
fi
"$PYTHON" -c 'import mutmut' 2>/dev/null || "$PYTHON" -m pip install -q 'mutmut>=3.8'
exec "$PYTHON" scripts/mutants.py "$@"
