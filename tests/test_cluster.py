"""Runs on a Ray cluster (``cluster.py``, docs/cluster.md): the Ray checks of ``ray_cases.py``
in a private network namespace, and what needs no Ray (retried jobs resume, the error without
Ray, local runs that never import it).

Ray binds to the machine's network address even when asked for 127.0.0.1, so it is started
only inside ``unshare -n`` with loopback up. Where that is not permitted the check skips with
the reason, unless ``SLUNGLOAD_RAY_TESTS=required`` (the README's test command, hence CI): then
it fails, so CI cannot pass without running them.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from flights import SMALL, TINY

from slungload.lab.reproduce import TrainingJob
from slungload.run_config import RunConfig

HERE = Path(__file__).parent
REQUIRED = os.environ.get("SLUNGLOAD_RAY_TESTS") == "required"


def _why_not() -> str | None:
    """Why Ray cannot run here in a private network, or None."""
    try:
        import ray  # noqa: F401
    except ImportError:
        return "Ray is not installed (pip install 'slungload[cluster]')"
    if shutil.which("unshare") is None:
        return "no unshare command"
    probe = subprocess.run(["unshare", "-n", "sh", "-c", "ip link set lo up"],
                           capture_output=True, text=True)  # fmt: skip
    if probe.returncode != 0:
        return f"unshare -n is not permitted here: {probe.stderr.strip()[:200]}"
    return None


@pytest.mark.slow
def test_ray_checks_pass_in_a_private_loopback_network(tmp_path):
    why = _why_not()
    if why is not None:
        if REQUIRED:
            pytest.fail(f"SLUNGLOAD_RAY_TESTS=required, but {why}")
        pytest.skip(why)
    # PYTHONPATH: the workers Ray starts import the test module's functions by name.
    inner = (f"ip link set lo up && RAY_USAGE_STATS_ENABLED=0 PYTHONPATH={HERE} "
             f"{sys.executable} -m pytest -q "
             f"-p no:cacheprovider --rootdir {HERE.parent} --basetemp {tmp_path / 'base'} "
             f"{HERE / 'ray_cases.py'}")  # fmt: skip
    done = subprocess.run(["unshare", "-n", "sh", "-c", inner], capture_output=True, text=True,
                          cwd=HERE.parent, timeout=900)  # fmt: skip
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
    assert " passed" in done.stdout and "skipped" not in done.stdout, done.stdout[-2000:]


def test_a_retried_training_job_resumes_from_its_last_checkpoint(tiny_run, tmp_path):
    # As a cluster retries a task whose worker died: the run folder holds last.ckpt, the job
    # was made before it existed (resume False), and it continues instead of refusing.
    run = RunConfig.from_preset(preset="quick", model=TINY, window=SMALL, max_epochs=1)
    out = tmp_path / "run"
    TrainingJob(tiny_run.data, out, run)()
    result = TrainingJob(tiny_run.data, out, RunConfig.from_preset(
        preset="quick", model=TINY, window=SMALL, max_epochs=2))()  # fmt: skip
    assert result.epochs == 2
    assert json.loads((out / "run.json").read_text())["epochs"] == 2


def test_without_ray_a_cluster_is_a_clear_error_and_local_runs_never_import_it():
    code = (
        "import sys\n"
        "sys.modules['ray'] = None  # as if it were not installed\n"
        "from slungload.workers import run_jobs\n"
        "assert list(run_jobs(abs, [-1, -2], workers=1, progress=False)) == [1, 2]\n"
        "try:\n"
        "    list(run_jobs(abs, [-1], workers=1, progress=False, cluster='auto'))\n"
        "except ValueError as exc:\n"
        "    assert \"pip install 'slungload[cluster]'\" in str(exc), exc\n"
        "else:\n"
        "    raise AssertionError('no error')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    code = (
        "import sys\nfrom slungload.lab.reproduce import run_training_jobs\n"
        "run_training_jobs([], workers=1, progress=False)\nassert 'ray' not in sys.modules\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]


def test_an_unreachable_cluster_is_refused_before_any_work(monkeypatch, run_cli, tmp_path):
    # ``--cluster auto`` with no cluster running: one line and exit 2 before the simulator runs
    # (it used to simulate for a minute, then die with Ray's ConnectionError). The connection
    # attempt is replaced, so no Ray starts here.
    pytest.importorskip("ray")
    import slungload.cluster as cluster

    def unreachable(address: str) -> bool:
        raise ConnectionError("Could not find any running Ray instance.")

    monkeypatch.setattr(cluster, "connect", unreachable)
    code, _, err = run_cli("reproduce", "--out", tmp_path / "o", "--cluster", "auto",
                           "--preset", "quick", "--quiet")  # fmt: skip
    assert code == 2 and "--cluster auto: no Ray cluster reachable" in err
    assert not (tmp_path / "o" / "data").exists()
    code, _, err = run_cli("study", "data", "--out", tmp_path / "d", "--cluster", "auto")
    assert code == 2 and "no Ray cluster reachable" in err and not (tmp_path / "d").exists()
    cluster.check_reachable(None)  # nothing asked: nothing checked
    cluster.check_reachable(cluster.LOCAL)  # started by the command itself
