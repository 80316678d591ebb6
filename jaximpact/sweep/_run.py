"""``run_sweep``: the pipelined loop over chunks (dispatch, convert, write) and its summary."""

from __future__ import annotations

import json
import os
import signal
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from .._io.tables import (
    RESULT_COLUMNS,
    atomic_write_text,
)
from ._chunks import (
    _chunk_inputs,
    _dispatch,
    _failure_counts,
    _fetch,
    _model_config,
    _runner,
    _settings,
)
from ._sources import GridSource, SweepError, TableSource
from ._store import (
    _MANIFEST,
    _PART,
    _TEMP,
    FORMAT,
    _atomic_write_table,
    _clear,
    _legacy_manifest_name,
    _load_manifests,
    _manifest_failures,
    _manifest_name,
    _part_name,
    _prepare_output,
    _result_columns,
    _setting_differences,
)
from ._writer import COMPRESSIONS, _chunk_table, _Writer, parquet_options, writer_threads

#: Impacts per chunk when none is given (float64; see ``DEFAULT_CHUNK_SIZE_FLOAT32``).
DEFAULT_CHUNK_SIZE = 8192
# float32: a chunk computes ~7x faster than a float64 one, and a chunk's fixed costs (dispatch,
# Parquet) weigh more: at 8192 a sweep ran 0.60 of ``simulate``'s marginal rate on one device
# and 0.79 on two (each device solving its part on its own, with loop kernels), at 32,768
# 0.97-1.07 and 0.96 (BENCHMARKS.md, "Large sweeps").
#: Impacts per chunk when none is given, in float32.
DEFAULT_CHUNK_SIZE_FLOAT32 = 32768


def default_chunk_size(dtype, devices: int = 1) -> int:
    """Impacts per chunk when none is given: 8192, or 32,768 in float32 (``devices``: kept for
    callers; the default no longer depends on it)."""
    import numpy as np

    del devices
    return DEFAULT_CHUNK_SIZE_FLOAT32 if np.dtype(dtype).itemsize < 8 else DEFAULT_CHUNK_SIZE


# Test hook only: after this many chunks are committed in one run, write the next part file and
# then SIGKILL the process before its manifest entry is written (the most delicate moment).
_KILL_ENV = "JAXIMPACT_SWEEP_KILL_AFTER"


@dataclass(frozen=True)
class SweepSummary:
    """What one :func:`run_sweep` call did (for this process).

    Attributes:
        output: the output directory.
        n_impacts, n_chunks, chunk_size: the whole sweep.
        chunks_run: chunks computed by this call; ``chunks_skipped``: this process's chunks
            already done before it started.
        impacts_run: impacts (without padding) computed by this call.
        failed: impacts with status ``failed`` among those computed by this call.
        seconds: wall time of the call; ``devices``: local devices used.
        complete: every chunk of the sweep is listed in the manifests as seen at the end.
        impacts_done: impacts in the chunks the manifests list at the end (every process, every
            call; ``n_impacts`` once complete).
        failures: ``{failure_reason: count}`` over those impacts (``unrecorded``: failed in a
            sweep begun before reasons were recorded); empty when none failed.
        legacy_columns: the sweep was begun before ``failure_reason`` existed; its part files
            keep the older columns (one schema per directory), so reasons are not stored.
    """

    output: str
    n_impacts: int
    n_chunks: int
    chunk_size: int
    chunks_run: int
    chunks_skipped: int
    impacts_run: int
    failed: int
    seconds: float
    devices: int
    complete: bool
    impacts_done: int = 0
    failures: dict = field(default_factory=dict)
    legacy_columns: bool = False


