"""Sweeps: grids of pure, idempotent tasks on one machine or on a Dask cluster.

A sweep is a grid ``materials × settings × seeds`` described in a small JSON or TOML file
(:func:`load_spec`). Every grid point is a *task*: a plain dict ::

    {"task": "fit_preset", "material": "rolled_brass", "seed": 3,
     "settings": {"noise": 0.05}, "fixed": {"n_samples": 400}}

and a task function ``fn(task, out_dir) -> metrics`` that writes whatever files it likes into
``out_dir`` and returns a flat dict of numbers (errors, counts). :func:`run_task` runs it in a
private temporary folder, writes ``sweep_task.json`` there and renames the folder into place
(``<root>/tasks/<task id>``) in one atomic step, so a task's result exists completely or not at
all: a worker killed mid-task leaves only a temporary folder that no reader looks at, and a
re-run skips every task whose complete ``sweep_task.json`` is present. (The name leaves
``summary.json`` to the task itself: a campaign writes its own there.) Two workers racing on the
same task (Dask re-running a task it believed lost) cannot write it twice: the second rename
fails and the loser discards its copy.

Executors (:func:`run_sweep`): ``"inprocess"`` (default, no dependency), ``"process"``
(:class:`concurrent.futures.ProcessPoolExecutor`; a crashed pool is rebuilt and the unfinished
tasks resubmitted) and ``"dask"`` (Dask distributed, the optional extra
``gonio[distributed]``; ``scheduler="tcp://host:port"`` or ``dask_local=N`` workers in a
``LocalCluster`` made by :func:`dask_local_cluster` with :data:`DASK_CONFIG`; Dask reschedules
the tasks of a lost worker, ``retries`` re-runs failed ones, and a cluster left without workers
for ``no_workers_timeout`` seconds fails the waiting tasks instead of hanging). Tasks finished
by an earlier run are read from their folders and never submitted. The gathered table
(``results.csv`` / ``results.json``) holds only deterministic columns, in grid order, so
every executor produces the same bytes; wall times go to ``timings.csv``.

Task functions are looked up by name in a registry (:func:`register_task`; built in:
``"fit_preset"``, and ``"campaign"`` which runs :mod:`gonio.campaign` when it is installed). A
spec file names a registered task only: reading a spec, even for ``--dry-run``, imports no
module the spec names; a task of your own is registered from Python first (its ``run`` may be
``"package.module:function"``, imported when the task first runs).
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import importlib
import io
import itertools
import json
import math
import os
import re
import shutil
import time
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gonio.campaign.blas import SingleThreadBLAS as _SingleThreadBLAS
from gonio.campaign.raw import RAW_CHOICES, disk_usage, keep_raw
from gonio.io.atomic import atomic_write_bytes

__all__ = [
    "DASK_CONFIG",
    "EXECUTORS",
    "SweepResult",
    "SweepSpec",
    "TaskFailed",
    "aggregate",
    "dask_local_cluster",
    "expand",
    "get_task",
    "load_spec",
    "plot_summary",
    "register_task",
    "run_sweep",
    "run_task",
    "task_id",
    "task_names",
]

EXECUTORS = ("inprocess", "process", "dask")
SUMMARY = "sweep_task.json"  # the completion record of a task folder
_SPEC_KEYS = (
    "name", "description", "task", "materials", "seeds", "settings", "fixed", "plot", "raw",
)  # fmt: skip

TaskFn = Callable[[dict[str, Any], Path], Mapping[str, Any]]


# --------------------------------------------------------------------------- task registry
@dataclass(frozen=True)
class _TaskEntry:
    run: TaskFn | str  # a callable or "module:function" imported on first use
    validate: Callable[[dict[str, Any]], None] | str | None = None
    metric: str = ""  # the headline metric for the summary plot
    doc: str = ""


_TASKS: dict[str, _TaskEntry] = {}


def register_task(
    name: str,
    run: TaskFn | str,
    *,
    validate: Callable[[dict[str, Any]], None] | str | None = None,
    metric: str = "",
    doc: str = "",
) -> None:
    """Register a task function under ``name`` (``run`` may be ``"module:function"``).

    ``validate(task)`` (optional) raises :class:`ValueError` for a task it cannot run; it is
    called for every grid point before any work starts, so a bad spec fails at once.
    ``metric`` names the headline metric the summary plot shows.
    """
    if not isinstance(name, str) or not re.fullmatch(r"[a-z][a-z0-9_]*", name):
        raise ValueError(f"task name must be snake_case, got {name!r}")
    _TASKS[name] = _TaskEntry(run, validate, metric, doc)


def task_names() -> list[str]:
    """Sorted names of the registered task functions."""
    return sorted(_TASKS)


def _import_ref(ref: str, what: str) -> Callable:
    mod_name, sep, attr = ref.partition(":")
    if not sep or not mod_name or not attr:
        raise ValueError(f"{what} must be a registered name or 'module:function', got {ref!r}")
    try:
        obj: Any = importlib.import_module(mod_name)
    except ImportError as exc:
        raise ValueError(f"{what} {ref!r}: cannot import module {mod_name!r} ({exc})") from None
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise ValueError(f"{what} {ref!r}: module {mod_name!r} has no attribute {attr!r}")
        obj = getattr(obj, part)
    if not callable(obj):
        raise ValueError(f"{what} {ref!r} is not callable")
    return obj


def _entry(name: str) -> _TaskEntry:
    """The registered task ``name``. A spec file cannot name ``"module:function"``: reading a
    spec (even with ``--dry-run``) must not import arbitrary modules; Python code registers
    its own task first (:func:`register_task`, whose ``run`` may be ``"module:function"``)."""
    if name in _TASKS:
        return _TASKS[name]
    raise ValueError(
        f"unknown task {name!r}; registered tasks are: {', '.join(task_names())} "
        "(a task of your own: gonio.campaign.sweep.register_task, then run_sweep)"
    )


def get_task(name: str) -> TaskFn:
    """The task function registered as ``name`` (its ``"module:function"`` imported)."""
    run = _entry(name).run
    return _import_ref(run, f"task {name!r}") if isinstance(run, str) else run


def _validator(name: str) -> Callable[[dict[str, Any]], None] | None:
    v = _entry(name).validate
    return _import_ref(v, f"validator of task {name!r}") if isinstance(v, str) else v


# --------------------------------------------------------------------------- the spec
@dataclass(frozen=True)
class SweepSpec:
    """A parsed sweep description (see :func:`load_spec` for the file format)."""

    task: str
    materials: tuple[str, ...]
    seeds: tuple[int, ...]
    settings: dict[str, tuple[Any, ...]] = field(default_factory=dict)
    fixed: dict[str, Any] = field(default_factory=dict)
    name: str = "sweep"
    description: str = ""
    plot: str = ""
    source: str = ""
    raw: str = "none"

    @property
    def n_tasks(self) -> int:
        """Number of grid points."""
        n = len(self.materials) * len(self.seeds)
        for v in self.settings.values():
            n *= len(v)
        return n

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable form (what ``sweep.json`` records)."""
        return {
            "name": self.name,
            "description": self.description,
            "task": self.task,
            "materials": list(self.materials),
            "seeds": list(self.seeds),
            "settings": {k: list(v) for k, v in self.settings.items()},
            "fixed": dict(self.fixed),
            "plot": self.plot,
            "raw": self.raw,
        }


