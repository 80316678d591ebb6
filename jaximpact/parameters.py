"""The registry of scene parameters: one table of every float parameter a user can name.

A parameter's name is the one of the impacts CSV and of ``jaximpact fit --params``
(``lambda`` is ``model.lambda_``; ``radius2``, ``density2``, ``omega2`` are the ``[target]``
sphere's). :data:`PARAMETERS` gives, for each, its place in a `Scene` (section and key), its
unit and allowed range (those of :data:`jaximpact._model.ranges.RANGES`, the one table of
ranges, docs/input_ranges.md), its default prior and its transform for fitting (``None`` for
the ones no fit moves) and a line of description. The command line, the sensitivities
(``output_jacobian``), the fit's objective and the wall law's capture speed all read it, so
that each accepts the same names and puts them in the same place.

Numpy and the standard library only: the ``jaximpact`` command imports it at every start.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from ._model.ranges import RANGES, Range

__all__ = [
    "FITTABLE",
    "PARAMETERS",
    "TRANSFORMS",
    "Parameter",
    "parameter_value",
    "place",
    "unused_reason",
    "with_parameters",
]

#: Transforms of a fitted parameter to the unconstrained variable ``u`` a solver moves:
#: ``"log"`` (``u = ln p``, for a positive parameter) or ``"logit"`` (``u = logit((p - lower) /
#: (upper - lower))``, for one bounded on both sides; its start must lie strictly inside).
TRANSFORMS = ("log", "logit")


@dataclass(frozen=True)
class Parameter:
    """One scene parameter.

    Attributes:
        name: the name users give (impacts-CSV column, ``--params``, ``[priors]`` key).
        section, key: where the `Scene` holds it: ``getattr(getattr(scene, section), key)``.
        unit: SI unit (``"1"``: dimensionless), as in :data:`RANGES`.
        lower, upper: the ends of its documented range (:attr:`range` says which are allowed).
        default_prior: ``(lo, hi)`` of the default log-uniform prior of a posterior (a
            physical range, inside the allowed one; docs/posterior.md), or ``None``.
        transform: ``"log"`` or ``"logit"`` (:data:`TRANSFORMS`), how a fit moves it; ``None``
            for a parameter that is not fitted.
        description: what it is, and which scenes use it.
    """

    name: str
    section: str
    key: str
    unit: str
    lower: float
    upper: float
    default_prior: tuple[float, float] | None
    transform: str | None
    description: str

    @property
    def range(self) -> Range:
        """The documented range (``RANGES[name]``: its ends and whether each is allowed)."""
        return RANGES[self.name]

    @property
    def fittable(self) -> bool:
        """Whether a fit (or a posterior) may move it."""
        return self.transform is not None

    @property
    def field(self) -> str:
        """``section.key``, as a scene file and an error message name it (``model.lambda``)."""
        return f"{self.section}.{self.key.rstrip('_')}"

    def to_unbounded(self, p: float) -> float:
        """The solver variable ``u`` of a physical value ``p`` (a float; no range check)."""
        if self.transform == "logit":
            x = (p - self.lower) / (self.upper - self.lower)
            return math.log(x / (1 - x))
        if self.transform == "log":
            return math.log(p)
        raise ValueError(f"{self.name} is not fitted: it has no solver variable")

    def to_physical(self, u: float) -> float:
        """The physical value of a solver variable ``u`` (a float): inverse of
        :meth:`to_unbounded`."""
        if self.transform == "logit":
            return float(self.lower + (self.upper - self.lower) / (1.0 + math.exp(-u)))
        if self.transform == "log":
            return float(math.exp(u))
        raise ValueError(f"{self.name} is not fitted: it has no solver variable")


def _parameter(name, section, key, prior, transform, description) -> Parameter:
    allowed = RANGES[name]
    return Parameter(
        name, section, key, allowed.unit, allowed.lo, allowed.hi, prior, transform, description
    )


# In the order the fit's messages list them ("fittable: C_A, C_H, f0, ...").
_TABLE = (
    ("C_A", "contact", "C_A", (1e-3, 1e2), "log", "adhesion damping constant"),
    ("C_H", "contact", "C_H", (1e-3, 1e2), "log", "Hertzian damping constant"),
    ("f0", "contact", "f0", (1e-1, 1e5), "log",
     'adhesion ring line force (model.normal = "brach_dunn")'),
    ("friction", "contact", "friction", (1e-3, 1.5), "logit", "Coulomb friction coefficient"),
    ("K", "contact", "K", (1e8, 1e13), "log", "Hertz stiffness, 4 E*/3"),
    ("G_star", "contact", "G_star", (1e6, 1e12), "log",
     'effective shear modulus of the Mindlin spring (model.tangential = "mindlin")'),
    ("w", "contact", "w", (1e-4, 1e2), "log",
     'work of adhesion (model.normal = "dmt", "jkr", "thornton_ning")'),
    # metals' 0.1-10 GPa inside the default prior
    ("p_y", "contact", "p_y", (1e7, 1e11), "log",
     'limiting contact pressure (model.normal = "thornton_ning")'),
    ("k_t", "contact", "k_t", (1e0, 1e7), "log",
     'tangential stiffness of LAMMPS\'s history spring (model.tangential = '
     '"lammps_linear_history")'),
    # its unit is model.damping's (LAMMPS's eta_n0): no default prior (give one)
    ("eta_n", "contact", "eta_n", None, "log",
     'coefficient of a LAMMPS normal damping (model.damping = "velocity", "mass_velocity", '
     '"viscoelastic" or "tsuji")'),
    ("lambda", "model", "lambda_", (1e-3, 1e2), "log",
     'lambda of the constant-lambda rolling law (model.rolling_moments = "lambda")'),
    ("radius", "particle", "radius", (1e-7, 1e-1), "log", "radius of the sphere"),
    ("density", "particle", "density", (1e2, 3e4), "log", "density of the sphere"),
    # the second sphere of a sphere-sphere impact ([target]); not fitted
    ("radius2", "target", "radius", None, None, "radius of the [target] sphere"),
    ("density2", "target", "density", None, None, "density of the [target] sphere"),
    ("omega2", "target", "omega0", None, None, "spin of the [target] sphere before the impact"),
)  # fmt: skip

#: Every scene parameter, by name.
PARAMETERS: Mapping[str, Parameter] = {row[0]: _parameter(*row) for row in _TABLE}

#: The names a fit (and a posterior, and a design) may move, in the registry's order.
FITTABLE: tuple[str, ...] = tuple(n for n, p in PARAMETERS.items() if p.fittable)


def place(name: str) -> tuple[str, str]:
    """``(section, key)`` of a parameter in a `Scene` (``KeyError`` for an unknown name)."""
    p = PARAMETERS[name]
    return p.section, p.key


def with_parameters(scene, values: Mapping[str, object]):
    """``scene`` with parameters (registry names; floats, arrays or traced values) replaced;
    the scene itself where ``values`` is empty."""
    sections: dict[str, dict] = {}
    for name, value in values.items():
        section, key = place(name)
        sections.setdefault(section, {})[key] = value
    return scene.replace(**sections) if sections else scene


def unused_reason(scene, name: str) -> str | None:
    """Why ``scene`` does not use parameter ``name`` (a value given for it would change
    nothing), or None where it does: ``G_star`` without the Mindlin spring, ``w`` with the
    Brach-Dunn ring, ``f0`` with another normal law, ``p_y`` without Thornton-Ning's."""
    model = scene.model
    if name == "G_star" and model.tangential not in ("mindlin", "lammps_mindlin"):
        return (
            f'G_star is used only with model.tangential = "mindlin" or "lammps_mindlin" (the '
            f'scene has "{model.tangential}"); e.g. the embedded scene kharaz2001_mindlin'
        )
    if name == "k_t" and model.tangential != "lammps_linear_history":
        return (
            'k_t is used only with model.tangential = "lammps_linear_history" (the scene has '
            f'"{model.tangential}")'
        )
    if name == "w" and model.normal == "brach_dunn":
        return (
            'w (work of adhesion) is used only with model.normal = "dmt", "jkr" or '
            '"thornton_ning" (the scene has "brach_dunn"); the Brach-Dunn ring takes f0'
        )
    if name == "f0" and model.normal != "brach_dunn":
        return f"f0 is the Brach-Dunn ring's; the {model.normal} law takes w (work of adhesion)"
    if name == "eta_n" and model.damping == "hertzian":
        return (
            "eta_n is the coefficient of a LAMMPS normal damping (model.damping = "
            '"velocity", "mass_velocity", "viscoelastic" or "tsuji"); the scene has the '
            "Hertzian damping, which takes C_H"
        )
    if name == "C_H" and model.damping != "hertzian":
        return (
            f'C_H is the Hertzian damping; the scene has model.damping = "{model.damping}", '
            "whose coefficient is eta_n"
        )
    if name == "p_y" and model.normal != "thornton_ning":
        return (
            'p_y (limiting contact pressure) is used only with model.normal = "thornton_ning" '
            f'(the scene has "{model.normal}")'
        )
    return None


def parameter_value(scene, name: str):
    """The scene's value of a parameter, as the scene holds it (``None`` where its section is
    absent: ``radius2`` of a scene without a ``[target]``)."""
    section, key = place(name)
    holder = getattr(scene, section)
    return None if holder is None else getattr(holder, key)
