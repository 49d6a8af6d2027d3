"""Silences Blender's per-bake and per-render console lines (written to fd 1 from C)."""
import contextlib
import os
import sys


@contextlib.contextmanager
def quiet():
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)