def run_sweep(
    source: TableSource | GridSource,
    output,
    *,
    scene_path=None,
    chunk_size: int | None = None,
    restart: bool = False,
    progress: bool = True,
    process_index: int | None = None,
    process_count: int | None = None,
    columns=None,
    compression: str | None = None,
    stored_precision: str | None = None,
) -> SweepSummary:
    """Run (or continue) a sweep, writing each finished chunk to ``output``.

    Set the precision first (``jax.config.update("jax_enable_x64", True)`` for float64); it is
    part of the settings.

    Arguments:
        source: the impacts (:func:`read_impacts_file`, or :class:`GridSource`).
        output: the output directory (created if missing).
        scene_path: an embedded scene's name or a scene file; ``None``: the embedded Table 1
            scene.
        chunk_size: impacts per chunk; a multiple of the number of local JAX devices.
            ``None``: the sweep's own when continuing one, else :func:`default_chunk_size`
            (8192; 32,768 in float32).
        restart: delete results made with other settings (or any results) and start over.
        progress: show a tqdm progress bar on stderr (impacts/s, ETA).
        process_index, process_count: this process's share (chunks ``i`` with
            ``i % process_count == process_index``); default ``jax.process_index()`` and
            ``jax.process_count()`` (0 and 1 without ``jax.distributed``).
        columns: the result columns to store (names of ``RESULT_COLUMNS``; ``status`` is
            always kept), or None for all of them (the sweep's own when continuing one).
            Fewer columns, fewer bytes per row (README, "Large sweeps"); part of the settings.
        compression: of the part files: "none" (default: the fastest to write), "snappy",
            "lz4" or "zstd" (smaller, slower); not a setting (readers take any mix).
        stored_precision: of the numeric result columns: "float64" or "float32" (half the
            bytes; the natural choice for a float32 run, whose results carry about 1e-5
            relative error anyway); None: the sweep's own when continuing one, else float64.
            Part of the settings.

    Returns:
        SweepSummary: what this call computed.

    Raises:
        SweepError: chunk size not a positive multiple of the device count, bad process share,
            ``output`` a file, not creatable or not writable, a non-empty directory that is
            not a sweep, or results there made with other settings (without ``restart``; the
            message names each setting that differs). All raised before any computing.
        SceneError: the scene file is invalid. OSError: files cannot be read or written.
    """
    t_start = time.perf_counter()
    plan = _plan(source, Path(output), scene_path, chunk_size, restart, process_index,
                 process_count, columns, compression, stored_precision)  # fmt: skip
    base, terms, cfg = _model_config(plan.scene, source, plan.chunk_size, plan.dtype)
    fn, sharding = _runner(terms, cfg, plan.devices)
    pipeline = _Pipeline(
        source, base, plan.chunk_size, plan.dtype, fn, sharding, plan.directory, plan.manifest,
        plan.result_columns, plan.own_completed, plan.own_failures, compression=compression,
        stored=plan.stored_precision,
    )  # fmt: skip
    bar = _progress_bar(source, plan.chunk_size, plan.mine, plan.todo, progress, plan.directory,
                        plan.index, plan.count)  # fmt: skip
    pipeline.run(plan.todo, bar)
    # begun before failure_reason
    legacy = plan.chosen is None and plan.result_columns != RESULT_COLUMNS
    return _summary(plan.directory, source, plan.chunk_size, plan.settings["n_chunks"], plan.mine,
                    plan.todo, pipeline, plan.result_columns, t_start, len(plan.devices),
                    legacy)  # fmt: skip


@dataclass
class _Plan:
    """What a :func:`run_sweep` call does, worked out (every problem raised) before any
    computing: its settings, this process's share of the chunks, and where that share
    stands."""

    directory: Path
    devices: list
    dtype: object
    scene: object
    chunk_size: int
    index: int
    count: int
    chosen: tuple | None  # the result columns chosen (None: all, on a sweep begun so)
    stored_precision: str
    settings: dict
    mine: list  # this process's chunks
    todo: list  # those not done yet
    result_columns: tuple
    own_completed: list
    own_failures: dict
    manifest: dict  # the fixed fields of this process's manifest


def _plan(source, directory: Path, scene_path, chunk_size, restart, process_index,
          process_count, columns, compression, stored_precision) -> _Plan:  # fmt: skip
    """:func:`run_sweep`'s arguments resolved (the sweep's own settings where continuing one)
    and checked, the output directory prepared, and this process's share of the chunks
    (``restart``: its results cleared)."""
    import jax
    import jax.numpy as jnp

    from .. import load_scene

    devices = jax.local_devices()
    dtype = jnp.result_type(float)
    if chunk_size is None:
        chunk_size = _existing_chunk_size(directory, restart) or default_chunk_size(
            dtype, len(devices)
        )
    index, count = _process_share(chunk_size, devices, process_index, process_count)
    scene = load_scene(scene_path)
    _check_inputs_used(scene, source)
    chosen, stored_precision = _stored_choices(
        directory, restart, columns, compression, stored_precision
    )
    settings, digest = _settings(scene_path, source, chunk_size, dtype, chosen, stored_precision)
    _prepare_output(directory)  # before any computing: every file problem first
    mine = [c for c in range(settings["n_chunks"]) if c % count == index]
    result_columns, own_completed, own_failures, todo = _resumed(
        directory, settings, digest, restart, chosen, mine, index, count
    )
    manifest = {
        "format": FORMAT,
        "settings_hash": digest,
        "settings": settings,
        "process_index": index,
        "process_count": count,
        "result_columns": list(result_columns),
    }
    return _Plan(
        directory, devices, dtype, scene, chunk_size, index, count, chosen, stored_precision,
        settings, mine, todo, result_columns, own_completed, own_failures, manifest,
    )  # fmt: skip


