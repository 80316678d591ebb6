"""Solving one chunk: the model and solver chosen once for the sweep, the sharded program that
solves a chunk as ``simulate`` solves a batch, and the dispatch and fetch of its results."""

from __future__ import annotations

import hashlib
import json

import numpy as np

from .._io.columns import IMPACT_COLUMNS, RESULT_COLUMNS
from ._store import FORMAT

_RUNNERS: dict = {}


_STIFFNESS: list = []  # the jitted stiffness estimate, made on first use (jax imports lazily)


# How the sweep's program solves a chunk: the batch path of ``jaximpact.simulate`` (its
# ``_simulate``), so that a sweep gives simulate's bits (its ``default_loop``).


def _runner(terms, cfg, devices):
    """The jitted, sharded program that solves one chunk (cached per model, solver, devices).

    A ``jit`` of the simulator's batch function with its inputs sharded along the batch over a
    1-D mesh of the local devices; inside, ``simulate``'s batch path gives each device its
    slice (``jax.shard_map``), which it solves on its own: the devices exchange no data.

    Inside, the chunk is solved as ``simulate`` solves a batch of that size on these devices:
    the same lanes per device at a time (``chunk``, ``shards``; ``lax.map`` over sub-chunks on
    a CPU). Returns ``(fn, sharding)``: ``fn(params, speed, angle_deg, omega0)`` gives the
    status codes and the numeric result columns stacked as one ``(len(OUTPUT_FIELDS), size)``
    array, so that fetching a chunk is one transfer of what its part file holds (not the step
    counts).
    """
    import jax
    import jax.numpy as jnp
    from jax.sharding import Mesh, NamedSharding
    from jax.sharding import PartitionSpec as P

    from .._engine.devices import compiler_options
    from .._engine.results import OUTPUT_FIELDS
    from .._engine.simulate import _default_chunk, _simulate_flat, default_loop
    from .._engine.tsit5 import lane_group

    shards = len(devices)
    chunk = _default_chunk(shards)
    loop = default_loop(jnp.result_type(float))
    key = (terms, cfg, tuple(d.id for d in devices), chunk, loop)
    if key not in _RUNNERS:
        mesh = Mesh(np.array(devices), ("batch",))
        sharding = NamedSharding(mesh, P("batch"))

        def sweep_chunk(params, speed, angle_deg, omega0):
            inputs = (params, speed, angle_deg, omega0)
            size = speed.shape[0]
            # as simulate: at least 2 lanes, whole lane groups per device (per_state form)
            pad = -size % (shards * max(2, lane_group(speed.dtype, cfg.stages)))
            inputs = jax.tree_util.tree_map(lambda x: jnp.pad(x, (0, pad), mode="edge"), inputs)
            result = _simulate_flat(terms, cfg, *inputs, chunk=chunk, shards=shards, loop=loop)
            values = jnp.stack([getattr(result, k)[:size] for k in OUTPUT_FIELDS])
            return result.status[:size], values

        fn = jax.jit(
            sweep_chunk,
            compiler_options=compiler_options(throughput=cfg.stages == "per_state") or None,
            in_shardings=sharding,
            out_shardings=(sharding, NamedSharding(mesh, P(None, "batch"))),
        )
        _RUNNERS[key] = (fn, sharding)
    return _RUNNERS[key]


def _params(base: dict, rows: dict, size: int, dtype) -> dict:
    """Per-impact parameter arrays: the row's override, else the scene's value."""
    return {k: np.asarray(rows[k] if k in rows else np.full(size, base[k]), dtype) for k in base}


def _padded_rows(source, start: int, chunk_size: int) -> tuple[dict, int]:
    """Rows ``start:start+chunk_size`` of ``source`` and how many are real.

    A short last chunk is padded by repeating its last row: a valid impact, so padding cannot
    fail or slow down the solver, and the shape (hence the compilation) stays the same.
    """
    stop = min(start + chunk_size, source.n)
    rows = source.rows(start, stop)
    valid = stop - start
    if valid == chunk_size:
        return rows, valid
    pad = np.concatenate([np.arange(valid), np.full(chunk_size - valid, valid - 1)])
    return {k: v[pad] for k, v in rows.items()}, valid


def _chunk_inputs(source, base: dict, chunk: int, chunk_size: int, dtype):
    """Chunk ``chunk``'s rows (unpadded, for its part file), its number of real rows, and the
    padded program inputs ``[params, speed, angle_deg, omega0]`` as host arrays."""
    padded, valid = _padded_rows(source, chunk * chunk_size, chunk_size)
    rows = {k: v[:valid] for k, v in padded.items()}
    prm = _params(base, padded, chunk_size, dtype)
    return rows, valid, [prm] + [np.asarray(padded[k], dtype) for k in IMPACT_COLUMNS]


