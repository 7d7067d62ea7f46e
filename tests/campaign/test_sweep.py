"""Tests of gonio.campaign.sweep: spec parsing, idempotent tasks, and the three executors."""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gonio.campaign import sweep

SPEC = {
    "name": "t",
    "task": "fit_preset",
    "materials": ["rolled_brass", "rolled_aluminum"],
    "seeds": 2,
    "settings": {"noise": [0.01, 0.05]},
    "fixed": {"n_samples": 60},
}


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


# ----------------------------------------------------------------------------- custom tasks
def counting_task(task: dict, out_dir: Path) -> dict:
    """Counts its executions in marker files; fails or kills its process on request."""
    state = Path(task["fixed"]["state"])
    tid = sweep.task_id(task)
    n = len(list(state.glob(f"{tid}.run*")))
    (state / f"{tid}.run{n}-{os.getpid()}").touch()
    (out_dir / "result.txt").write_text(f"{task['seed']}\n")
    mode = task["settings"].get("mode", "ok")
    if n == 0 and mode == "fail_once":
        raise RuntimeError(f"planned failure of {tid}")
    if n == 0 and mode == "die_once":
        os._exit(13)  # the worker process dies mid-task
    return {"value": float(task["seed"]) * 1.5, "square": float(task["seed"] ** 2)}


def blas_task(task: dict, out_dir: Path) -> dict:
    """A multi-threaded-BLAS-sized dot product: its rounding depends on the thread count."""
    rng = np.random.default_rng(task["seed"])
    x = rng.standard_normal(2_000_000)
    return {"dot": float(x @ x), "norm": float(np.linalg.norm(rng.standard_normal((300, 300))))}


def _runs(state: Path, tid: str) -> int:
    return len(list(state.glob(f"{tid}.run*")))


def _custom_spec(state: Path, modes=("ok",), seeds=4) -> sweep.SweepSpec:
    return sweep.spec_from_dict(
        {
            "task": "custom",
            "materials": ["m"],
            "seeds": seeds,
            "settings": {"mode": list(modes)},
            "fixed": {"state": str(state)},
        }
    )


sweep.register_task("custom", counting_task, metric="value")


