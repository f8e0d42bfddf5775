"""Command-line habits: did-you-mean, options that would be ignored, negative numbers as values.

* :class:`CovvizParser` adds a "did you mean" (difflib) to argparse's "invalid
  choice" errors (a mistyped subcommand, ``--method smacfo``), and
  :func:`unrecognized` to unknown options (``--trakers`` -> ``--trackers``),
  printed with the usage of the subcommand they were given to.
* :func:`check_ignored` refuses option combinations where one option would do
  nothing (``snapshot --offsets`` without ``--event``, ``--mds-every`` with
  ``--no-save``, ...): :data:`IGNORED` lists them, each with what to do.
* :func:`glue_negative_values` lets ``--box -5,10,40,60`` through (argparse
  takes a value starting with ``-`` for an option).
"""

from __future__ import annotations

import argparse
import difflib
import re

from covviz.cli.common import UsageError

__all__ = ["IGNORED", "NEGATIVE_VALUED", "CovvizParser", "check_ignored", "given_options", "glue_negative_values",
           "unrecognized"]

#: Options whose value may start with '-' (numbers): ``--box -5,10,40,60``, ``--offsets -5,0,5``.
NEGATIVE_VALUED = ("--box", "--offsets")

_INVALID_CHOICE = re.compile(r"invalid choice: '([^']*)' \(choose from (.*)\)")


def _close(word: str, choices) -> list[str]:
    return difflib.get_close_matches(word, list(choices), n=2, cutoff=0.6)


class CovvizParser(argparse.ArgumentParser):
    """argparse's parser, with "did you mean" on a mistyped choice (subcommands included)."""

    def error(self, message: str):
        m = _INVALID_CHOICE.search(message)
        if m:
            choices = re.findall(r"'([^']*)'", m.group(2))
            close = _close(m.group(1), choices)
            if close:
                message += f"; did you mean {' or '.join(map(repr, close))}?"
        super().error(message)


def glue_negative_values(argv: list[str]) -> list[str]:
    """``--box -5,10,40,60`` as ``--box=-5,10,40,60`` (and so for :data:`NEGATIVE_VALUED`)."""
    out: list[str] = []
    it = iter(argv)
    for a in it:
        if a in NEGATIVE_VALUED:
            nxt = next(it, None)
            if nxt is None:
                out.append(a)
            elif nxt.startswith("--"):  # another option: let argparse say the value is missing
                out += [a, nxt]
            else:
                out.append(f"{a}={nxt}")
        else:
            out.append(a)
    return out


def _option_strings(parser: argparse.ArgumentParser) -> list[str]:
    return [s for a in parser._actions for s in a.option_strings if s.startswith("--")]


def subparser(parser: argparse.ArgumentParser, command: str | None) -> argparse.ArgumentParser:
    """The parser of ``command`` (or ``parser`` itself)."""
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction) and command in a.choices:
            return a.choices[command]
    return parser


def unrecognized(parser: argparse.ArgumentParser, command: str | None, extra: list[str]):
    """argparse's "unrecognized arguments" error, from the subcommand's parser, with a did-you-mean."""
    p = subparser(parser, command)
    known = _option_strings(p)
    hints = []
    for a in extra:
        if a.startswith("--"):
            close = _close(a.partition("=")[0], known)
            if close:
                hints.append(f"{a.partition('=')[0]}: did you mean {' or '.join(close)}?")
    p.error(f"unrecognized arguments: {' '.join(extra)}" + (f" ({'; '.join(hints)})" if hints else ""))


def given_options(build_parser, argv: list[str]) -> set[str]:
    """The ``dest`` of every option the user gave on ``argv`` (not those left at their default).

    Parses ``argv`` again with a parser whose defaults are all suppressed, so
    abbreviations and ``--opt=value`` count as given exactly as argparse reads them.
    ``build_parser()`` may return a parser already used: it is changed for good
    (every default suppressed), so give one that is not parsed with again.
    """
    parser = build_parser()
    stack = [parser]
    while stack:
        p = stack.pop()
        p._defaults.clear()
        for a in p._actions:
            a.default = argparse.SUPPRESS
            if isinstance(a, argparse._SubParsersAction):
                stack.extend(a.choices.values())
    ns, _ = parser.parse_known_args(argv)
    return set(vars(ns))


def _recorded(args) -> bool:
    return not getattr(args, "no_save", False) or bool(
        getattr(args, "spawn", False) or getattr(args, "connect", None) or getattr(args, "serve_web", False)
    )


def _no_stochastic(args) -> bool:
    from covviz.trackers import STOCHASTIC
    from covviz.trackers.variants import base_name

    names = args.trackers.split(",") if isinstance(args.trackers, str) else args.trackers
    return not any(base_name(n.strip().lower()) in STOCHASTIC for n in names if n.strip())


_PARTICLES = ("--particles sets the particle count of the stochastic trackers (manifold, manifold-paper, ipca), "
              "and none of --trackers is one; drop --particles")
_JOBS = ("--jobs counts local jobs; with --cluster the cluster's workers run them (local:N sets how many); "
         "drop --jobs")
_OFFSETS = ("--offsets takes frames around an event: give --event K too ('covviz events REC.rrd' lists them), "
            "or drop --offsets")
_UNRECORDED = "{opts} would be ignored: with --no-save and no viewer there is no recording; drop {opts} or --no-save"

#: command -> (option dests, when they would be ignored (args -> bool), the one-line error).
IGNORED = {
    "snapshot": [(("offsets",), lambda a: a.event is None, _OFFSETS)],
    "track": [
        (("mds_every", "likelihood_every"), lambda a: not _recorded(a), _UNRECORDED),
        (("particles",), _no_stochastic, _PARTICLES),
    ],
    # (bench --particles with deterministic trackers only is not ignored: the manifest keeps it, and a
    # folder made with other particles is refused on resume)
    "bench": [(("jobs",), lambda a: a.cluster is not None, _JOBS)],
    "tune": [(("jobs",), lambda a: a.cluster is not None, _JOBS)],
    "mds": [
        (("png_dir",), lambda a: a.no_png, "--png-dir and --no-png contradict each other; give one"),
        (("format",), lambda a: a.no_png, "--format and --no-png contradict each other; give one"),
    ],
}


def check_ignored(args, given: set[str]) -> None:
    """Raise :class:`UsageError` when an option the user gave would be ignored (:data:`IGNORED`)."""
    for dests, ignored, message in IGNORED.get(getattr(args, "command", None), []):
        opts = [f"--{d.replace('_', '-')}" for d in dests if d in given]
        if opts and ignored(args):
            raise UsageError(message.format(opts=" and ".join(opts)))
