"""The lean step loop: ``simulate``'s one engine for values and derivatives.

The integration of ``diffrax.diffeqsolve`` with only what a batch of impacts needs (one
plain ``lax.while_loop``, the same arithmetic); design notes in docs/engine.md."""

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np
from diffrax import RESULTS
from diffrax._solution import is_okay, is_successful

from . import event as _event


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


def lane_functions(
    term, solver, t0, t1, dt0, y0, *, event, stepsize_controller, max_steps, keep_dense=False
):
    """The pieces of one lane's solve: ``init(y0, args) -> state``, ``running(state)``,
    ``step(state, args) -> state`` and ``finish(state, args) -> LeanSolution``, called in
    that order they are :func:`diffeqsolve_lean`; :func:`solve_pool` calls them on lanes
    that change impacts. ``y0``: an initial state (or a batch of them), for its float type.

    ``keep_dense``: the state keeps the last step's dense output (its stages), from which
    ``finish`` locates the event; else it keeps the step's inputs and ``finish`` takes that
    step again (see :func:`diffeqsolve_lean` for which is used where)."""
    lane = _Lane(term, solver, t0, t1, dt0, y0, event, stepsize_controller, max_steps)
    lane.keep_dense = keep_dense
    return lane.init, lane.running, lane.step, lane.finish


class _Lane:
    """One lane's solve in pieces (:func:`lane_functions`); the state is a dict."""

    def __init__(self, term, solver, t0, t1, dt0, y0, event, stepsize_controller, max_steps):
        dtype = jnp.result_type(*jax.tree_util.tree_leaves(y0))
        # diffrax's clip of the last step to t1 (a constant here: t1 is a Python number)
        t1_clip_floor = np.asarray(t1, dtype)
        for _ in range(100):
            t1_clip_floor = np.nextafter(t1_clip_floor, np.asarray(-np.inf, dtype))
        self.t1_clip_floor = t1_clip_floor
        self.t0, self.t1, self.dt0 = (jnp.asarray(x, dtype) for x in (t0, t1, dt0))
        self.term, self.solver, self.event, self.max_steps = term, solver, event, max_steps
        self.controller = stepsize_controller
        self.cond_fn = event.cond_fn
        self.error_order = solver.error_order(term)

    def init(self, y0, args):
        term, solver, t0, t1 = self.term, self.solver, self.t0, self.t1
        tnext, controller_state = self.controller.init(
            term, t0, t1, y0, self.dt0, args, solver.func, self.error_order
        )
        tnext = jnp.minimum(tnext, t1)
        solver_state = solver.init(term, t0, tnext, y0, args)
        return dict(
            tprev=t0,
            tnext=tnext,
            y=y0,
            solver_state=solver_state,
            controller_state=controller_state,
            num_steps=jnp.zeros((), jnp.int32),
            result=RESULTS.where(jnp.zeros((), bool), RESULTS.successful, RESULTS.successful),
            event=jnp.zeros((), bool),
            value=self.cond_fn(t0, y0, args),
            # the last attempted step: its dense output, or its inputs to repeat it in finish
            ev_tprev=t0,
            ev_tnext=t0,
            **(
                dict(ev_dense=self._no_dense(y0, args, solver_state))
                if self.keep_dense
                else dict(ev_y=y0, ev_state=solver_state)
            ),
        )

    def _no_dense(self, y0, args, solver_state):
        """Zeros shaped as a step's dense output (the state's entry before the first step)."""
        if hasattr(self.solver, "empty_dense_info"):
            return self.solver.empty_dense_info(y0)
        shapes = jax.eval_shape(
            lambda y, a, st: self.solver.step(self.term, self.t0, self.t0, y, a, st, False)[2],
            y0, args, solver_state,
        )  # fmt: skip
        return jax.tree_util.tree_map(lambda x: jnp.zeros(x.shape, x.dtype), shapes)

    def unfinished(self, s):  # diffrax's cond_fun
        return (s["tprev"] < self.t1) & is_successful(s["result"])

    def running(self, s):
        return self.unfinished(s) & (s["num_steps"] < self.max_steps)

    def step(self, s, args):
        t1 = self.t1
        y1, y_error, dense, new_state, step_result = self.solver.step(
            self.term, s["tprev"], s["tnext"], s["y"], args, s["solver_state"], False
        )
        y_error = jax.tree_util.tree_map(lambda x: jnp.where(jnp.isnan(x), jnp.inf, x), y_error)
        keep, tprev, tnext, _, controller_state, ctrl_result = self.controller.adapt_step_size(
            s["tprev"], s["tnext"], s["y"], y1, args, y_error, self.error_order,
            s["controller_state"],
        )  # fmt: skip
        tprev = jnp.minimum(tprev, t1)
        clip = tnext > self.t1_clip_floor
        tnext = jnp.where(clip, jnp.where(keep, t1, tprev + 0.5 * (t1 - tprev)), tnext)
        select = lambda a, b: jax.tree_util.tree_map(  # noqa: E731
            lambda u, v: jnp.where(keep, u, v), a, b
        )
        y = select(y1, s["y"])
        solver_state = select(new_state, s["solver_state"])  # any solver's state pytree
        result = RESULTS.where(keep, step_result, RESULTS.successful)
        result = RESULTS.where(is_okay(s["result"]), result, s["result"])
        result = RESULTS.where(is_okay(result), ctrl_result, result)
        value = self.cond_fn(tprev, y, args)
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
            **(
                dict(ev_dense=dense)
                if self.keep_dense
                else dict(ev_y=s["y"], ev_state=s["solver_state"])
            ),
        )

    def finish(self, s, args):
        result = s["result"]
        happened = s["event"]

        def located():  # a lane without an event ends where its loop did, whatever its batch
            t_event, y_event, result_event = self.root_find(s, args, result, happened)
            return (
                jnp.where(happened, t_event, s["tprev"]),
                jax.tree_util.tree_map(lambda a, b: jnp.where(happened, a, b), y_event, s["y"]),
                RESULTS.where(happened, result_event, result),
            )

        if self.keep_dense:  # a cheap root find (no step): no cond, which JAX would trace
            tfinal, yfinal, result = located()  # three times over under a derivative
        else:  # only where some lane had an event: without the cond the unrolled program,
            # whose root find takes the last step again, compiled 1-3 s slower (measured)
            tfinal, yfinal, result = jax.lax.cond(
                eqxi.unvmap_any(happened), located, lambda: (s["tprev"], s["y"], result)
            )
        result = RESULTS.where(self.unfinished(s), RESULTS.max_steps_reached, result)
        return LeanSolution(
            ts=tfinal[None],
            ys=jax.tree_util.tree_map(lambda x: x[None], yfinal),
            result=result,
            stats={"num_steps": s["num_steps"]},
        )

    def root_find(self, s, args, result, happened):
        """The event's time and state in the last step (lanes without one: the step's end)."""
        solver, cond_fn = self.solver, self.cond_fn
        if self.keep_dense:
            dense_info = s["ev_dense"]
        else:
            _, _, dense_info, _, _ = solver.step(
                self.term, s["ev_tprev"], s["ev_tnext"], s["ev_y"], args, s["ev_state"], False
            )

        def along_the_step(dense_info, t0, t1, args):  # the dense output and the event there
            interp = solver.interpolation_cls(t0=t0, t1=t1, **dense_info)

            def event_value(t, y):  # lanes without an event: the end of the step
                return jnp.where(happened, cond_fn(t, y, args), t1 - t)

            return interp.evaluate, event_value

        step = (dense_info, s["ev_tprev"], s["ev_tnext"], args)
        path, event_value = along_the_step(*step)
        t_event, y, found = _event.locate(
            path,
            event_value,
            s["ev_tprev"],
            s["ev_tnext"],
            self.event.root_finder.rtol,
            self.event.root_finder.atol,
            search=along_the_step(*jax.lax.stop_gradient(step)),
        )
        y = jax.tree_util.tree_map(lambda a, b: jnp.where(s["num_steps"] == 0, a, b), s["y"], y)
        return t_event, y, RESULTS.where(found, result, RESULTS.nonlinear_divergence)