# ----------------------------------------------------------------------------- specs
def test_toml_and_json_specs_agree(tmp_path):
    toml = _write(
        tmp_path,
        "s.toml",
        'name = "t"\ntask = "fit_preset"\nmaterials = ["rolled_brass", "rolled_aluminum"]\n'
        "seeds = 2\n[settings]\nnoise = [0.01, 0.05]\n[fixed]\nn_samples = 60\n",
    )
    js = _write(tmp_path, "s.json", json.dumps(SPEC))
    a, b = sweep.load_spec(toml), sweep.load_spec(js)
    assert a.to_dict() == b.to_dict()
    tasks = sweep.expand(a)
    assert a.n_tasks == len(tasks) == 8
    assert [t["seed"] for t in tasks[:4]] == [0, 1, 0, 1]
    assert tasks[0] == {
        "task": "fit_preset",
        "material": "rolled_brass",
        "seed": 0,
        "settings": {"noise": 0.01},
        "fixed": {"n_samples": 60},
    }
    ids = [sweep.task_id(t) for t in tasks]
    assert len(set(ids)) == len(ids)
    assert ids == [sweep.task_id(t) for t in sweep.expand(b)]
    assert ids[0].startswith("rolled_brass-s0-")


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({**SPEC, "materail": ["x"]}, r"unknown key\(s\) \['materail'\]"),
        ({k: v for k, v in SPEC.items() if k != "seeds"}, "missing required key 'seeds'"),
        ({**SPEC, "task": "nope"}, "unknown task 'nope'; registered tasks are"),
        ({**SPEC, "materials": []}, "'materials' must be a non-empty list"),
        ({**SPEC, "materials": ["rolled_brass", "rolled_brass"]}, "lists a material twice"),
        ({**SPEC, "materials": ["unobtainium"]}, "material 'unobtainium' is not a preset"),
        ({**SPEC, "seeds": 0}, r"'seeds' as a count must be in \[1, 100000\], got 0"),
        ({**SPEC, "seeds": [1, -2]}, "integers >= 0, got -2"),
        ({**SPEC, "seeds": [1, 1]}, "lists a seed twice"),
        ({**SPEC, "settings": {"noise": 0.1}}, "settings.noise must be a non-empty list"),
        ({**SPEC, "settings": {"seed": [1]}}, "clashes with the grid axis 'seed'"),
        ({**SPEC, "settings": {"noise": [1.5]}}, r"noise must be a number in \[0, 1\), got 1.5"),
        ({**SPEC, "fixed": {"n_samples": 60, "bogus": 1}}, r"unknown option\(s\) \['bogus'\]"),
        ({**SPEC, "fixed": {"noise": 0.1}}, "appear in both"),
        ({**SPEC, "settings": {"residual": ["l2"]}}, "residual must be one of"),
        ([1, 2], "the document is a list, expected an object"),
        ({**SPEC, "task": "no_such_module_x:f"}, "unknown task 'no_such_module_x:f'"),
        ({**SPEC, "task": "this:s"}, "unknown task 'this:s'"),  # imports nothing
        ({**SPEC, "name": "/../../escaped"}, "'name' '/../../escaped' must be a plain folder"),
        ({**SPEC, "name": ".."}, "must be a plain folder name"),
        ({**SPEC, "seeds": 100_000_000}, r"'seeds' as a count must be in \[1, 100000\]"),
        ({**SPEC, "seeds": 50_000, "materials": ["a", "b", "c"]}, "the grid has 300000 points"),
        ({**SPEC, "task": 5}, "'task' must be a string, got 5"),
        ({**SPEC, "seeds": 2.5}, "'seeds' must be a count or a non-empty list of integers"),
        ({**SPEC, "seeds": True}, "'seeds' must be a count or a non-empty list of integers"),
        ({**SPEC, "materials": 3}, "'materials' must be a non-empty list of names, got 3"),
        ({**SPEC, "settings": [1]}, "'settings' must be a table of lists"),
        ({**SPEC, "fixed": [1]}, "'fixed' must be a table"),
        ({**SPEC, "settings": {"noise": [None]}}, r"settings.noise\[0\] must be a number"),
        ({**SPEC, "settings": {"noise": [0.1, 0.1]}}, "settings.noise lists a value twice"),
        ({**SPEC, "name": 3}, "'name' must be a string, got 3"),
        ({**SPEC, "plot": 3}, "'plot' must be a string, got 3"),
        (
            {
                "task": "campaign",
                "materials": ["rolled_brass"],
                "seeds": 1,
                "settings": {"mirorr": ["ellipsoid"]},
            },
            r"task rolled_brass-s0-\w+: unknown plan field\(s\) \['mirorr'\]",
        ),
        (
            {
                "task": "campaign",
                "materials": ["rolled_brass"],
                "seeds": 1,
                "settings": {"mirror": ["parabola"]},
            },
            "mirror 'parabola'; expected 'ellipsoid' or 'hemisphere'",
        ),
        (
            {"task": "campaign", "materials": ["unobtainium"], "seeds": 1},
            "unknown material 'unobtainium'",
        ),
        (
            {**SPEC, "raw": "lzw"},
            "'raw' must be one of keep, compressed, none, got 'lzw'",
        ),
    ],
)
def test_bad_specs_name_the_problem(tmp_path, data, match):
    p = _write(tmp_path, "bad.json", json.dumps(data))
    with pytest.raises(ValueError, match=match) as exc:
        sweep.load_spec(p)
    assert "bad.json" in str(exc.value)


