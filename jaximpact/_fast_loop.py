"""The lean step loop: ``simulate``'s default for concrete inputs (issue 12).

``diffrax.diffeqsolve`` runs its step loop with machinery this simulator never uses in a batch:
save buffers, dense-output buffers, a checkpointed while loop, a progress meter, the attempted
step's dense output (the 7 stages) carried through every step for the event's root find. Under
``vmap`` every piece of that state is selected, lane by lane, on every step (~500 ns per
lane-step against ~40 ns for the vector field itself, BENCHMARKS.md "Throughput").

:func:`diffeqsolve_lean` is the same integration with only what the hot case needs: an explicit
adaptive Runge-Kutta solver (``LaneTsit5``), diffrax's step-size controller, one scalar event
with a root finder (separation or capture), ``SaveAt(t1=True)``. It calls the same pieces in
the same order as ``diffrax``'s loop (``solver.init``, ``controller.init``, ``solver.step``,
``controller.adapt_step_size``, the event's sign test, ``optx.root_find`` on the solver's
dense output of the last step), so a lane gives the same arithmetic; what it leaves out is
only bookkeeping. Instead of carrying the dense output, it keeps the state and first stage
before each step and, after the loop, repeats the step that triggered the event (the same
bits) to build its interpolation.

It is forward-only (a plain ``lax.while_loop``): ``_simulate`` uses it only for concrete inputs
(and the sweep, which never differentiates), so ``jax.grad``/``jax.jacfwd`` and traced inputs
go through ``diffeqsolve``. Its outputs, step counts and failure statuses are bitwise
``diffeqsolve``'s (tests/test_throughput_paths.py, float64 and float32, both programs); it runs
1.2-1.6x as many impacts per second (BENCHMARKS.md, "Throughput (issue 12)").
"""

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import optimistix as optx
from diffrax import RESULTS
from diffrax._solution import is_okay, is_successful


class LeanSolution(eqx.Module):
    """The fields of ``diffrax.Solution`` that ``_solve_one`` reads."""

    ts: jax.Array
    ys: dict
    result: RESULTS
    stats: dict


def supported(solver, controller, event) -> bool:
    """Whether :func:`diffeqsolve_lean` handles this solve (else use ``diffeqsolve``)."""
    return (
        isinstance(solver, diffrax.AbstractAdaptiveSolver)
        and not isinstance(solver, diffrax.AbstractImplicitSolver)
        and isinstance(controller, diffrax.PIDController)
        and event is not None
        and callable(event.cond_fn)
        and event.root_finder is not None
    )


def diffeqsolve_lean(term, solver, t0, t1, dt0, y0, args, *, event, stepsize_controller, max_steps):
    """One solve (one lane; ``vmap`` it), as ``diffrax.diffeqsolve(..., throw=False)``."""
    dtype = jnp.result_type(*jax.tree_util.tree_leaves(y0))
    t0, t1, dt0 = (jnp.asarray(x, dtype) for x in (t0, t1, dt0))
    controller = stepsize_controller
    cond_fn = event.cond_fn
    error_order = solver.error_order(term)
    t1_clip_floor = t1
    for _ in range(100):
        t1_clip_floor = eqxi.prevbefore(t1_clip_floor)

    tnext, controller_state = controller.init(term, t0, t1, y0, dt0, args, solver.func, error_order)
    tnext = jnp.minimum(tnext, t1)
    solver_state = solver.init(term, t0, tnext, y0, args)
    value0 = cond_fn(t0, y0, args)
    init = dict(
        tprev=t0,
        tnext=tnext,
        y=y0,
        solver_state=solver_state,
        controller_state=controller_state,
        num_steps=jnp.zeros((), jnp.int32),
        result=RESULTS.where(jnp.zeros((), bool), RESULTS.successful, RESULTS.successful),
        event=jnp.zeros((), bool),
        value=value0,
        # the last attempted step, to repeat it after the loop
        ev_tprev=t0,
        ev_tnext=t0,
        ev_y=y0,
        ev_state=solver_state,
    )

    def running(s):  # diffrax's cond_fun
        return (s["tprev"] < t1) & is_successful(s["result"])

    def cond(s):
        return running(s) & (s["num_steps"] < max_steps)

    def body(s):
        y1, y_error, _, new_state, step_result = solver.step(
            term, s["tprev"], s["tnext"], s["y"], args, s["solver_state"], False
        )
        y_error = jax.tree_util.tree_map(lambda x: jnp.where(jnp.isnan(x), jnp.inf, x), y_error)
        keep, tprev, tnext, _, controller_state, ctrl_result = controller.adapt_step_size(
            s["tprev"], s["tnext"], s["y"], y1, args, y_error, error_order, s["controller_state"]
        )
        tprev = jnp.minimum(tprev, t1)
        clip = tnext > t1_clip_floor
        tnext = jnp.where(clip, jnp.where(keep, t1, tprev + 0.5 * (t1 - tprev)), tnext)
        select = lambda a, b: jax.tree_util.tree_map(  # noqa: E731
            lambda u, v: jnp.where(keep, u, v), a, b
        )
        y = select(y1, s["y"])
        solver_state = select(new_state, s["solver_state"])  # any solver's state pytree
        result = RESULTS.where(keep, step_result, RESULTS.successful)
        result = RESULTS.where(is_okay(s["result"]), result, s["result"])
        result = RESULTS.where(is_okay(result), ctrl_result, result)
        value = cond_fn(tprev, y, args)
        event = (jnp.sign(s["value"]) > 0) & (jnp.sign(value) <= 0)
        result = RESULTS.where(event, RESULTS.event_occurred, result)
        return dict(
            tprev=tprev,
            tnext=tnext,
            y=y,
            solver_state=solver_state,
            controller_state=controller_state,
            num_steps=s["num_steps"] + 1,
            result=result,
            event=event,
            value=value,
            ev_tprev=s["tprev"],
            ev_tnext=s["tnext"],
            ev_y=s["y"],
            ev_state=s["solver_state"],
        )

    s = jax.lax.while_loop(cond, body, init)
    result = s["result"]
    happened = s["event"]

    def root_find():
        _, _, dense_info, _, _ = solver.step(
            term, s["ev_tprev"], s["ev_tnext"], s["ev_y"], args, s["ev_state"], False
        )
        interp = solver.interpolation_cls(t0=s["ev_tprev"], t1=s["ev_tnext"], **dense_info)

        def fn(t, _):
            value = jax.lax.cond(
                happened, lambda: cond_fn(t, interp.evaluate(t), args), lambda: 0.0
            )
            return jnp.where(happened, value, s["ev_tnext"] - t)

        sol = optx.root_find(
            fn,
            event.root_finder,
            y0=s["ev_tnext"],
            options=dict(lower=s["ev_tprev"], upper=s["ev_tnext"]),
            throw=False,
        )
        y = jax.lax.cond(s["num_steps"] == 0, lambda: s["y"], lambda: interp.evaluate(sol.value))
        ok = sol.result == optx.RESULTS.successful
        return sol.value, y, RESULTS.where(ok, result, RESULTS.promote(sol.result))

    tfinal, yfinal, result = jax.lax.cond(
        eqxi.unvmap_any(happened), root_find, lambda: (s["tprev"], s["y"], result)
    )
    result = RESULTS.where(running(s), RESULTS.max_steps_reached, result)
    return LeanSolution(
        ts=tfinal[None],
        ys=jax.tree_util.tree_map(lambda x: x[None], yfinal),
        result=result,
        stats={"num_steps": s["num_steps"]},
    )