def _is_scalar(v: Any) -> bool:
    if isinstance(v, bool | str | int):
        return True
    return isinstance(v, float) and math.isfinite(v)


def _check_value(v: Any, where: str) -> Any:
    """A JSON-able value: scalar, or list/dict of them (finite floats only)."""
    if _is_scalar(v):
        return v
    if isinstance(v, float):
        raise ValueError(f"{where} must be finite, got {v!r}")
    if isinstance(v, list | tuple):
        return [_check_value(x, f"{where}[{i}]") for i, x in enumerate(v)]
    if isinstance(v, dict):
        return {str(k): _check_value(x, f"{where}.{k}") for k, x in v.items()}
    raise ValueError(f"{where} must be a number, string, boolean, list or table, got {v!r}")


#: A sweep's ``name``: one path component (the default results folder is ``sweep_<name>``).
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")

#: Most grid points a spec may expand to; the grid is counted before it is built.
MAX_TASKS = 100_000


def _spec_task(data: dict[str, Any], where: str) -> str:
    """The spec's keys checked (none unknown, the required present) and its registered task."""
    unknown = sorted(set(data) - set(_SPEC_KEYS))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; expected keys are {list(_SPEC_KEYS)}")
    for key in ("task", "materials", "seeds"):
        if key not in data:
            raise ValueError(f"{where}: missing required key {key!r}")
    task = data["task"]
    if not isinstance(task, str):
        raise ValueError(f"{where}: 'task' must be a string, got {task!r}")
    try:
        get_task(task)  # registered only
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    return task


def _spec_materials(mats: Any, where: str) -> list[str]:
    """The ``materials`` axis: a name or a non-empty list of distinct names."""
    if isinstance(mats, str):
        mats = [mats]
    if not isinstance(mats, list) or not mats:
        raise ValueError(f"{where}: 'materials' must be a non-empty list of names, got {mats!r}")
    for m in mats:
        if not isinstance(m, str) or not m:
            raise ValueError(f"{where}: 'materials' entries must be non-empty strings, got {m!r}")
    if len(set(mats)) != len(mats):
        raise ValueError(f"{where}: 'materials' lists a material twice: {mats!r}")
    return mats


def _spec_seeds(seeds: Any, where: str) -> list[int]:
    """The ``seeds`` axis: a count (``range(count)``) or a list of distinct integers >= 0."""
    if isinstance(seeds, int) and not isinstance(seeds, bool):
        if not 1 <= seeds <= MAX_TASKS:
            raise ValueError(
                f"{where}: 'seeds' as a count must be in [1, {MAX_TASKS}], got {seeds}"
            )
        seeds = list(range(seeds))
    if not isinstance(seeds, list) or not seeds:
        raise ValueError(
            f"{where}: 'seeds' must be a count or a non-empty list of integers, got {seeds!r}"
        )
    for s in seeds:
        if not isinstance(s, int) or isinstance(s, bool) or s < 0:
            raise ValueError(f"{where}: 'seeds' entries must be integers >= 0, got {s!r}")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"{where}: 'seeds' lists a seed twice: {seeds!r}")
    return seeds


def _spec_settings(settings_in: Any, where: str) -> dict[str, tuple[Any, ...]]:
    """The ``[settings]`` grid axes: each a non-empty list of distinct JSON-able values."""
    if not isinstance(settings_in, dict):
        raise ValueError(f"{where}: 'settings' must be a table of lists, got {settings_in!r}")
    settings: dict[str, tuple[Any, ...]] = {}
    for k, v in settings_in.items():
        if k in ("material", "seed"):
            raise ValueError(
                f"{where}: settings.{k} clashes with the grid axis {k!r}; use 'materials'/'seeds'"
            )
        if not isinstance(v, list) or not v:
            raise ValueError(
                f"{where}: settings.{k} must be a non-empty list of values (a grid axis), "
                f"got {v!r}; put single values under [fixed]"
            )
        vals = tuple(_check_value(x, f"{where}: settings.{k}[{i}]") for i, x in enumerate(v))
        if len({json.dumps(x, sort_keys=True) for x in vals}) != len(vals):
            raise ValueError(f"{where}: settings.{k} lists a value twice: {v!r}")
        settings[k] = vals
    return settings


def _spec_name(data: dict[str, Any], where: str) -> str:
    """The string keys (``name``, ``description``, ``plot``) checked; the sweep's name."""
    for key in ("name", "description", "plot"):
        if key in data and not isinstance(data[key], str):
            raise ValueError(f"{where}: {key!r} must be a string, got {data[key]!r}")
    name = data.get("name", "sweep")
    if not _NAME.fullmatch(name):
        raise ValueError(
            f"{where}: 'name' {name!r} must be a plain folder name (letters, digits, '_', '-' "
            "and '.', at most 64, starting with a letter or digit); it names sweep_<name>"
        )
    return name