def test_bad_spec_files(tmp_path):
    with pytest.raises(ValueError, match="not valid TOML"):
        sweep.load_spec(_write(tmp_path, "a.toml", "task = [unclosed\n"))
    with pytest.raises(ValueError, match="not valid JSON"):
        sweep.load_spec(_write(tmp_path, "a.json", "{'task': 1}"))
    with pytest.raises(ValueError, match=r"expected a .json or .toml file, got suffix '.yaml'"):
        sweep.load_spec(_write(tmp_path, "a.yaml", "task: x"))
    with pytest.raises(ValueError, match="does not exist"):
        sweep.load_spec(tmp_path / "missing.toml")
    with pytest.raises(ValueError, match="is not a file"):
        sweep.load_spec(tmp_path)
    with pytest.raises(ValueError, match="missing required key 'task'"):
        sweep.load_spec(_write(tmp_path, "empty.toml", ""))
    (tmp_path / "bin.json").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ValueError, match=r"bin\.json'?: not valid JSON"):
        sweep.load_spec(tmp_path / "bin.json")
    with pytest.raises(ValueError, match="must be finite"):
        sweep.spec_from_dict({**SPEC, "fixed": {"n_samples": float("nan")}})


def test_example_specs_load():
    root = Path(__file__).resolve().parents[2] / "benchmarks" / "sweeps"
    files = sorted(root.glob("*.toml")) + sorted(root.glob("*.json"))
    assert files
    for f in files:
        spec = sweep.load_spec(f)
        assert spec.n_tasks >= 1


# ----------------------------------------------------------------------------- one task
def test_run_task_is_idempotent_and_atomic(tmp_path):
    state = tmp_path / "state"
    state.mkdir()
    task = sweep.expand(_custom_spec(state, seeds=1))[0]
    tid = sweep.task_id(task)
    s1 = sweep.run_task(task, tmp_path / "out")
    assert s1["skipped"] is False and s1["metrics"] == {"value": 0.0, "square": 0.0}
    final = tmp_path / "out" / "tasks" / tid
    on_disk = json.loads((final / sweep.SUMMARY).read_text())
    assert on_disk["complete"] is True and "skipped" not in on_disk
    assert (final / "result.txt").read_text() == "0\n"
    s2 = sweep.run_task(task, tmp_path / "out")
    assert s2["skipped"] is True and s2["metrics"] == s1["metrics"]
    assert _runs(state, tid) == 1
    # a half-written result (no complete summary) is not trusted: the task runs again
    (final / sweep.SUMMARY).write_text('{"complete": false}')
    s3 = sweep.run_task(task, tmp_path / "out")
    assert s3["skipped"] is False and _runs(state, tid) == 2
    assert sweep.read_summary(final, task)["metrics"] == s1["metrics"]
    # a summary of a different task in this folder does not count either
    assert sweep.read_summary(final, {**task, "seed": 99}) is None


def test_failed_task_leaves_nothing(tmp_path):
    state = tmp_path / "state"
    state.mkdir()
    task = sweep.expand(_custom_spec(state, modes=("fail_once",), seeds=1))[0]
    with pytest.raises(RuntimeError, match="planned failure"):
        sweep.run_task(task, tmp_path / "out")
    assert list((tmp_path / "out" / "tasks").iterdir()) == []
    assert sweep.run_task(task, tmp_path / "out")["metrics"]["value"] == 0.0


def test_task_must_return_finite_scalars(tmp_path):
    task = {"task": "x", "material": "m", "seed": 0, "settings": {}, "fixed": {}}
    with pytest.raises(ValueError, match="metric 'e' is not finite"):
        sweep.run_task(task, tmp_path, lambda t, d: {"e": float("inf")})
    with pytest.raises(ValueError, match="must return a dict"):
        sweep.run_task(task, tmp_path, lambda t, d: 3.0)
    assert list((tmp_path / "tasks").iterdir()) == []


