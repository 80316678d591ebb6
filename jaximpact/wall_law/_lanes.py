"""The impacts of :func:`capture_speed`'s search, each lane on one solver throughout
(:class:`_Lanes`)."""

import jax
import jax.numpy as jnp
import numpy as np

from ..parameters import with_parameters

# The solvers of ``method = "auto"`` (``_engine.settings.integration_settings``).
IMPLICIT_METHOD, EXPLICIT_METHOD = "kvaerno5", "tsit5"


def _settings_stiff(scene, dtype) -> bool:
    """The part of the engine's ``auto`` rule that the settings alone decide
    (``integration_settings``): a slip width below 30 rtol takes the implicit solver."""
    from .._engine.solvers import default_slip_width, default_tolerances

    rtol, _ = default_tolerances(dtype, scene.solver.rtol, scene.solver.atol)
    return default_slip_width(dtype, scene.solver.slip_width, rtol) < 30 * rtol


@jax.jit
def _lane_stiffness(params, speed, angle):
    """The engine's stiffness estimate of each lane (``stiffness_estimate``, per lane)."""
    from .._engine.settings import stiffness_estimate

    return jax.vmap(stiffness_estimate)(params, speed, angle)


class _Lanes:
    """The search's impacts, each lane on one solver throughout its search.

    With ``solver.method = "auto"`` the engine picks the solver per call, for the whole batch,
    from the stiffness of the impacts at hand; a search calls it at speeds spread over six
    decades, so a lane's solver changed from one call to the next with its speed and with the
    other lanes' (and the implicit one, near a lane's capture speed, put the threshold
    elsewhere). Here each lane's solver is chosen once, by the engine's own rule
    (``integration_settings``: the settings, then the stiffness estimate against
    ``solver.stiffness_limit``) applied to the lane alone at the lowest and the highest speed
    of its scan (the estimate grows or falls monotonically with the speed): implicit if either
    is judged stiff. A lane whose impact still reaches ``max_steps`` on its solver moves to
    the other one for the rest of its search (once), that impact run again (``retried``): the
    estimate is an estimate (2 of 200 random Brach-Dunn scenes reached it on Tsit5), and
    Kvaerno5 reached it on every impact of some overdamped JKR scenes that Tsit5 captures in
    at most 77 steps (4 of 200). Each solver's lanes run as one batch, padded to a power
    of two lanes so that a move seldom compiles a new program. Other methods than ``auto``:
    every lane on the scene's method, as before."""

    def __init__(self, simulate, scene, params, angle, omega, grid):
        self.simulate, self.scene, self.params = simulate, scene, params
        self.angle, self.omega = angle, omega
        n = angle.size
        self.retried = np.zeros(n, bool)
        if scene.solver.method != "auto":
            self.method = np.full(n, None, dtype=object)
            return
        dtype = jnp.result_type(float)
        lanes = {k: jnp.asarray(v, dtype) for k, v in params.items()}
        stiff = np.full(n, _settings_stiff(scene, dtype))
        for k in (0, -1):  # each lane's stiffness at each end of its scan
            rate = _lane_stiffness(lanes, jnp.asarray(grid[:, k], dtype), jnp.asarray(angle, dtype))
            stiff |= np.asarray(rate) > scene.solver.stiffness_limit
        self.method = np.where(stiff, IMPLICIT_METHOD, EXPLICIT_METHOD).astype(object)

    def _run_group(self, method, lanes, v):
        """Statuses and ``vn_out`` of ``lanes`` at speeds ``v`` (all lanes' speeds)."""
        size = 1 << max(1, int(lanes.size - 1).bit_length())  # a power of two, >= 2
        pad = np.concatenate([lanes, np.full(size - lanes.size, lanes[-1])])
        sub = with_parameters(self.scene, {k: x[pad] for k, x in self.params.items()})
        res = self.simulate(sub, v[pad], self.angle[pad], self.omega[pad], method=method)
        return np.asarray(res.status)[: lanes.size], np.asarray(res.vn_out)[: lanes.size]

    def run(self, v):
        """``(status, q)`` of every lane at its speed ``v``: ``q = vn_out^2`` of a rebound
        (the secant works on the energies: nearly linear near v_c, where the adhesive loss
        hardly changes with the speed), NaN otherwise."""
        n = v.size
        st, vn = np.empty(n, int), np.full(n, np.nan)
        todo = np.ones(n, bool)
        while todo.any():
            for method in dict.fromkeys(self.method[todo]):
                lanes = np.flatnonzero(todo & (self.method == method))
                st[lanes], vn[lanes] = self._run_group(method, lanes, v)
            todo[:] = False
            if self.scene.solver.method == "auto":
                stuck = ~self.retried & (st == 2)  # Status.MAX_STEPS, on the lane's first solver
                self.method[stuck] = np.where(
                    self.method[stuck] == IMPLICIT_METHOD, EXPLICIT_METHOD, IMPLICIT_METHOD
                )
                self.retried |= stuck
                todo = stuck
        return st, np.where(st == 0, vn**2, np.nan)