def spec_from_dict(data: Any, source: str = "<dict>") -> SweepSpec:
    """Validate a decoded spec (a dict as read from JSON or TOML) into a :class:`SweepSpec`.

    Every problem raises :class:`ValueError` naming the file, the key, the bad value and what
    was expected. The checks run in the order the keys are described in :func:`load_spec`:
    keys and task, materials, seeds, settings, fixed values, the grid's size, the names, and
    last the task's own validator on every grid point.
    """
    where = f"sweep spec {source}"
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a table/object at the top level, got {data!r}")
    task = _spec_task(data, where)
    mats = _spec_materials(data["materials"], where)
    seeds = _spec_seeds(data["seeds"], where)
    settings = _spec_settings(data.get("settings", {}), where)
    fixed = data.get("fixed", {})
    if not isinstance(fixed, dict):
        raise ValueError(f"{where}: 'fixed' must be a table, got {fixed!r}")
    fixed = {k: _check_value(v, f"{where}: fixed.{k}") for k, v in fixed.items()}
    n_tasks = len(mats) * len(seeds) * math.prod(len(v) for v in settings.values())
    if n_tasks > MAX_TASKS:
        raise ValueError(
            f"{where}: the grid has {n_tasks} points (materials x settings x seeds), more "
            f"than the {MAX_TASKS} a sweep runs"
        )
    raw = _check_raw(data.get("raw", "none"), f"{where}: 'raw'")
    clash = sorted(set(fixed) & set(settings))
    if clash:
        raise ValueError(f"{where}: key(s) {clash} appear in both [settings] and [fixed]")
    spec = SweepSpec(
        task=task,
        materials=tuple(mats),
        seeds=tuple(seeds),
        settings=settings,
        fixed=fixed,
        name=_spec_name(data, where),
        description=data.get("description", ""),
        plot=data.get("plot", ""),
        source=source,
        raw=raw,
    )
    validate = _validator(task)
    if validate is not None:
        for t in expand(spec):
            try:
                validate(t)
            except ValueError as exc:
                raise ValueError(f"{where}: task {task_id(t)}: {exc}") from None
    return spec


def load_spec(path: str | os.PathLike) -> SweepSpec:
    """Read a sweep spec from a ``.json`` or ``.toml`` file.

    Keys: ``task`` (a registered task name, :func:`task_names`), ``materials`` (list of
    names), ``seeds`` (a count ``n`` meaning ``0..n-1``, or a list of integers), ``settings``
    (table of grid axes, each a non-empty list), ``fixed`` (table passed to every task),
    optional ``name``, ``description``, ``plot`` (metric shown in the summary plot), ``raw``
    (what a task keeps of its raw frames: ``"none"``, the default, ``"compressed"`` or
    ``"keep"``; see :func:`run_task`).

    Examples
    --------
    A TOML spec::

        name = "noise"
        task = "fit_preset"
        materials = ["rolled_brass", "rolled_aluminum"]
        seeds = 3
        [settings]
        noise = [0.01, 0.05]
        [fixed]
        n_samples = 300
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"sweep spec {str(p)!r} does not exist or is not a file")
    suffix = p.suffix.lower()
    if suffix not in (".toml", ".json"):
        raise ValueError(f"sweep spec {p}: expected a .json or .toml file, got suffix {suffix!r}")
    from gonio.io.jsonfile import read_document

    return read_document(p, lambda d: spec_from_dict(d, str(p)), what="a sweep spec")


def _check_raw(raw: Any, what: str) -> str:
    """``raw`` if it is one of :data:`gonio.campaign.raw.RAW_CHOICES`, else a clear error."""
    if raw not in RAW_CHOICES:
        raise ValueError(f"{what} must be one of {', '.join(RAW_CHOICES)}, got {raw!r}")
    return raw


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)


def task_id(task: Mapping[str, Any]) -> str:
    """A readable, unique, deterministic folder name for ``task``.

    ``<material>-<seed>-<hash>``: the hash (12 hex digits of SHA-1 of the canonical JSON of
    the whole task) changes with any setting, so two different tasks never share a folder.
    """
    h = hashlib.sha1(_canonical(dict(task)).encode()).hexdigest()[:12]
    mat = re.sub(r"[^A-Za-z0-9_.]+", "_", str(task.get("material", "x")))[:40]
    return f"{mat}-s{task.get('seed', 0)}-{h}"


def expand(spec: SweepSpec) -> list[dict[str, Any]]:
    """The grid's task dicts in a fixed order: materials, then settings (file order), seeds."""
    keys = list(spec.settings)
    out = []
    for mat in spec.materials:
        for combo in itertools.product(*(spec.settings[k] for k in keys)):
            for seed in spec.seeds:
                out.append(
                    {
                        "task": spec.task,
                        "material": mat,
                        "seed": int(seed),
                        "settings": dict(zip(keys, combo)),
                        "fixed": dict(spec.fixed),
                    }
                )
    return out


# --------------------------------------------------------------------------- one task
class TaskFailed(RuntimeError):
    """Some tasks of a sweep raised; ``failures`` maps task id to the error text."""

    def __init__(self, failures: dict[str, str], result: SweepResult | None = None) -> None:
        self.failures = failures
        self.result = result
        first = next(iter(failures.items()))
        super().__init__(
            f"{len(failures)} task(s) failed (re-run the sweep to retry only those); "
            f"first: {first[0]}: {first[1]}"
        )


def read_summary(task_dir: str | os.PathLike, task: Mapping[str, Any] | None = None) -> dict | None:
    """The complete summary of a finished task, or ``None`` if it is absent or incomplete.

    A summary counts as complete when it parses, says ``"complete": true`` and (if ``task``
    is given) records exactly this task.
    """
    from gonio.io.jsonfile import read_json

    p = Path(task_dir) / SUMMARY
    try:
        data = read_json(p)
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("complete") is not True:
        return None
    if task is not None and _canonical(data.get("task")) != _canonical(dict(task)):
        return None
    return data


def _clean_metrics(metrics: Any, tid: str) -> dict[str, Any]:
    if not isinstance(metrics, Mapping):
        raise ValueError(f"task {tid}: the task function must return a dict, got {metrics!r}")
    out = {}
    for k, v in metrics.items():
        if isinstance(v, np.generic):
            v = v.item()
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"task {tid}: metric {k!r} is not finite ({v!r})")
        if not _is_scalar(v) and v is not None:
            raise ValueError(f"task {tid}: metric {k!r} must be a scalar, got {type(v).__name__}")
        out[str(k)] = v
    return out