# ----------------------------------------------------------------------------- in-process
def test_inprocess_sweep_outputs(tmp_path):
    spec = sweep.spec_from_dict(SPEC)
    res = sweep.run_sweep(spec, tmp_path)
    assert res.n_run == 8 and res.n_skipped == 0 and len(res.rows) == 8
    for name in ("results.csv", "results.json", "aggregate.csv", "timings.csv", "sweep.json"):
        assert (tmp_path / name).is_file()
    assert (tmp_path / "summary.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = json.loads((tmp_path / "results.json").read_text())["rows"]
    assert [r["task_id"] for r in rows] == [sweep.task_id(t) for t in sweep.expand(spec)]
    # the fit recovers the presets: errors small, and larger at 5 % than at 1 % noise
    agg = {(a["material"], a["noise"]): a for a in sweep.aggregate(rows, spec)}
    for mat in spec.materials:
        lo, hi = agg[(mat, 0.01)]["rms_log_brdf_mean"], agg[(mat, 0.05)]["rms_log_brdf_mean"]
        assert 0 < lo < hi < 0.1
    doc = json.loads((tmp_path / "sweep.json").read_text())
    assert doc["n_tasks"] == 8 and doc["failures"] == {} and len(doc["aggregate"]) == 4
    csv_before = (tmp_path / "results.csv").read_bytes()
    again = sweep.run_sweep(spec, tmp_path)
    assert again.n_run == 0 and again.n_skipped == 8
    assert (tmp_path / "results.csv").read_bytes() == csv_before


def test_plot_metric_that_is_not_a_column(tmp_path):
    # the spec's 'plot' can only be checked against the metrics once tasks ran: the tables
    # are still written and sweep.json says why there is no plot
    state = tmp_path / "state"
    state.mkdir()
    spec = sweep.spec_from_dict(
        {
            "task": "custom",
            "materials": ["m"],
            "seeds": 2,
            "plot": "nope",
            "fixed": {"state": str(state)},
        }
    )
    res = sweep.run_sweep(spec, tmp_path / "out")
    assert len(res.rows) == 2 and not (tmp_path / "out" / "summary.png").exists()
    doc = json.loads((tmp_path / "out" / "sweep.json").read_text())
    assert "plot metric 'nope' is not a numeric column" in doc["plot_error"]


def test_rerun_skips_finished_after_failures(tmp_path):
    state = tmp_path / "state"
    state.mkdir()
    spec = _custom_spec(state, modes=("ok", "fail_once"), seeds=3)
    with pytest.raises(sweep.TaskFailed) as exc:
        sweep.run_sweep(spec, tmp_path / "out", retries=0)
    assert len(exc.value.failures) == 3
    assert all("planned failure" in v for v in exc.value.failures.values())
    assert len(exc.value.result.rows) == 3  # the good half is gathered
    assert json.loads((tmp_path / "out" / "sweep.json").read_text())["failures"]
    res = sweep.run_sweep(spec, tmp_path / "out", retries=0)
    assert res.n_run == 3 and res.n_skipped == 3
    for t in sweep.expand(spec):
        assert _runs(state, sweep.task_id(t)) == (2 if t["settings"]["mode"] == "fail_once" else 1)
    # retries in-process recover without a second invocation
    spec2 = _custom_spec(tmp_path / "state2", modes=("fail_once",), seeds=2)
    (tmp_path / "state2").mkdir()
    assert sweep.run_sweep(spec2, tmp_path / "out2", retries=1).n_run == 2


# ----------------------------------------------------------------------------- processes
def test_process_pool_matches_inprocess(tmp_path):
    spec = sweep.spec_from_dict(SPEC)
    sweep.run_sweep(spec, tmp_path / "a", plot=False)
    sweep.run_sweep(spec, tmp_path / "b", executor="process", workers=2, plot=False)
    assert (tmp_path / "a" / "results.csv").read_bytes() == (
        tmp_path / "b" / "results.csv"
    ).read_bytes()


def test_process_pool_recovers_from_a_dead_worker(tmp_path):
    state = tmp_path / "state"
    state.mkdir()
    spec = _custom_spec(state, modes=("ok", "die_once"), seeds=2)
    res = sweep.run_sweep(spec, tmp_path / "out", executor="process", workers=2, plot=False)
    assert len(res.rows) == 4
    assert [r["value"] for r in res.rows] == [0.0, 1.5, 0.0, 1.5]
    dirs = [d.name for d in (tmp_path / "out" / "tasks").iterdir()]
    assert sorted(dirs) == sorted(sweep.task_id(t) for t in sweep.expand(spec))  # no debris
    for t in sweep.expand(spec):
        if t["settings"]["mode"] == "die_once":
            assert _runs(state, sweep.task_id(t)) >= 2


def test_bad_executor_arguments(tmp_path):
    spec = sweep.spec_from_dict(SPEC)
    with pytest.raises(ValueError, match="executor must be one of"):
        sweep.run_sweep(spec, tmp_path, executor="mpi")
    with pytest.raises(ValueError, match="need executor='dask'"):
        sweep.run_sweep(spec, tmp_path, dask_local=2)


def test_dask_missing_gives_clear_error(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)
    spec = sweep.spec_from_dict(SPEC)
    with pytest.raises(ValueError, match=r"pip install 'gonio\[distributed\]'"):
        sweep.run_sweep(spec, tmp_path, executor="dask", dask_local=2)


# ----------------------------------------------------------------------------- dask
@pytest.fixture(scope="module")
def dask_client():
    pytest.importorskip("distributed")
    import cloudpickle

    # the test module is not importable on the workers: ship its functions by value
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    # gonio's own cluster settings (sweep.DASK_CONFIG): with Dask's defaults a worker death
    # 15 s after an earlier one (or a restart slower than 15 s) closes the nanny for good
    with sweep.dask_local_cluster(2) as client:
        yield client


def _inprocess_and_dask_agree(spec, tmp_path, dask_client):
    """Run ``spec`` in-process (under ``a``) and on Dask (under ``b``): the same rows and
    byte-identical ``results.csv``. Returns both results."""
    a = sweep.run_sweep(spec, tmp_path / "a", plot=False)
    b = sweep.run_sweep(spec, tmp_path / "b", executor="dask", client=dask_client, plot=False)
    assert a.rows == b.rows
    assert (tmp_path / "a" / "results.csv").read_bytes() == (
        tmp_path / "b" / "results.csv"
    ).read_bytes()
    return a, b


def test_dask_localcluster_matches_inprocess(tmp_path, dask_client):
    spec = sweep.spec_from_dict(SPEC)
    a, b = _inprocess_and_dask_agree(spec, tmp_path, dask_client)
    assert len({t["pid"] for t in b.timings}) == 2  # both workers took part
    # the same through a scheduler address (what `gonio sweep --scheduler tcp://...` does)
    addr = dask_client.scheduler.address
    assert addr.startswith("tcp://")
    c = sweep.run_sweep(spec, tmp_path / "c", executor="dask", scheduler=addr, plot=False)
    assert c.rows == a.rows and c.n_run == 8


def test_dask_recovers_from_a_killed_worker(tmp_path, dask_client):
    state = tmp_path / "state"
    state.mkdir()
    spec = _custom_spec(state, modes=("ok", "die_once"), seeds=2)
    res = sweep.run_sweep(
        spec, tmp_path / "out", executor="dask", client=dask_client, fn=counting_task
    )
    assert [r["value"] for r in res.rows] == [0.0, 1.5, 0.0, 1.5]
    # every task ran in this sweep, exactly once to completion (no double or half result)
    assert res.n_run == 4 and res.n_skipped == 0
    assert sorted(d.name for d in (tmp_path / "out" / "tasks").iterdir()) == sorted(
        sweep.task_id(t) for t in sweep.expand(spec)
    )
    # both workers came back (the nannies restarted them and were not closed); a restart
    # may still be registering when the sweep ends on a loaded machine (seen once: 1 of 2)
    dask_client.wait_for_workers(2, timeout=60)
    assert len(dask_client.nthreads()) == 2
    for t in sweep.expand(spec):
        tid = sweep.task_id(t)
        assert sweep.read_summary(tmp_path / "out" / "tasks" / tid, t) is not None
        if t["settings"]["mode"] == "die_once":
            assert _runs(state, tid) >= 2  # the task lost with its worker was run again
    # the same grid in-process (fresh state: no planned deaths left) gives the same table
    state2 = tmp_path / "state2"
    state2.mkdir()
    spec2 = _custom_spec(state2, ("ok", "die_once"), 2)
    for t in sweep.expand(spec2):
        (state2 / f"{sweep.task_id(t)}.run-earlier").touch()
    rows_in = sweep.run_sweep(spec2, tmp_path / "in").rows
    assert [r["value"] for r in rows_in] == [r["value"] for r in res.rows]


def test_single_thread_blas_guard_restores():
    with sweep._SingleThreadBLAS() as guard:
        inside = [get() for get, _ in guard._openblas()]
    after = [get() for get, _ in sweep._SingleThreadBLAS._openblas()]
    assert all(n == 1 for n in inside)
    assert len(after) == len(inside)


def test_dask_tables_identical_for_blas_heavy_tasks(tmp_path, dask_client):
    # Dask workers run BLAS on one thread; run_task does the same everywhere, so the
    # rounding of large reductions matches bit for bit
    spec = sweep.spec_from_dict({"task": "blas", "materials": ["m"], "seeds": 2})
    a = sweep.run_sweep(spec, tmp_path / "a", plot=False)
    b = sweep.run_sweep(
        spec, tmp_path / "b", executor="dask", client=dask_client, plot=False, fn=blas_task
    )
    assert a.rows == b.rows


sweep.register_task("blas", blas_task)


@pytest.mark.slow
def test_campaign_sweep_identical_on_dask(tmp_path, dask_client):
    pytest.importorskip("gonio.campaign")
    spec = sweep.spec_from_dict(
        {
            "task": "campaign",
            "materials": ["rolled_brass"],
            "seeds": 1,
            "settings": {"mirror": ["ellipsoid", "hemisphere"]},
            "fixed": {"theta_i_deg": [30.0], "preset": "ideal"},
        }
    )
    a, _ = _inprocess_and_dask_agree(spec, tmp_path, dask_client)
    for r in a.rows:
        assert r["converged"] and r["max_rel_err"] < 0.05 and r["rms_log_brdf"] < 0.05
        # the campaign's own results directory is intact beside the sweep's record
        d = tmp_path / "a" / "tasks" / r["task_id"]
        assert (d / "summary.json").is_file() and (d / sweep.SUMMARY).is_file()
        assert (d / "samples.csv").is_file()


def test_dask_workers_lost_twice_in_a_row(tmp_path, dask_client):
    # two worker deaths in a row (the cluster restarts them between sweeps) cost only the
    # tasks that died: the re-run finds the first sweep's results and submits nothing
    for k in range(2):
        state = tmp_path / f"state{k}"
        state.mkdir()
        spec = _custom_spec(state, modes=("die_once",), seeds=[10 * k, 10 * k + 1])
        res = sweep.run_sweep(
            spec, tmp_path / f"out{k}", executor="dask", client=dask_client, fn=counting_task
        )
        assert [r["value"] for r in res.rows] == [15.0 * k, 15.0 * k + 1.5]
        assert all(_runs(state, sweep.task_id(t)) == 2 for t in sweep.expand(spec))
    again = sweep.run_sweep(
        spec, tmp_path / "out1", executor="dask", client=dask_client, fn=counting_task
    )
    assert again.n_run == 0 and again.n_skipped == 2
    assert all(_runs(state, sweep.task_id(t)) == 2 for t in sweep.expand(spec))


def test_dask_without_workers_fails_instead_of_hanging(tmp_path):
    distributed = pytest.importorskip("distributed")
    state = tmp_path / "state"
    state.mkdir()
    spec = _custom_spec(state, seeds=2)
    cluster = distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=":0")
    try:
        with distributed.Client(cluster) as client:
            t0 = time.perf_counter()
            with pytest.raises(sweep.TaskFailed, match=r"no Dask worker for 1 s") as exc:
                sweep.run_sweep(
                    spec,
                    tmp_path / "out",
                    executor="dask",
                    client=client,
                    fn=counting_task,
                    retries=0,
                    no_workers_timeout=1.0,
                    plot=False,
                )
            assert time.perf_counter() - t0 < 30
            assert len(exc.value.failures) == 2 and exc.value.result.rows == []
            assert client.processing() == {} and not list(state.iterdir())
    finally:
        cluster.close()
    with pytest.raises(ValueError, match="no_workers_timeout must be > 0"):
        sweep.run_sweep(spec, tmp_path / "x", no_workers_timeout=0)