def diffeqsolve_lean(term, solver, t0, t1, dt0, y0, args, **options):
    """One solve (one lane; ``vmap`` it), as ``diffrax.diffeqsolve(..., throw=False)``.
    ``options``: ``event``, ``stepsize_controller``, ``max_steps``.

    The stages-in-a-loop form (the compact program, which every derivative uses) keeps the
    last step's dense output in the state, so the program holds one step instead of two:
    measured on the fit's program (25 impacts, 3 tangents), about 1 s less compiling and
    0.7 s less tracing, the same bits and the same time per call. The unrolled form
    recomputes the step: keeping its 7 x 10 stage arrays per lane cost 25 % of the float64
    rate on 20,000 impacts (5,400 against 7,100 impacts/s) and compiled no faster."""
    keep_dense = getattr(solver, "stages", None) == "loop"
    init, running, step, finish = lane_functions(
        term, solver, t0, t1, dt0, y0, keep_dense=keep_dense, **options
    )
    s = jax.lax.while_loop(running, lambda s: step(s, args), init(y0, args))
    return finish(s, args)


# Refill the lanes once this fraction of them has finished: often enough that few lanes idle,
# rarely enough that the refill (a gather, one vector-field evaluation per lane for the new
# impacts' first stage, a scatter of the finished lanes' states) costs little.
REFILL_FRACTION = 1 / 8