class _TaskMalloc:
    """Context manager: glibc's default heap behaviour for the task inside a Dask worker.

    A Dask nanny starts its workers with ``MALLOC_TRIM_THRESHOLD_=65536`` (the
    ``distributed.nanny.pre-spawn-environ`` default). Setting that variable also switches off
    glibc's dynamic mmap threshold, so every array above 128 KiB is a fresh ``mmap`` whose pages
    fault in again on each use: measured here, one campaign task ran 1.6-2.6x slower (16x the
    minor page faults, 9x the system time) in such a process. When the variable is set, this
    raises the mmap and trim thresholds (``mallopt``) for the task's duration and afterwards
    restores the worker's settings and returns the freed memory (``malloc_trim``). A no-op
    when the variable is unset (in-process, process pool, gonio's own LocalCluster) or without
    glibc.
    """

    _M_TRIM_THRESHOLD = -1
    _M_MMAP_THRESHOLD = -3

    def __enter__(self) -> _TaskMalloc:
        self._libc = None
        trim = os.environ.get("MALLOC_TRIM_THRESHOLD_")
        if not trim or not trim.isdigit():
            return self
        try:
            import ctypes

            libc = ctypes.CDLL(None)
            mallopt, malloc_trim = libc.mallopt, libc.malloc_trim
        except (OSError, AttributeError):
            return self
        self._libc = (mallopt, malloc_trim, int(trim))
        mallopt(self._M_MMAP_THRESHOLD, 32 * 1024 * 1024)  # glibc's dynamic maximum
        mallopt(self._M_TRIM_THRESHOLD, 128 * 1024 * 1024)
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._libc is None:
            return
        mallopt, malloc_trim, trim = self._libc
        mmap = os.environ.get("MALLOC_MMAP_THRESHOLD_", "")
        mallopt(self._M_MMAP_THRESHOLD, int(mmap) if mmap.isdigit() else 128 * 1024)
        mallopt(self._M_TRIM_THRESHOLD, trim)
        malloc_trim(0)


def run_task(
    task: Mapping[str, Any],
    root: str | os.PathLike,
    fn: TaskFn | str | None = None,
    raw: str = "none",
) -> dict[str, Any]:
    """Run one task idempotently under ``root/tasks/<task id>`` and return its summary.

    If the task's complete ``sweep_task.json`` exists it is returned without running anything
    (with ``"skipped": True`` added to the returned dict, never to the file). Otherwise ``fn``
    (default: the task's registered function) runs in a fresh temporary folder; its metrics
    and wall time go to ``sweep_task.json`` (written atomically) and the folder is renamed into
    place. If another worker finished the same task meanwhile, its result wins and ours is
    discarded.

    ``raw`` says what the finished task keeps of the raw frames in its folder's ``raw``
    sub-folder, where a campaign writes them (:func:`gonio.campaign.raw.keep_raw`: ``"none"``
    removes them, ``"compressed"`` re-encodes them losslessly, ``"keep"`` leaves them): a
    sweep needs the results, and a 24-task campaign sweep kept 400 MB of frames. It is
    applied before the folder moves into place; a finished task is recognised by its
    ``sweep_task.json`` alone, so a re-run skips it whatever it kept. The summary records
    ``raw`` and the folder's ``disk_bytes``.
    """
    _check_raw(raw, "raw")
    task = dict(task)
    tid = task_id(task)
    tasks_dir = Path(root) / "tasks"
    final = tasks_dir / tid
    done = read_summary(final, task)
    if done is not None:
        return {**done, "skipped": True}
    if fn is None:
        fn = get_task(task["task"])
    elif isinstance(fn, str):
        fn = get_task(fn)
    tasks_dir.mkdir(parents=True, exist_ok=True)
    tmp = tasks_dir / f".{tid}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    tmp.mkdir()
    try:
        t0 = time.perf_counter()
        with _SingleThreadBLAS(), _TaskMalloc():
            metrics = _clean_metrics(fn(task, tmp), tid)
        wall = time.perf_counter() - t0
        keep_raw(tmp, raw)
        summary = {
            "task_id": tid,
            "task": task,
            "metrics": metrics,
            "wall_s": wall,
            "raw": raw,
            "disk_bytes": disk_usage(tmp)["total"],
            "host": os.uname().nodename,
            "pid": os.getpid(),
            "complete": True,
        }
        atomic_write_bytes(tmp / SUMMARY, (json.dumps(summary, indent=2) + "\n").encode())
        if final.exists() and read_summary(final, task) is None:
            # an incomplete folder (not made by run_task, e.g. copied by hand): move it aside
            final.rename(tasks_dir / f".{tid}.stale-{uuid.uuid4().hex[:8]}")
        try:
            os.rename(tmp, final)
        except OSError:
            other = read_summary(final, task)
            if other is None:
                raise
            shutil.rmtree(tmp, ignore_errors=True)
            return {**other, "skipped": True}
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return {**summary, "skipped": False}


class _ByValue:
    """A task function shipped to Dask workers as cloudpickle bytes.

    Dask pickles a task's arguments with plain :mod:`pickle` (by reference), so a function
    from a module the workers cannot import — a user's script, a test module registered with
    ``cloudpickle.register_pickle_by_value`` — would fail to load there ("No module named
    ..."); cloudpickle ships such functions by value.
    """

    def __init__(self, fn: TaskFn) -> None:
        import cloudpickle

        self.data = cloudpickle.dumps(fn)

    def load(self) -> TaskFn:
        import cloudpickle

        return cloudpickle.loads(self.data)


def _run_task_entry(
    task: dict, root: str, fn: TaskFn | str | _ByValue | None, raw: str = "none"
) -> dict:
    """Picklable entry point for worker processes: returns the summary or an error record."""
    import traceback

    try:
        if isinstance(fn, _ByValue):
            fn = fn.load()
        return run_task(task, root, fn, raw)
    except Exception as exc:  # reported per task, the sweep carries on
        return {
            "task_id": task_id(task),
            "error": f"{type(exc).__name__}: {exc}",
            "traceback": traceback.format_exc(),
        }