def test_dask_local_cluster_settings_and_environment():
    pytest.importorskip("distributed")
    import dask

    before = dict(os.environ)
    with sweep.dask_local_cluster(1) as client:
        assert dask.config.get("distributed.deploy.lost-worker-timeout") == "7 days"
        env = client.run(lambda: dict(os.environ))
        (wenv,) = env.values()
        # workers: one BLAS thread, glibc's default heap (no MALLOC_TRIM_THRESHOLD_)
        assert wenv["OMP_NUM_THREADS"] == "1" and "MALLOC_TRIM_THRESHOLD_" not in wenv
    assert dict(os.environ) == before  # the nanny's pre-spawn environment did not leak here
    with pytest.raises(ValueError, match="n_workers must be >= 1"):
        with sweep.dask_local_cluster(0):
            pass


def test_task_malloc_guard_in_dask_like_worker(monkeypatch):
    # inside a worker started with Dask's MALLOC_TRIM_THRESHOLD_ the guard sets and restores
    # glibc's thresholds (mallopt returns 1 on success); outside one it does nothing
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    with sweep._TaskMalloc() as g:
        assert g._libc is None
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "65536")
    with sweep._TaskMalloc() as g:
        x = np.ones(1_000_000).sum()
    assert x == 1e6
    if sys.platform.startswith("linux"):
        assert g._libc is not None and g._libc[2] == 65536


