#!/usr/bin/env bash
# Set up .venv (scripts/bootstrap.sh), then run the test suite. Extra args go to pytest.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
bash scripts/bootstrap.sh
exec .venv/bin/python -m pytest tests -q "$@"