# --------------------------------------------------------------------------- executors
@dataclass
class SweepResult:
    """What :func:`run_sweep` returns and writes."""

    spec: SweepSpec
    root: Path
    rows: list[dict[str, Any]]
    timings: list[dict[str, Any]]
    wall_s: float
    executor: str
    n_run: int
    n_skipped: int
    startup_s: float = 0.0  # of that wall time: starting a LocalCluster / connecting
    files: dict[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The ``sweep.json`` / ``--json`` content."""
        return {
            "spec": self.spec.to_dict(),
            "executor": self.executor,
            "wall_s": self.wall_s,
            "startup_s": self.startup_s,
            "n_tasks": len(self.rows),
            "n_run": self.n_run,
            "n_skipped": self.n_skipped,
            "task_wall_s": sum(t["wall_s"] for t in self.timings if not t["skipped"]),
            "rows": self.rows,
            "aggregate": aggregate(self.rows, self.spec),
            "files": self.files,
        }


def _run_inprocess(tasks, root, fn, progress, raw):
    for t in tasks:
        res = _run_task_entry(t, root, fn, raw)
        progress(res)
        yield res


def _pool_worker(parent: int) -> None:
    """A sweep worker ends with the process that started it
    (:func:`gonio.campaign.executor.die_with_parent`). Without it, a parent ended by a
    signal it does not handle (``kill`` of a script that calls :func:`run_sweep`) left its
    workers waiting forever on the pool's queue, re-parented to init: two were found
    46 minutes after such a kill."""
    from gonio.campaign.executor import die_with_parent

    die_with_parent(parent)


def _run_process(tasks, root, fn, workers, retries, progress, raw):
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    pending = {task_id(t): t for t in tasks}
    attempts = 0
    while pending:
        broken = False
        with ProcessPoolExecutor(max_workers=workers, initializer=_pool_worker,
                                 initargs=(os.getpid(),)) as pool:  # fmt: skip
            futs = {
                pool.submit(_run_task_entry, t, root, fn, raw): tid for tid, t in pending.items()
            }
            try:
                for fut in as_completed(futs):
                    tid = futs[fut]
                    try:
                        res = fut.result()
                    except BrokenProcessPool:
                        broken = True
                        continue
                    pending.pop(tid, None)
                    progress(res)
                    yield res
            except BaseException:  # Ctrl-C, SIGTERM: the queued tasks cancelled, workers ended
                workers_left = list((pool._processes or {}).values())  # (public in 3.14 only)
                pool.shutdown(wait=False, cancel_futures=True)
                for proc in workers_left:
                    proc.kill()  # (a task's unfinished folder is removed by the next run)
                raise
        if broken:
            attempts += 1
            if attempts > retries:
                for tid in list(pending):
                    yield {"task_id": tid, "error": "worker process died (pool broken)"}
                return


# Dask settings gonio applies to the clusters it starts (and that tests/benchmarks can use):
DASK_CONFIG: dict[str, Any] = {
    # SpecCluster closes a worker's nanny for good when no worker of that name is registered
    # this long after a worker was removed. The timer is not cancelled when the nanny restarts
    # the worker, so a timer left from an earlier worker death fires during a later restart and
    # shuts the nanny down: the cluster ends with no workers and every queued task waits
    # forever (the hang of the worker-loss tests; reproduced with two worker deaths 15 s apart,
    # and a restart slower than 15 s on a loaded machine does the same). Nannies are gonio's
    # own here: they restart their workers for the life of the cluster.
    "distributed.deploy.lost-worker-timeout": "7 days",
    # tasks waiting with no worker at all fail after this (the scheduler's side of the timeout)
    "distributed.scheduler.no-workers-timeout": "60s",
    # see _TaskMalloc: keep glibc's dynamic mmap threshold in the workers
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
}


@contextlib.contextmanager
def dask_local_cluster(n_workers: int = 2, **cluster_kwargs: Any) -> Iterator[Any]:
    """A Dask ``LocalCluster`` of ``n_workers`` single-threaded processes and its ``Client``.

    Runs with :data:`DASK_CONFIG` in force and restores this process's environment on exit
    (a nanny writes its workers' ``pre-spawn-environ`` into the process that runs it, here
    ours, on every worker (re)start). Closing is bounded by timeouts.

    Examples
    --------
    >>> with dask_local_cluster(2) as client:  # doctest: +SKIP
    ...     run_sweep(spec, "out", executor="dask", client=client)
    """
    try:
        import dask
        from distributed import Client, LocalCluster
    except ImportError:
        raise _no_dask() from None
    if int(n_workers) < 1:
        raise ValueError(f"n_workers must be >= 1, got {n_workers!r}")
    environ = dict(os.environ)
    # loopback only: the scheduler and its dashboard are not reachable from other machines
    kwargs = {
        "threads_per_worker": 1,
        "processes": True,
        "host": "127.0.0.1",
        "dashboard_address": "127.0.0.1:0",
    }
    kwargs.update(cluster_kwargs)
    with dask.config.set(DASK_CONFIG):
        cluster = LocalCluster(n_workers=int(n_workers), **kwargs)
        try:
            client = Client(cluster, timeout="60s")
            try:
                yield client
            finally:
                client.close(timeout=30)
        finally:
            cluster.close(timeout=60)
            os.environ.clear()
            os.environ.update(environ)


def _no_dask() -> ValueError:
    return ValueError(
        "the Dask executor needs the optional dependency dask[distributed]; "
        "install it with: pip install 'gonio[distributed]'"
    )


def _run_dask(tasks, root, fn, client, progress, no_workers_timeout, raw):
    """Submit every task; yield summaries (or error records) as they finish.

    Bounded everywhere: waits poll every 2 s (or half the timeout); a result whose worker is
    lost while it is fetched is fetched again after Dask recomputes it (the recomputation
    finds the task's folder and returns at once); when the cluster has had no worker for
    ``no_workers_timeout`` seconds, the remaining tasks are cancelled and reported as failed.
    """
    from distributed import wait

    futs = {}
    ship = _ByValue(fn) if callable(fn) else fn
    for t in tasks:
        tid = task_id(t)
        key = f"gonio-sweep-{tid}-{uuid.uuid4().hex[:8]}"
        futs[client.submit(_run_task_entry, t, root, ship, raw, key=key, pure=False)] = tid
    pending = set(futs)
    poll = min(2.0, no_workers_timeout / 2)
    no_workers_since: float | None = None
    try:
        while pending:
            try:
                done, _ = wait(list(pending), timeout=poll, return_when="FIRST_COMPLETED")
            except TimeoutError:
                done = set()
            for fut in done:
                if fut.status == "finished":
                    try:
                        res = fut.result(timeout=30)
                    except TimeoutError:  # its worker died during the fetch: recomputed
                        continue
                    except Exception as exc:
                        res = {"task_id": futs[fut], "error": f"{type(exc).__name__}: {exc}"}
                elif fut.status in ("error", "cancelled"):
                    try:
                        exc = fut.exception(timeout=30)
                    except Exception as err:  # cancelled
                        exc = err
                    # KilledWorker: the task's worker died `allowed-failures` times
                    res = {"task_id": futs[fut], "error": f"{type(exc).__name__}: {exc}"}
                else:  # lost again meanwhile
                    continue
                pending.discard(fut)
                progress(res)
                yield res
            if not pending or done:
                no_workers_since = None
                continue
            try:
                n_workers = len(client.nthreads())
            except Exception:  # scheduler unreachable: count as no workers
                n_workers = 0
            now = time.monotonic()
            if n_workers:
                no_workers_since = None
            elif no_workers_since is None:
                no_workers_since = now
            elif now - no_workers_since > no_workers_timeout:
                msg = f"no Dask worker for {no_workers_timeout:g} s; task not run"
                for fut in sorted(pending, key=lambda f: futs[f]):
                    res = {"task_id": futs[fut], "error": msg}
                    progress(res)
                    yield res
                return
    finally:
        if pending:
            client.cancel(list(pending))


def run_sweep(
    spec: SweepSpec | str | os.PathLike,
    root: str | os.PathLike,
    *,
    executor: str = "inprocess",
    workers: int | None = None,
    scheduler: str | None = None,
    dask_local: int | None = None,
    client: Any = None,
    retries: int = 2,
    fn: TaskFn | str | None = None,
    plot: bool = True,
    progress: Callable[[dict], None] | None = None,
    no_workers_timeout: float = 60.0,
    raw: str | None = None,
) -> SweepResult:
    """Run every task of ``spec`` under ``root`` and gather the results table.

    Parameters
    ----------
    spec
        A :class:`SweepSpec` or the path of a spec file.
    root
        Results folder: ``tasks/<id>/`` per task, then ``results.csv``, ``results.json``,
        ``aggregate.csv``, ``timings.csv``, ``sweep.json`` and ``summary.png``.
    executor
        ``"inprocess"``, ``"process"`` or ``"dask"``.
    workers
        Process count for ``"process"`` (default: CPU count).
    scheduler, dask_local, client
        For ``"dask"``: a scheduler address, or a number of ``LocalCluster`` workers to
        start, or an existing ``distributed.Client``. With a remote scheduler, ``root`` must
        be on a file system every worker shares (the tasks write their folders there) and
        gonio (plus any ``"module:function"`` task) must be installed on the workers.
    retries
        How often a failed task (or, for ``"process"``, a broken pool) is retried.
    fn
        Override the task function (a callable or ``"module:function"``); by default the
        spec's task is looked up in the registry.
    plot
        Write ``summary.png``.
    progress
        Called with each task's summary (or error record) as it completes (tasks finished
        by an earlier run first, without being submitted anywhere).
    no_workers_timeout
        For ``"dask"``: seconds the cluster may have no worker at all while tasks wait; then
        the waiting tasks fail (and are retried ``retries`` times) instead of waiting forever.
    raw
        What each task run now keeps of its raw frames (see :func:`run_task`); default the
        spec's ``raw`` (``"none"`` unless it says otherwise).

    Raises
    ------
    TaskFailed
        When some tasks failed; the finished ones are kept (and gathered into the tables with
        the failures listed), so a re-run only repeats the failed ones.
    """
    if not isinstance(spec, SweepSpec):
        spec = load_spec(spec)
    _check_run_options(executor, scheduler, dask_local, client, retries, no_workers_timeout)
    raw = _check_raw(spec.raw if raw is None else raw, "raw")
    root = Path(root).resolve()  # workers elsewhere resolve relative paths differently
    root.mkdir(parents=True, exist_ok=True)
    tasks = expand(spec)
    progress = progress or (lambda _res: None)
    t0 = time.perf_counter()
    startup = 0.0
    w = 1
    if executor == "process":
        w = int(workers or os.cpu_count() or 1)
        if w < 1:
            raise ValueError(f"workers must be >= 1, got {workers!r}")
    results, todo = _finished_before(tasks, root, progress)
    stack = contextlib.ExitStack()
    if executor == "dask" and client is None and todo:
        client = _open_dask_client(stack, scheduler, dask_local)
        startup = time.perf_counter() - t0

    def execute(batch: list[dict]) -> Iterator[dict]:
        if executor == "inprocess":
            return _run_inprocess(batch, str(root), fn, progress, raw)
        if executor == "process":
            return _run_process(batch, str(root), fn, w, retries, progress, raw)
        return _run_dask(batch, str(root), fn, client, progress, no_workers_timeout, raw)

    with stack:
        _run_with_retries(execute, todo, results, retries)
    wall = time.perf_counter() - t0

    rows, timings, failures = _gather(tasks, results)
    n_skipped = sum(t["skipped"] for t in timings)
    result = SweepResult(
        spec=spec,
        root=root,
        rows=rows,
        timings=timings,
        wall_s=wall,
        executor=executor,
        n_run=len(timings) - n_skipped,
        n_skipped=n_skipped,
        startup_s=startup,
    )
    _write_outputs(result, plot=plot, failures=failures)
    if failures:
        raise TaskFailed(failures, result)
    for leftover in (root / "tasks").glob(".*.tmp-*"):
        shutil.rmtree(leftover, ignore_errors=True)  # debris of killed workers
    return result


def _check_run_options(
    executor: str,
    scheduler: str | None,
    dask_local: int | None,
    client: Any,
    retries: int,
    no_workers_timeout: float,
) -> None:
    """:func:`run_sweep`'s executor options checked before anything is written."""
    if executor not in EXECUTORS:
        raise ValueError(f"executor must be one of {EXECUTORS}, got {executor!r}")
    if executor != "dask" and (scheduler or dask_local or client is not None):
        raise ValueError(f"scheduler/dask_local/client need executor='dask', got {executor!r}")
    if retries < 0:
        raise ValueError(f"retries must be >= 0, got {retries!r}")
    if not (isinstance(no_workers_timeout, int | float) and no_workers_timeout > 0):
        raise ValueError(f"no_workers_timeout must be > 0 seconds, got {no_workers_timeout!r}")


def _finished_before(
    tasks: list[dict], root: Path, progress: Callable[[dict], None]
) -> tuple[dict[str, dict], list[dict]]:
    """The results of tasks an earlier run finished (reported to ``progress``), and the rest.

    Finished tasks are read here and never submitted: a re-run costs no executor round
    trips, and "skipped" means exactly "finished before this sweep started".
    """
    results: dict[str, dict] = {}
    todo = []
    for t in tasks:
        tid = task_id(t)
        done = read_summary(Path(root) / "tasks" / tid, t)
        if done is None:
            todo.append(t)
        else:
            results[tid] = {**done, "skipped": True}
            progress(results[tid])
    return results, todo


def _open_dask_client(
    stack: contextlib.ExitStack, scheduler: str | None, dask_local: int | None
) -> Any:
    """A ``distributed.Client`` on ``scheduler``, or on a local cluster, closed by ``stack``."""
    if scheduler:
        try:
            from distributed import Client
        except ImportError:
            raise _no_dask() from None
        return stack.enter_context(Client(scheduler, timeout="60s"))
    return stack.enter_context(dask_local_cluster(int(dask_local or 2)))


def _run_with_retries(
    execute: Callable[[list[dict]], Iterator[dict]],
    todo: list[dict],
    results: dict[str, dict],
    retries: int,
) -> None:
    """Run ``todo`` through ``execute`` into ``results``, then re-run failed tasks ``retries``
    times.

    A task that raised (or whose worker was lost too often) is run again; finished tasks are
    never repeated (run_task skips them).
    """

    def collect(batch: list[dict]) -> None:
        for r in execute(batch):
            if r.get("skipped"):
                # finished during this sweep: Dask recomputed a result lost with its worker,
                # or two workers raced; the folder's record is the one run that counts
                r = {**r, "skipped": False}
            results[r["task_id"]] = r

    if todo:
        collect(todo)
    for _ in range(retries):
        again = [t for t in todo if "error" in results.get(task_id(t), {"error": ""})]
        if not again:
            break
        collect(again)


def _gather(
    tasks: list[dict], results: Mapping[str, dict]
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], dict[str, str]]:
    """The results table's rows, the timings and the failures (task id -> error), in grid
    order."""
    rows, timings, failures = [], [], {}
    for t in tasks:
        tid = task_id(t)
        r = results.get(tid) or {"error": "no result returned"}
        if "error" in r:
            failures[tid] = r["error"]
            continue
        rows.append(_row(t, tid, r["metrics"]))
        timings.append(
            {
                "task_id": tid,
                "wall_s": r["wall_s"],
                "skipped": bool(r.get("skipped")),
                "host": r.get("host", ""),
                "pid": r.get("pid", 0),
            }
        )
    return rows, timings, failures