def solve_pool(term, solver, t0, t1, dt0, y0s, args_s, *, lanes, tail_lanes, **options):
    """Solve a batch of impacts (the leading axis of ``y0s`` and ``args_s``) with ``lanes``
    lane slots that each take the next impact when theirs has finished.

    A vmapped solve runs every lane for as many steps as its slowest impact needs (in the
    near-capture band, float32, a few grazing impacts take 40x the median steps). Here the
    lanes are stepped together as in ``vmap`` (a finished lane's state is kept, as the batched
    while loop keeps it); whenever a ``REFILL_FRACTION`` of them has finished, their states are
    stored and they start the next impacts; once no impact is left to start and at most
    ``tail_lanes`` still run, those go on in ``tail_lanes`` lanes. Every operation is
    elementwise over lanes (``lanes`` and ``tail_lanes`` whole numbers of SIMD lane groups) and
    every impact starts through the same refill code, so an impact's bits do not depend on its
    lane or on when it started. ``options``: as :func:`diffeqsolve_lean`'s. Returns the
    batch's ``LeanSolution``.
    """
    size = jax.tree_util.tree_leaves(y0s)[0].shape[0]
    init, running, step, finish = lane_functions(term, solver, t0, t1, dt0, y0s, **options)

    index = jnp.arange(lanes)
    args = _take(args_s, index)
    states = jax.vmap(init)(_take(y0s, index), args)
    records = jax.tree_util.tree_map(lambda x: jnp.zeros((size,) + x.shape[1:], x.dtype), states)
    # every impact starts through the refill below (one compiled form of its first stage)
    carry = (states, args, index, jnp.zeros(lanes, bool), jnp.asarray(0), records)

    def finished_of(states, active):
        return active & ~jax.vmap(running)(states)

    def refill_due(states, active, next_impact):
        n_free = jnp.sum(finished_of(states, active) | ~active)
        return (next_impact < size) & (n_free >= REFILL_FRACTION * lanes)

    def tail_due(states, active, next_impact):  # few lanes left: go on with fewer lanes
        n_running = jnp.sum(active & jax.vmap(running)(states))
        return (next_impact >= size) & (n_running <= tail_lanes)

    def cond(carry):
        states, _, _, active, next_impact, _ = carry
        busy = jnp.any(active & jax.vmap(running)(states)) | (next_impact < size)
        return busy & ~tail_due(states, active, next_impact)

    def step_lanes(states, args, active):
        go = active & jax.vmap(running)(states)
        return _where(go, jax.vmap(step)(states, args), states)

    def body(carry):
        states, args, index, active, next_impact, records = carry

        # step the lanes until a refill is due (the inner loop carries only the lanes: the
        # records of the whole batch are touched once per refill)
        def stepping(states):
            go = jnp.any(active & jax.vmap(running)(states))
            go = go & ~refill_due(states, active, next_impact)
            return go & ~tail_due(states, active, next_impact)

        states = jax.lax.while_loop(stepping, lambda x: step_lanes(x, args, active), states)
        finished = finished_of(states, active)
        free = finished | ~active
        records = _store(records, states, index, finished)
        states, args, index, fill = _refilled(
            init, y0s, args_s, states, args, index, next_impact, free
        )
        active = (active & ~finished) | fill
        next_impact = jnp.minimum(next_impact + jnp.sum(free), size)
        return states, args, index, active, next_impact, records

    states, args, index, active, _, records = jax.lax.while_loop(cond, body, carry)
    # The tail: the impacts still running, gathered into `tail_lanes` lanes (the slowest
    # impacts of a batch would otherwise keep every lane stepping).
    records = _store(records, states, index, finished_of(states, active))
    active = active & jax.vmap(running)(states)
    order = jnp.argsort(~active, stable=True)[:tail_lanes]  # the running lanes first
    states, args, index, active = _take((states, args, index, active), order)
    states = jax.lax.while_loop(
        lambda x: jnp.any(active & jax.vmap(running)(x)),
        lambda x: step_lanes(x, args, active),
        states,
    )
    records = _store(records, states, index, active)
    return jax.vmap(finish)(records, args_s)


def _take(tree, i):
    """The rows ``i`` of every leaf of ``tree``."""
    return jax.tree_util.tree_map(lambda x: x[i], tree)


def _where(mask, a, b):
    """``a`` where ``mask`` (one flag per lane), else ``b``, leaf by leaf."""
    return jax.tree_util.tree_map(
        lambda u, v: jnp.where(mask.reshape(mask.shape + (1,) * (u.ndim - 1)), u, v), a, b
    )


def _store(records, states, index, mask):
    """Rows ``index`` of the batch's ``records`` set to the lanes' ``states`` where ``mask``."""
    size = jax.tree_util.tree_leaves(records)[0].shape[0]
    rows = jnp.where(mask, index, size)  # out of range: dropped
    return jax.tree_util.tree_map(lambda r, x: r.at[rows].set(x, mode="drop"), records, states)


def _refilled(init, y0s, args_s, states, args, index, next_impact, free):
    """The free lanes started on the next impacts, the ``i``-th free lane on impact
    ``next_impact + i`` while there is one (its first stage through ``init``): the lanes'
    ``(states, args, index)`` and which lanes took an impact."""
    size = jax.tree_util.tree_leaves(y0s)[0].shape[0]
    new = next_impact + jnp.cumsum(free) - 1
    fill = free & (new < size)
    rows = jnp.minimum(new, size - 1)
    new_args = _take(args_s, rows)
    states = _where(fill, jax.vmap(init)(_take(y0s, rows), new_args), states)
    args = _where(fill, new_args, args)
    index = jnp.where(fill, new, index)
    return states, args, index, fill