def _check_inputs_used(scene, source) -> None:
    """A grid axis or impacts column of a parameter that the scene does not use is refused
    (every value would give the same impacts)."""
    from ..parameters import unused_reason

    for name in source.value_sets():
        reason = unused_reason(scene, name)
        if reason is not None:
            raise SweepError(f"{name}: {reason}")


def _stored_choices(directory: Path, restart: bool, columns, compression, stored_precision):
    """``(result columns, stored precision)`` of the sweep: the user's choices, checked, or
    where not given the sweep's own when continuing one (``None`` columns: all of them)."""
    if compression is not None and compression not in COMPRESSIONS:
        raise SweepError(f"compression: {compression!r}; allowed: {', '.join(COMPRESSIONS)}")
    if stored_precision not in (None, "float64", "float32"):
        raise SweepError(f"stored_precision: {stored_precision!r}; allowed: float64, float32")
    chosen = result_columns_for(columns)
    if chosen is None:  # continuing: the sweep's own choice (all columns if it made none)
        own = _existing_setting(directory, "result_columns", restart)
        chosen = tuple(own) if own else None
    if stored_precision is None:
        own = _existing_setting(directory, "stored_precision", restart)
        stored_precision = own or "float64"
    return chosen, stored_precision


def _resumed(directory: Path, settings, digest, restart: bool, chosen, mine, index, count):
    """Where this process's share of the sweep stands: with ``restart`` its results cleared,
    else the manifests of the sweep continued and this process's temporaries removed.
    Returns ``(result columns, own completed chunks, own failure counts, chunks to do)``."""
    if restart:
        _clear_for_restart(directory, mine, index, count, settings["n_chunks"])
        manifests = {}
    else:
        manifests = _continued_manifests(directory, settings, digest, index, count)
        _clear_own_temporaries(directory, mine, index)
    result_columns = chosen or _result_columns(manifests)
    done = {int(c) for _, m in manifests.values() for c in m["completed"]}
    own_manifest = manifests[index][1] if index in manifests else {"completed": []}
    own_completed = sorted(int(c) for c in own_manifest["completed"])
    own_failures = _manifest_failures(directory, own_manifest) if own_completed else {}
    todo = [c for c in mine if c not in done]
    return result_columns, own_completed, own_failures, todo


def result_columns_for(columns) -> tuple[str, ...] | None:
    """The stored result columns for the user's choice ``columns`` (names, or one string of
    comma-separated names): ``status`` first, then the others in ``RESULT_COLUMNS`` order;
    None for None (all columns)."""
    if columns is None:
        return None
    names = [c.strip() for c in columns.split(",")] if isinstance(columns, str) else list(columns)
    names = [c for c in names if c]
    unknown = [c for c in names if c not in RESULT_COLUMNS]
    if unknown or not names:
        raise SweepError(
            f"columns: {', '.join(map(repr, unknown)) or 'none given'} not a result column; "
            f"allowed: {', '.join(RESULT_COLUMNS)}"
        )
    return tuple(c for c in RESULT_COLUMNS if c == "status" or c in names)


def _summary(
    directory, source, chunk_size, n_chunks, mine, todo, pipeline, result_columns, t_start,
    devices, legacy,
) -> SweepSummary:  # fmt: skip
    """What this call computed, and what the sweep (all processes' manifests) holds now."""
    final = _load_manifests(directory)
    finished = {int(c) for _, m in final.values() for c in m["completed"]}
    failures: dict[str, int] = {}
    for _, m in final.values():
        for reason, n in _manifest_failures(directory, m).items():
            failures[reason] = failures.get(reason, 0) + n
    return SweepSummary(
        output=str(directory),
        n_impacts=source.n,
        n_chunks=n_chunks,
        chunk_size=chunk_size,
        chunks_run=len(todo),
        chunks_skipped=len(mine) - len(todo),
        impacts_run=pipeline.impacts_run,
        failed=pipeline.failed,
        seconds=time.perf_counter() - t_start,
        devices=devices,
        complete=finished >= set(range(n_chunks)),
        impacts_done=sum(min(chunk_size, source.n - c * chunk_size) for c in finished),
        failures=failures,
        legacy_columns=legacy,
    )