def test_a_spec_imports_no_module_it_names(tmp_path):
    import subprocess

    spec = tmp_path / "s.toml"
    spec.write_text('task = "this:s"\nmaterials = ["rolled_brass"]\nseeds = 1\n')
    code = "import sys; from gonio.cli import main; sys.exit(main(sys.argv[1:]))"
    p = subprocess.run([sys.executable, "-P", "-c", code, "sweep", str(spec), "--dry-run"],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert p.returncode == 2 and "unknown task 'this:s'" in p.stderr
    assert "Beautiful is better than ugly" not in p.stdout  # `import this` prints the Zen


def test_dask_local_cluster_listens_on_loopback_only():
    pytest.importorskip("distributed")
    psutil = pytest.importorskip("psutil")
    with sweep.dask_local_cluster(1) as client:
        assert client.dashboard_link.startswith("http://127.0.0.1:")
        conns = psutil.Process().net_connections("tcp")
        hosts = {c.laddr.ip for c in conns if c.status == psutil.CONN_LISTEN}
    assert hosts == {"127.0.0.1"}


def test_campaign_sweep_keeps_no_raw_frames_unless_asked(tmp_path):
    """A sweep's campaigns keep no raw frames by default (the spec's ``raw``, or ``raw=``,
    can keep or compress them); the results are the same either way, and a finished task is
    recognised on a re-run without its frames."""
    pytest.importorskip("gonio.campaign")
    spec = sweep.spec_from_dict(
        {
            "task": "campaign",
            "materials": ["rolled_brass"],
            "seeds": 1,
            "fixed": {"theta_i_deg": [30.0], "preset": "ideal"},
        }
    )
    assert spec.raw == "none" and spec.to_dict()["raw"] == "none"
    a = sweep.run_sweep(spec, tmp_path / "a", plot=False)
    (tid,) = [r["task_id"] for r in a.rows]
    da = tmp_path / "a" / "tasks" / tid
    assert (da / "samples.csv").is_file() and not (da / "raw").exists()
    rec = json.loads((da / sweep.SUMMARY).read_text())
    assert rec["raw"] == "none" and 0 < rec["disk_bytes"] < 5e6
    again = sweep.run_sweep(spec, tmp_path / "a", plot=False, raw="keep")
    assert (again.n_run, again.n_skipped) == (0, 1) and not (da / "raw").exists()

    kept = sweep.spec_from_dict({**spec.to_dict(), "raw": "keep"})
    b = sweep.run_sweep(kept, tmp_path / "b", plot=False)
    db = tmp_path / "b" / "tasks" / tid
    frames = sum(f.stat().st_size for f in (db / "raw").rglob("*.tif"))
    rec_b = json.loads((db / sweep.SUMMARY).read_text())
    assert rec_b["raw"] == "keep" and rec_b["disk_bytes"] >= rec["disk_bytes"] + frames > 0
    sweep.run_sweep(spec, tmp_path / "c", plot=False, raw="compressed")
    dc = tmp_path / "c" / "tasks" / tid
    assert 0 < sum(f.stat().st_size for f in (dc / "raw").rglob("*.tif")) < frames
    for name in ("samples.csv",):  # the campaign's results do not depend on what it keeps
        assert (da / name).read_bytes() == (db / name).read_bytes() == (dc / name).read_bytes()
    strip = [{k: v for k, v in r.items() if k != "wall_s"} for r in a.rows]
    assert strip == [{k: v for k, v in r.items() if k != "wall_s"} for r in b.rows]
    with pytest.raises(ValueError, match="raw must be one of keep, compressed, none"):
        sweep.run_sweep(spec, tmp_path / "d", raw="all")


_ORPHAN_SCRIPT = """
import os, sys, time
from gonio.campaign.sweep import register_task, run_sweep, spec_from_dict

def sleepy(task, out_dir):
    (out_dir.parent.parent / f"pid-{os.getpid()}").write_text("")
    time.sleep(60)
    return {"x": 1.0}

register_task("sleepy_orphan", sleepy, metric="x")
spec = spec_from_dict({"name": "o", "task": "sleepy_orphan", "materials": ["-"],
                       "seeds": [0, 1, 2, 3]})
run_sweep(spec, sys.argv[1], executor="process", workers=2, plot=False)
"""


def test_process_workers_end_with_a_killed_parent(tmp_path):
    """A script calling run_sweep killed by a signal it does not handle: its workers end
    too (they were left waiting on the pool's queue forever, re-parented to init)."""
    import signal
    import subprocess
    import sys
    import time

    script = tmp_path / "orphan.py"
    script.write_text(_ORPHAN_SCRIPT)
    root = tmp_path / "root"
    proc = subprocess.Popen([sys.executable, str(script), str(root)], cwd=tmp_path)
    try:
        t0 = time.monotonic()
        while len(list(root.glob("pid-*"))) < 2 and time.monotonic() - t0 < 60:
            time.sleep(0.1)
        pids = [int(p.name[4:]) for p in root.glob("pid-*")]
        assert len(pids) == 2, "the workers did not start"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()

    def alive(pid: int) -> bool:
        try:
            with open(f"/proc/{pid}/stat") as f:
                return f.read().split()[2] != "Z"
        except FileNotFoundError:
            return False

    t0 = time.monotonic()
    while any(alive(p) for p in pids) and time.monotonic() - t0 < 10:
        time.sleep(0.1)
    left = [p for p in pids if alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert not left, f"workers {left} outlived their parent"
