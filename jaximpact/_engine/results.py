"""Impact results: status codes and the result record (fields named like the results CSV)."""

import equinox as eqx
import jax
import numpy as np

from .._io.columns import RESULT_COLUMNS, TEXT_RESULT_COLUMNS


class Status:
    """Integer status codes of an impact. ``failed`` covers every code >= 2."""

    REBOUND = 0
    CAPTURED = 1
    MAX_STEPS = 2  # step limit reached (often: a stiff scene on an explicit solver)
    NONFINITE = 3  # the state became NaN or infinite
    SOLVER_ERROR = 4  # any other solver failure
    INVALID_INPUT = 5  # a traced input outside its range (docs/input_ranges.md): not solved

    NAMES = {
        0: "rebound",
        1: "captured",
        2: "max_steps",
        3: "nonfinite",
        4: "solver_error",
        5: "invalid_input",
    }

    @staticmethod
    def csv_name(code) -> str:
        """``rebound``, ``captured`` or ``failed`` (the results-CSV vocabulary)."""
        return {0: "rebound", 1: "captured"}.get(int(code), "failed")


# The numeric results-CSV columns, each a field of ImpactResult.
OUTPUT_FIELDS = tuple(c for c in RESULT_COLUMNS if c not in TEXT_RESULT_COLUMNS)


class ImpactResult(eqx.Module):
    """Result of ``simulate``: one entry per impact (scalars for a scalar call).

    Units SI. ``status`` holds ``Status`` codes. ``vn_out`` is the normal rebound speed (away
    from the surface), ``cor_n = vn_out / v_n``, ``cor_t = vt_out / v_t`` (NaN when
    ``v_t = 0``), ``rebound_angle_deg`` is the angle of the centre-of-mass velocity from the
    normal. ``contact_time`` is the time to separation (rebound) or to the moment capture is
    certain (captured). ``roll_time`` is the time at which the slip first falls to zero (NaN if
    it never does). For a captured impact ``vn_out = cor_n = 0`` and ``rebound_angle_deg`` is
    NaN; ``vt_out`` and ``omega_out`` are the values when capture was declared. A failed impact
    has NaN outputs. The energy ledger (J): ``energy_in - energy_out`` equals the sum of the
    four losses (five with Thornton-Ning's ``loss_plastic``). ``steps`` counts accepted and
    rejected solver steps.
    """

    status: jax.Array
    vn_out: jax.Array
    vt_out: jax.Array
    omega_out: jax.Array
    cor_n: jax.Array
    cor_t: jax.Array
    rebound_angle_deg: jax.Array
    contact_time: jax.Array
    roll_time: jax.Array
    max_overlap: jax.Array
    energy_in: jax.Array
    energy_out: jax.Array
    loss_hertz_damping: jax.Array
    loss_adhesion_damping: jax.Array
    loss_friction: jax.Array
    loss_rolling: jax.Array
    steps: jax.Array
    # With model.tangential = "mindlin": the part of energy_out held by the tangential spring
    # (0 after a rebound: the spring has given its energy back by separation); else None.
    energy_tangential: jax.Array | None = None
    # With a [target] sphere (and rotation): its spin at the end (rad/s, signed as omega2 in
    # the scene); else None.
    omega2_out: jax.Array | None = None
    # With model.normal = "thornton_ning": the energy yield took (J), a fifth loss of the
    # ledger; else None.
    loss_plastic: jax.Array | None = None

    @property
    def status_names(self) -> np.ndarray:
        """Status of each impact as a string: rebound, captured or the failure reason."""
        codes = np.asarray(self.status)
        return np.vectorize(lambda c: Status.NAMES[int(c)], otypes=[object])(codes)

    @property
    def failure_reasons(self) -> np.ndarray:
        """Why each impact failed (``max_steps``, ``nonfinite``, ``solver_error``,
        ``invalid_input``), else ``""``."""
        codes = np.asarray(self.status)
        name = lambda c: Status.NAMES[int(c)] if c >= Status.MAX_STEPS else ""  # noqa: E731
        return np.vectorize(name, otypes=[object])(codes)

    @property
    def failed(self):
        return self.status >= Status.MAX_STEPS

    def columns(self) -> dict:
        """The results-CSV columns as numpy arrays (``status`` as rebound/captured/failed)."""
        out = {"status": np.vectorize(Status.csv_name, otypes=[object])(np.asarray(self.status))}
        for name in OUTPUT_FIELDS:
            out[name] = np.asarray(getattr(self, name), dtype=float)
        out["failure_reason"] = self.failure_reasons
        return out
