"""Command line for the bpy-module world: `python -m photon_lightmaps {demo,render,bake,bake-ol}`.

Each command lives with the code it drives: `render` in headless.py, `bake`
in bake.py, `bake-ol` in ol_bake.py, `demo` in demo.py; this module parses
arguments (so `--help` works without importing Blender) and turns whatever a
command raises into what the user sees (messages.py): a user error is one
line "error: <culprit>: <what to do>" and exit code 2, a bug is one line
"error: internal error: ..." and exit code 1; `--debug` adds the traceback.
"""
import argparse
import importlib
import sys


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        # argparse prints usage plus "prog: error: argument --x: ..."; the user gets one line.
        if message.startswith("argument "):
            message = message[len("argument "):]
        sys.stderr.write(f"error: {message} (see {self.prog} --help)\n")
        sys.exit(2)


def _count(least, most=2 ** 31 - 1):
    # Blender's IntProperty holds 32 bits: a larger value would fail only after the file is loaded.
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not least <= value <= most:
            raise argparse.ArgumentTypeError(f"must be a whole number from {least} to {most:,}, got '{text}'")
        return value
    parse.__name__ = f"count >= {least}"
    return parse


def _add_common(p):
    p.add_argument("--photons", type=_count(0), default=None, help="photons to shoot (default: scene setting)")
    p.add_argument("--seed", type=_count(0), default=None, help="random seed (default: scene setting)")
    p.add_argument("--json", metavar="REPORT", default=None, help="write a JSON report here")
    # Also accepted after the command; SUPPRESS keeps a global --debug from being reset.
    p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)


def build_parser():
    p = _Parser(
        prog="python -m photon_lightmaps",
        description="Photon Lightmaps: lightmap-based photon tracing (Wilkie 2001) for Blender files.")
    p.add_argument("--debug", action="store_true",
                   help="print the traceback of an error (for bug reports)")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    d = sub.add_parser("demo", help="render and bake the built-in demo scene")
    d.add_argument("--out", default="out/demo", help="output folder")
    _add_common(d)
    d.add_argument("--samples", type=_count(1), default=None)
    d.set_defaults(module="demo", func="demo_main")

    r = sub.add_parser("render", help="render a .blend with the Photon Lightmaps engine")
    r.add_argument("blend", metavar="FILE.blend")
    r.add_argument("--out", required=True, metavar="IMG", help="output image (.png or .exr)")
    _add_common(r)
    r.add_argument("--samples", type=_count(1), default=None, help="pixel samples")
    r.set_defaults(module="headless", func="render_main")

    b = sub.add_parser("bake", help="bake photon lightmaps of a .blend to OpenEXR images")
    b.add_argument("blend", metavar="FILE.blend")
    b.add_argument("--out", required=True, metavar="DIR", help="folder for <object name>.exr")
    _add_common(b)
    b.add_argument("--resolution", type=_count(1), default=None, metavar="R", help="force R x R lightmaps")
    b.add_argument("--indirect-only", action="store_true", help="leave direct light out of the maps")
    b.set_defaults(module="bake", func="bake_main")

    o = sub.add_parser("bake-ol", help="bake the orientation lightmaps of a .blend to OpenEXR images")
    o.add_argument("blend", metavar="FILE.blend")
    o.add_argument("--out", required=True, metavar="DIR", help="folder for <empty name>.exr")
    _add_common(o)
    o.set_defaults(module="ol_bake", func="ol_bake_main")
    return p


class _LineTracker:
    """sys.stderr that remembers whether its last write ended a line (progress uses "\\r")."""

    def __init__(self, stream):
        self._stream = stream
        self.at_line_start = True

    def write(self, s):
        if s:
            self.at_line_start = s.endswith("\n")
        return self._stream.write(s)

    def __getattr__(self, name):
        return getattr(self._stream, name)


def main(argv=None):
    args = build_parser().parse_args(argv)
    stderr = sys.stderr
    sys.stderr = tracker = _LineTracker(stderr)
    try:
        module = importlib.import_module(f"{__package__}.{args.module}")
        return getattr(module, args.func)(args)
    except Exception as exc:  # noqa: BLE001  (the one place a command's failure reaches the user)
        from .messages import describe, is_user_error
        user = is_user_error(exc)
        if not tracker.at_line_start:
            stderr.write("\n")
        if args.debug:
            import traceback
            traceback.print_exception(exc, file=stderr)
        hint = "" if user or args.debug else " (rerun with --debug for the traceback)"
        stderr.write(f"error: {describe(exc)}{hint}\n")
        stderr.flush()
        return 2 if user else 1
    finally:
        sys.stderr = stderr


if __name__ == "__main__":
    sys.exit(main())
