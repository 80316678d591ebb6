"""Reading the words of the ``fit`` and ``design`` options: names, ``NAME=VALUE`` items, and
the hints for a scene or data argument an option took as one of its words."""

from __future__ import annotations

__all__ = ["EMBEDDED_DATA", "split_names"]


def _parse_init(items) -> dict[str, float]:
    return parse_pairs(items, "--init", "NAME=VALUE")


def parse_pairs(items, option: str, form: str, command: str = "fit") -> dict[str, float]:
    """``{name: float}`` from ``NAME=VALUE`` words of ``option``; ``FitError`` naming the
    option and its ``form`` (with the hint for a swallowed positional argument) otherwise."""
    from .._least_squares.objective import FitError

    out = {}
    for item in items:
        name, sep, text = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[name.strip()] = float(text)
        except ValueError:
            raise FitError(
                f"{option} expects {form}, got {item!r}{_swallowed(option, item, command)}"
            ) from None
    return out


def _looks_positional(item: str) -> bool:
    """Whether a word an option took looks like a SCENE or DATA argument instead."""
    import os

    import jaximpact

    return (
        item in EMBEDDED_DATA
        or item in jaximpact.embedded_scenes()
        or item.lower().endswith((".csv", ".toml"))
        or os.path.exists(item)
    )


def _swallowed(option: str, item: str, command: str = "fit") -> str:
    """A hint for an option that took a positional argument as one of its words, or ``""``."""
    if not _looks_positional(item):
        return ""
    first = "the scene and data" if command == "fit" else "the scene"
    return (
        f" ({item!r} looks like an argument: {option} takes every word up to the next option; "
        f"give {first} before the options)"
    )


def split_names(option: str, items, allowed, command: str = "fit") -> tuple[str, ...]:
    """The names an option was given, as separate words or comma lists (``a,b c``).

    Raises:
        FitError: a name not in ``allowed``; where it looks like the scene or data argument
            (the option took every word up to the next option), the message says how to give
            them.
    """
    from .._least_squares.objective import FitError

    names = tuple(n.strip() for item in items for n in str(item).split(",") if n.strip())
    for name in names:
        if name not in allowed and _looks_positional(name):
            first, example = (
                ("the scene and data", "jaximpact fit kharaz2001 --params friction,G_star")
                if command == "fit"
                else ("the scene", "jaximpact design table1 --params C_A,f0 --candidates C.csv")
            )
            raise FitError(
                f"{option}: {name!r} is not a name of {option} but was read as one ({option} "
                f"takes every word up to the next option); give {first} before the options, "
                f"or the names as one comma list: `{example}`"
            )
    return names


def _kharaz2001():
    from .._data import kharaz2001_path

    return str(kharaz2001_path())


#: Observation data sets shipped with fitting, by name (each may have a scene of that name).
EMBEDDED_DATA = {
    "kharaz2001": _kharaz2001,
    "kharaz2001_mindlin": _kharaz2001,
    "kharaz2001_lammps": _kharaz2001,
}


def _parse_priors(items, names) -> dict:
    """``NAME=SPEC`` items -> ``{name: Prior}`` (bad input: a `FitError` naming the field)."""
    from .._bayesian.priors import parse_prior
    from .._least_squares.objective import FitError

    out = {}
    for item in items:
        name, sep, spec = item.partition("=")
        name = name.strip()
        if not sep:
            raise FitError(
                f"--prior expects NAME=loguniform:LO:HI or NAME=normal:MU:SD, got {item!r}"
                + _swallowed("--prior", item)
            )
        if name not in names:
            raise FitError(f"--prior {name}: not among the fitted --params {list(names)}")
        out[name] = parse_prior(name, spec)
    return out