def _row(task: Mapping[str, Any], tid: str, metrics: Mapping[str, Any]) -> dict[str, Any]:
    row: dict[str, Any] = {"task_id": tid, "material": task["material"]}
    for k, v in task["settings"].items():
        row[k] = v if _is_scalar(v) else json.dumps(v, sort_keys=True)
    row["seed"] = task["seed"]
    row.update(metrics)
    return row


# --------------------------------------------------------------------------- outputs
def _csv_bytes(rows: Sequence[Mapping[str, Any]]) -> bytes:
    cols: list[str] = []
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow([_cell(r.get(c, "")) for c in cols])
    return buf.getvalue().encode()


def _cell(v: Any) -> str:
    if isinstance(v, bool) or v is None:
        return "" if v is None else str(v).lower()
    if isinstance(v, float):
        return repr(v)
    return str(v)


def aggregate(rows: Sequence[Mapping[str, Any]], spec: SweepSpec) -> list[dict[str, Any]]:
    """Mean, sample standard deviation and count of every numeric metric over the seeds.

    One output row per (material, settings) group, in grid order.
    """
    keys = ["material", *spec.settings]
    groups: dict[tuple, list[Mapping[str, Any]]] = {}
    for r in rows:
        groups.setdefault(tuple(json.dumps(r.get(k), sort_keys=True) for k in keys), []).append(r)
    out = []
    for members in groups.values():
        rec: dict[str, Any] = {k: members[0].get(k) for k in keys}
        rec["n"] = len(members)
        metric_names = [
            k
            for k in members[0]
            if k not in keys
            and k not in ("task_id", "seed")
            and isinstance(members[0][k], int | float)
            and not isinstance(members[0][k], bool)
        ]
        for m in metric_names:
            vals = np.array([float(x[m]) for x in members if isinstance(x.get(m), int | float)])
            rec[f"{m}_mean"] = float(vals.mean())
            rec[f"{m}_std"] = float(vals.std(ddof=1)) if len(vals) > 1 else 0.0
        out.append(rec)
    return out