def _dispatch(fn, sharding, args):
    """Put a chunk's inputs on the devices and run its program (asynchronously where JAX can);
    the copy of its results to the host starts as soon as they are computed (on a GPU)."""
    import jax

    result = fn(*jax.device_put(args, sharding))
    for array in result:
        array.copy_to_host_async()
    return result


def _fetch(result, valid: int) -> tuple[np.ndarray, np.ndarray]:
    """Wait for a chunk's program and copy its status codes and result columns to the host."""
    import jax

    status, values = jax.device_get(result)
    return np.asarray(status[:valid]), np.asarray(values[:, :valid])


def _model_config(scene, source, chunk_size: int, dtype):
    """Model terms and solver settings for the whole sweep (static: one compilation).

    The same choice :func:`jaximpact.simulate` makes for one batch holding every impact: the
    terms from all values each input takes; with ``method = "auto"``, Kvaerno5 if the stiffness
    estimate of any impact exceeds the limit (computed chunk by chunk to bound memory, in one
    compiled function of the padded chunk, read back once at the end).
    """
    import jax
    import jax.numpy as jnp

    from .._engine.settings import (
        integration_settings,
        required_terms,
        scene_parameters,
        stiffness_estimate,
    )

    base = {k: float(v) for k, v in scene_parameters(scene).items()}
    sets = source.value_sets()
    params = {k: np.asarray(sets.get(k, base[k]), np.float64) for k in base}
    terms = required_terms(scene, params, sets["angle_deg"], sets["omega0"])
    method = scene.solver.method
    if method == "auto":
        if not _STIFFNESS:
            _STIFFNESS.append(jax.jit(stiffness_estimate))
        stiffness = None
        for start in range(0, source.n, chunk_size):
            rows, _ = _padded_rows(source, start, chunk_size)  # the copies: the same maximum
            prm = _params(base, rows, chunk_size, dtype)
            estimate = _STIFFNESS[0](prm, rows["speed"].astype(dtype), rows["angle_deg"])
            stiffness = estimate if stiffness is None else jnp.maximum(stiffness, estimate)
        method = "kvaerno5" if float(stiffness) > scene.solver.stiffness_limit else "tsit5"
    one = {k: np.ones(1) for k in base}
    cfg = integration_settings(scene, one, np.ones(1), np.zeros(1), dtype, method)
    return base, terms, cfg


def _settings(
    scene_path, source, chunk_size: int, dtype, result_columns=None, stored="float64"
) -> tuple[dict, str]:
    """The sweep's settings and their digest; ``result_columns``: a chosen subset (recorded,
    so that resuming with other columns is refused), or None for every column (the settings of
    sweeps begun before the choice existed); ``stored``: the result columns' precision
    (recorded where float32)."""
    from .. import __version__
    from .._io.scene_files import describe_scene_source
    from .._io.scene_files import scene_path as resolve_scene

    scene_file = resolve_scene(scene_path)  # an embedded scene's name, or a path
    settings = {
        "format": FORMAT,
        "jaximpact": __version__,
        "scene": describe_scene_source(scene_path),
        "scene_sha256": hashlib.sha256(scene_file.read_bytes()).hexdigest(),
        "impacts": source.fingerprint,
        "precision": np.dtype(dtype).name,
        "chunk_size": chunk_size,
        "n_impacts": source.n,
        "n_chunks": -(-source.n // chunk_size),
        "columns": list(source.columns),
    }
    if result_columns is not None and tuple(result_columns) != RESULT_COLUMNS:
        settings["result_columns"] = list(result_columns)
    if stored != "float64":
        settings["stored_precision"] = stored
    # The hash covers what determines the numbers; not the scene's path (moving a file is fine).
    hashed = {k: v for k, v in settings.items() if k != "scene"}
    digest = hashlib.sha256(json.dumps(hashed, sort_keys=True).encode()).hexdigest()
    return settings, digest


def _status_texts():
    """Arrow string arrays indexed by status code: the ``status`` column's text
    (rebound/captured/failed) and ``failure_reason``'s (null unless failed)."""
    import pyarrow as pa

    from .._engine.results import Status

    codes = range(max(Status.NAMES) + 1)
    status = pa.array([Status.csv_name(c) for c in codes], pa.string())
    reason = [Status.NAMES[c] if c >= Status.MAX_STEPS else None for c in codes]
    return status, pa.array(reason, pa.string())


def _failure_counts(status: np.ndarray) -> dict[str, int]:
    """``{failure_reason: count}`` of a chunk's status codes (failed impacts only)."""
    from .._engine.results import Status

    counts = np.bincount(status, minlength=max(Status.NAMES) + 1)
    return {Status.NAMES[c]: int(n) for c, n in enumerate(counts) if c >= Status.MAX_STEPS and n}
