#!/bin/sh
# Creates .venv with bpy 5.0.1 (Python 3.11), numba, xatlas and the test tools,
# and makes this checkout importable as the package `photon_lightmaps`.
set -eu
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3.11}
command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python3
"$PYTHON" -c 'import sys; assert sys.version_info[:2] == (3, 11), "bpy 5.0.1 needs Python 3.11, found %s" % sys.version.split()[0]'
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -r requirements.txt
site=$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
# The repository root *is* the add-on package: link it under its extension id.
ln -sfn "$(pwd)" "$site/photon_lightmaps"
touch .venv/.stamp