def _headline_metric(spec: SweepSpec, rows: Sequence[Mapping[str, Any]]) -> str | None:
    if spec.plot:
        return spec.plot
    entry = _TASKS.get(spec.task)
    if entry is not None and entry.metric:
        return entry.metric
    skip = {"task_id", "material", "seed", *spec.settings}
    for k, v in (rows[0] if rows else {}).items():
        if k not in skip and isinstance(v, int | float) and not isinstance(v, bool):
            return k
    return None


def plot_summary(
    rows: Sequence[Mapping[str, Any]], spec: SweepSpec, path: str | os.PathLike, metric: str
) -> Path:
    """Error-bar plot of ``metric`` (mean ± std over seeds) per material and setting (PNG)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    agg = aggregate(rows, spec)
    if agg and f"{metric}_mean" not in agg[0]:
        raise ValueError(f"plot metric {metric!r} is not a numeric column of the results")
    mats = list(dict.fromkeys(a["material"] for a in agg))
    combos = list(dict.fromkeys(tuple((k, a[k]) for k in spec.settings) for a in agg))
    fig, ax = plt.subplots(figsize=(max(6.0, 0.9 * len(mats) + 3), 4.5))
    width = 0.8 / max(len(combos), 1)
    for j, combo in enumerate(combos):
        sel = [a for a in agg if tuple((k, a[k]) for k in spec.settings) == combo]
        xs = [mats.index(a["material"]) + (j - (len(combos) - 1) / 2) * width for a in sel]
        label = ", ".join(f"{k}={v}" for k, v in combo) or "all"
        ax.errorbar(
            xs,
            [a[f"{metric}_mean"] for a in sel],
            yerr=[a[f"{metric}_std"] for a in sel],
            fmt="o",
            capsize=3,
            label=label,
        )
    ax.set_xlim(-0.6, len(mats) - 0.4)
    ax.set_xticks(range(len(mats)))
    ax.set_xticklabels(mats, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel(f"{metric} (mean ± std over {len(spec.seeds)} seeds)")
    ax.set_title(f"sweep {spec.name}: {spec.task}")
    vals = [a[f"{metric}_mean"] for a in agg]
    if vals and min(vals) > 0 and max(vals) / min(vals) > 50:
        ax.set_yscale("log")
    if combos and len(combos) > 1:
        ax.legend(fontsize=7)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return atomic_write_bytes(path, buf.getvalue())


def _write_outputs(result: SweepResult, *, plot: bool, failures: dict[str, str]) -> None:
    root = result.root
    files = {
        "results_csv": str(atomic_write_bytes(root / "results.csv", _csv_bytes(result.rows))),
        "results_json": str(
            atomic_write_bytes(
                root / "results.json",
                (json.dumps({"rows": result.rows}, indent=2, allow_nan=False) + "\n").encode(),
            )
        ),
        "aggregate_csv": str(
            atomic_write_bytes(
                root / "aggregate.csv", _csv_bytes(aggregate(result.rows, result.spec))
            )
        ),
        "timings_csv": str(atomic_write_bytes(root / "timings.csv", _csv_bytes(result.timings))),
    }
    metric = _headline_metric(result.spec, result.rows)
    plot_error = ""
    if plot and result.rows and metric:
        try:
            files["summary_png"] = str(
                plot_summary(result.rows, result.spec, root / "summary.png", metric)
            )
        except ValueError as exc:  # e.g. the spec's 'plot' names no metric of the task:
            plot_error = str(exc)  # the tables are written; only the plot is missing
    result.files = files
    doc = result.to_dict()
    doc["failures"] = failures
    if plot_error:
        doc["plot_error"] = plot_error
    files["sweep_json"] = str(root / "sweep.json")
    atomic_write_bytes(root / "sweep.json", (json.dumps(doc, indent=2) + "\n").encode())


# --------------------------------------------------------------------------- built-in tasks
def _fit_preset_task(task: dict[str, Any], out_dir: Path) -> dict[str, Any]:
    from gonio.diagnostics.bench import fit_preset

    return fit_preset(task, out_dir)


def _fit_preset_validate(task: dict[str, Any]) -> None:
    from gonio.diagnostics.bench import fit_preset_options

    fit_preset_options(task)


def _campaign_plan(task: Mapping[str, Any]) -> Any:
    """The resolved :class:`gonio.campaign.Plan` of a ``campaign`` task."""
    try:
        from gonio.campaign import Plan
    except ImportError as exc:
        raise ValueError(
            f"task 'campaign' needs gonio.campaign, which is not available ({exc})"
        ) from None
    opts = {"plots": False, **dict(task.get("fixed", {})), **dict(task.get("settings", {}))}
    for k in ("material", "seed"):
        if k in opts:
            raise ValueError(f"campaign: {k!r} is a grid axis; give it as 'materials'/'seeds'")
    try:
        plan = Plan.from_dict({**opts, "material": task["material"], "seed": int(task["seed"])})
        return plan.resolved()
    except TypeError as exc:
        raise ValueError(f"campaign: bad plan field ({exc})") from None


def _campaign_validate(task: dict[str, Any]) -> None:
    _campaign_plan(task)


def _campaign_task(task: dict[str, Any], out_dir: Path) -> dict[str, Any]:
    """One :func:`gonio.campaign.run` per grid point; its results directory is ``out_dir``.

    Options (``fixed`` and ``settings``) are :class:`gonio.campaign.Plan` fields (``mirror``,
    ``theta_i_deg``, ``rotations_deg``, ``exposures_s``, ``noise``, ``residual``, ``model``,
    ``plots`` (default off here), ...). Metrics: ``rel_err_<param>`` (the campaign's
    ``relative_error``), ``max_rel_err``, ``rms_log_brdf`` of the fitted model against the
    preset over :func:`gonio.diagnostics.bench.error_directions`, the fit's ``rms``,
    ``rms_relative``, ``chi2_dof``, ``converged`` and ``n_samples``.
    """
    from gonio import campaign, materials
    from gonio.diagnostics.bench import brdf_errors

    plan = _campaign_plan(task)
    res = campaign.run(plan, out_dir, quiet=True)
    summ = res.summary
    out: dict[str, Any] = {}
    rel = {k: float(v) for k, v in summ.get("relative_error", {}).items()}
    for k, v in rel.items():
        out[f"rel_err_{k}"] = v
    if rel:
        out["max_rel_err"] = max(rel.values())
    truth = materials.get(task["material"])
    out["rms_log_brdf"] = brdf_errors(truth, res.fit.model, {}, {})["rms_log_brdf"]
    for k in ("rms", "rms_relative", "chi2_dof"):
        v = summ.get(k)
        out[k] = float(v) if isinstance(v, int | float) and math.isfinite(v) else None
    out["converged"] = bool(summ.get("converged"))
    out["n_samples"] = int(summ.get("n_samples", 0))
    return out


register_task(
    "fit_preset",
    _fit_preset_task,
    validate=_fit_preset_validate,
    metric="rms_log_brdf",
    doc="simulate noisy samples of a material preset on a fixed direction design and fit them",
)
register_task(
    "campaign",
    _campaign_task,
    validate=_campaign_validate,
    metric="rms_log_brdf",
    doc="a full gonio campaign (plan, capture, reduce, fit) per grid point",
)