def _process_share(chunk_size, devices, process_index, process_count) -> tuple[int, int]:
    """This process's index and the process count, the chunk size checked against devices."""
    import jax

    if chunk_size < 1 or chunk_size % len(devices):
        raise SweepError(
            f"--chunk-size {chunk_size} must be a positive multiple of the number of local "
            f"devices ({len(devices)}: {', '.join(str(d) for d in devices)})"
        )
    index = jax.process_index() if process_index is None else process_index
    count = jax.process_count() if process_count is None else process_count
    if not 0 <= index < count:
        raise SweepError(f"process index {index} is not in [0, {count})")
    return index, count


def _own_names(mine, index: int) -> set[str]:
    """The files only this process writes: its chunks' part files and its manifest."""
    return {_part_name(c) for c in mine} | {_manifest_name(index), _legacy_manifest_name(index)}


def _clear_for_restart(directory: Path, mine, index: int, count: int, n_chunks: int) -> None:
    """Delete the results a restart replaces.

    Each process deletes only what it will rewrite, so concurrent processes of a distributed
    restart never delete each other's new files; process 0 also deletes what no process of
    this run owns (parts past the end, manifests of a larger old run)."""
    own = _own_names(mine, index)

    def keep(name: str) -> bool:
        if name in own:
            return False
        if index != 0:
            return True
        part, manifest = _PART.match(name), _MANIFEST.match(name)
        if part:
            return int(part.group(1)) < n_chunks
        if manifest:
            return int(manifest.group(1)) < count
        return True  # others' temporaries may be in flight

    _clear(directory, keep)


def _clear_own_temporaries(directory: Path, mine, index: int) -> None:
    """Delete the temporaries a killed run of this process left (a part file or manifest it
    was writing when it died). Only this process writes those names, so none is in flight."""
    own = _own_names(mine, index)

    def keep(name: str) -> bool:
        temporary = _TEMP.match(name)
        return not (temporary and name[1:].rsplit(".", 2)[0] in own)

    _clear(directory, keep)


def _existing_setting(directory: Path, name: str, restart: bool = False):
    """The setting ``name`` the sweep in ``directory`` was begun with, where its manifests
    agree on one (``None``: no sweep there, unreadable, a restart, or not set), so that
    continuing a sweep without the option keeps the sweep's own."""
    if restart or not directory.is_dir():
        return None
    try:
        manifests = _load_manifests(directory)
    except SweepError:
        return None  # the run reports it
    values = {
        json.dumps(v, sort_keys=True)
        for _, m in manifests.values()
        if (v := (m.get("settings") or {}).get(name)) is not None
    }
    return json.loads(values.pop()) if len(values) == 1 else None


def _existing_chunk_size(directory: Path, restart: bool) -> int | None:
    """The chunk size of the sweep in ``directory`` (see :func:`_existing_setting`)."""
    size = _existing_setting(directory, "chunk_size", restart)
    return size if isinstance(size, int) and size > 0 else None


def _continued_manifests(directory: Path, settings, digest, index: int, count: int) -> dict:
    """The manifests of the sweep being continued, refused if made with other settings."""
    manifests = _load_manifests(directory)
    for _, m in manifests.values():
        if m.get("settings_hash") != digest:
            differences = _setting_differences(m.get("settings") or {}, settings)
            raise SweepError(
                f"{directory}: a sweep made with other settings: {'; '.join(differences)}. "
                "Use --restart to discard its results, or another -o"
            )
    # Old-style manifest names (before "_manifest-"): this process renames its own (process
    # 0 also those no process of this run owns), so Parquet readers skip them from now on.
    for p, (file, m) in list(manifests.items()):
        if (p == index or (index == 0 and p >= count)) and file.name != _manifest_name(p):
            os.replace(file, directory / _manifest_name(p))
            manifests[p] = (directory / _manifest_name(p), m)
    return manifests


def _progress_bar(source, chunk_size, mine, todo, progress, directory, index, count):
    """The tqdm bar of this process's impacts (those of chunks already done count as done)."""
    from tqdm import tqdm

    total = sum(min(chunk_size, source.n - c * chunk_size) for c in mine)
    return tqdm(
        total=total,
        initial=total - sum(min(chunk_size, source.n - c * chunk_size) for c in todo),
        unit="impact",
        unit_scale=True,
        smoothing=0.1,
        # No bar for a single chunk (it would jump from 0 to 100 %) nor for work under a second.
        disable=not progress or len(todo) < 2,
        delay=1.0,
        desc=f"sweep {directory.name}" + (f" [process {index}/{count}]" if count > 1 else ""),
    )


