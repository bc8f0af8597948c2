#!/usr/bin/env bash
# Create/refresh the project virtual environment in .venv (idempotent).
# Re-installs only when pyproject.toml changed since the last successful install.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

VENV=.venv
STAMP="$VENV/.usdbtf-bootstrap.sha256"
PY="$VENV/bin/python"

if [ ! -x "$PY" ] || ! "$PY" -m pip --version >/dev/null 2>&1; then
    echo "bootstrap: creating $VENV" >&2
    rm -rf "$VENV"
    python3 -m venv "$VENV"
    rm -f "$STAMP"
fi

want="$(sha256sum pyproject.toml | cut -d' ' -f1)"
have="$(cat "$STAMP" 2>/dev/null || true)"
if [ "$want" = "$have" ]; then
    exit 0
fi

echo "bootstrap: installing usdbtf and dependencies into $VENV (first run downloads wheels)" >&2
"$PY" -m pip install --quiet --disable-pip-version-check --upgrade pip
"$PY" -m pip install --quiet --disable-pip-version-check -e '.[test]'
echo "$want" > "$STAMP"
echo "bootstrap: done" >&2
