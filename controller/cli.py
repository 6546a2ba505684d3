"""The ``valvectl`` command line (DESIGN.md, Command line).

Each verb lives in ``controller/commands/<verb>.py`` with ``add_arguments(parser)``
and ``run(args) -> int``; those modules import their heavy dependencies inside
``run`` so that ``--help`` stays fast. Bad input anywhere raises
:class:`models.recording.InputError`, printed here as one line, exit 2.
"""
from __future__ import annotations

import os

# One BLAS thread, set before numpy loads: on a 2-core controller host, OpenBLAS's spinning
# threads compete with the 1 kHz loop, and the many tiny LAPACK calls of a fit (e.g. the
# Everett mesh's 5000 barycentric transforms: 15 ms on one thread, seconds on a busy two)
# only lose by threading.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import importlib  # noqa: E402
import sys  # noqa: E402

#: verb -> (module, one-line help)
VERBS = {
    "fit": ("controller.commands.fit", "fit one hysteresis model to a recording"),
    "compare": ("controller.commands.compare", "paper Table 1 on a recording, plus the inverse PI check"),
    "simulate": ("controller.commands.simulate", "make a recording from the simulated valve"),
    "run": ("controller.commands.run", "a closed-loop run"),
    "valve-node": ("controller.commands.valve_node", "the simulated valve as a Zenoh node"),
    "sweep": ("controller.commands.sweep", "a controller tuning sweep"),
    "diagnose": ("controller.commands.diagnose", "find the physics a simulation leaves out"),
    "monitor": ("controller.commands.monitor", "live view of a running controller over Zenoh"),
    "certs": ("controller.commands.certs", "a site CA and one certificate per role, for --certs"),
    "identify": ("controller.commands.identify", "characterize a valve over Zenoh and write a run configuration for it"),
}


#: The arguments being parsed (for the parsers' error messages).
_ARGV: list[str] = []


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit 2), as DESIGN.md asks of bad input; a misspelt flag is named
    rather than the required arguments it hid."""

    def _unknown_options(self) -> list[str]:
        verb = self.prog.split()[-1]
        args = _ARGV[_ARGV.index(verb) + 1:] if verb in _ARGV else _ARGV
        known = list(self._option_string_actions)
        out = []
        for a in args:
            if a == "--":
                break
            flag = a.split("=", 1)[0]
            if not flag.startswith("-") or flag == "-" or _is_number(flag):
                continue
            if not any(k.startswith(flag) for k in known):  # argparse takes unambiguous abbreviations
                out.append(flag)
        return out

    def error(self, message):
        if message.startswith("the following arguments are required"):  # argparse checks these before it
            unknown = self._unknown_options()                            # looks at flags it does not know
            if unknown:
                message = f"unrecognized arguments: {' '.join(unknown)}"
        message = message.replace("\r", "\\r").replace("\n", "\\n")
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="valvectl",
        description="Flow control for a ventilator's proportional solenoid valve: identify its "
        "hysteresis, run the feedforward + feedback loop, sweep tunings, diagnose model mismatch.",
    )
    sub = parser.add_subparsers(dest="verb", metavar="VERB", parser_class=_Parser)
    sub.required = True
    for verb, (modname, help_) in VERBS.items():
        try:
            mod = importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name != modname:
                raise
            continue  # verb not built yet
        p = sub.add_parser(verb, help=help_, description=(mod.__doc__ or help_).strip().splitlines()[0])
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run, _parser=p)
    return parser


#: The checkout this valvectl runs from (its config/ holds the default configurations).
CHECKOUT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def resolve_default_paths(args) -> None:
    """Every verb's default configuration paths (``config/...``), resolved one way: the working
    directory's when it has the file, else this checkout's. Paths given on the command line stay as given."""
    for action in args._parser._actions:
        d = action.default
        if (isinstance(d, str) and d.startswith("config/") and getattr(args, action.dest, None) == d
                and not os.path.exists(d)):
            setattr(args, action.dest, os.path.join(CHECKOUT, d))


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    _ARGV[:] = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(argv)
    resolve_default_paths(args)
    # imported after parsing: it brings numpy, which --help and usage errors never need
    from models.recording import InputError

    try:
        return int(args._run(args) or 0)
    except InputError as exc:
        # one line, whatever the input held (a file name or a cell with a line break in it)
        text = str(exc).replace("\r", "\\r").replace("\n", "\\n")
        sys.stderr.write(f"valvectl {args.verb}: error: {text}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write(f"valvectl {args.verb}: interrupted\n")
        return 130
    except BrokenPipeError:  # the reader of our output went away (`| head`): nothing left to say
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