class _Pipeline:
    """This process's chunks, each dispatched before the one before is fetched, converted and
    handed to the writer thread, which writes its part file and then the manifest."""

    def __init__(
        self, source, base, chunk_size, dtype, fn, sharding, directory, manifest, result_columns,
        own_completed, own_failures, compression=None, stored="float64",
    ):  # fmt: skip
        self.source, self.base, self.chunk_size, self.dtype = source, base, chunk_size, dtype
        self.fn, self.sharding, self.directory = fn, sharding, directory
        self.manifest = manifest  # the fixed fields of this process's manifest
        self.result_columns = result_columns
        self.own_completed, self.own_failures = own_completed, own_failures
        self.skipped_own = len(own_completed)
        kill_after = os.environ.get(_KILL_ENV)
        self.kill_after = None if kill_after is None else int(kill_after)
        self.failed = self.impacts_run = 0
        self.bar = None
        self.threads = writer_threads()
        self.compression = compression  # the part files' (None: parquet_options' default)
        self.stored = stored  # the numeric result columns' precision

    def launch(self, chunk: int):
        """Build chunk ``chunk``'s inputs and dispatch it (in the dispatcher thread)."""
        rows, valid, args = _chunk_inputs(
            self.source, self.base, chunk, self.chunk_size, self.dtype
        )
        return chunk, valid, rows, self.dispatcher.submit(_dispatch, self.fn, self.sharding, args)

    def write(self, chunk: int, valid: int, rows: dict, status, values) -> None:
        """On a writer thread: the chunk's table and part file."""
        table = _chunk_table(
            rows, self.source.columns, status, values, self.manifest["settings_hash"],
            self.result_columns, self.stored,
        )  # fmt: skip
        _atomic_write_table(
            self.directory / _part_name(chunk),
            table,
            **parquet_options(self.source.columns, self.result_columns, self.compression),
        )

    def commit(self, chunk: int, valid: int, rows: dict, status, values) -> None:
        """On this thread, in chunk order, after its part file: the manifest that lists it."""
        counts = _failure_counts(status)
        if self.kill_after is not None:
            if len(self.own_completed) - self.skipped_own >= self.kill_after:
                os.kill(os.getpid(), signal.SIGKILL)  # test hook: die before the manifest update
        self.own_completed.append(chunk)
        # Counted in memory (reasons are known even where the sweep's columns lack them), and
        # stored with the completed list in one atomic write.
        for reason, n in counts.items():
            self.own_failures[reason] = self.own_failures.get(reason, 0) + n
        manifest = {
            **self.manifest,
            "completed": sorted(self.own_completed),
            "failures": dict(sorted(self.own_failures.items())),
        }
        index = manifest["process_index"]
        atomic_write_text(
            self.directory / _manifest_name(index), json.dumps(manifest, indent=1) + "\n"
        )
        self.failed += sum(counts.values())
        self.impacts_run += valid
        self.bar.update(valid)

    def hand_over(self, chunk: int, valid: int, rows: dict, result) -> None:
        """Wait for the chunk, copy it to the host and give it to the writers."""
        status, values = _fetch(result.result(), valid)
        self.writer.submit(chunk, valid, rows, status, values)

    def run(self, todo, bar) -> None:
        """Compute and write the chunks ``todo``, in order."""
        self.bar = bar
        pending = None
        self.writer = _Writer(self.write, self.commit, self.threads)
        # JAX runs a program on one CPU device asynchronously, but the call of a program
        # sharded over several CPU devices returns only when the chunk is done (measured):
        # calls from a thread of their own keep this thread free to fetch and convert the
        # chunk before.
        self.dispatcher = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sweep-dispatch")
        try:
            # Dispatch chunk k+1 before waiting for chunk k: the devices always have the next
            # chunk while the host fetches, converts and (in the writer thread) writes the last.
            for chunk in todo:
                launched = self.launch(chunk)
                if pending is not None:
                    self.hand_over(*pending)
                pending = launched
            if pending is not None:
                self.hand_over(*pending)
            self.writer.finish()
        finally:
            self.dispatcher.shutdown(wait=True, cancel_futures=True)
            self.writer.close()
            self.bar.close()
