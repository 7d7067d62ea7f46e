"""The plot worker a command begins before its campaign (plot_worker.started_early)."""

from gonio.campaign.executor import CampaignExecutor
from gonio.campaign.plot_worker import _EARLY, adopt, started_early


def _write(name, path):
    with open(path, "a", encoding="utf-8") as f:
        f.write(name + ";")


def test_the_executor_adopts_the_early_worker_and_draws_there(tmp_path):
    log = tmp_path / "log"
    with started_early(True):
        early = _EARLY[0]
        with CampaignExecutor(2, plots=True) as ex:
            assert ex._plotter is early and not _EARLY  # adopted, not forked again
            ex.plot(_write, log, each=["a", "b"])
            ex.wait_plots()
        assert not early._proc.is_alive()  # closed by the executor
    assert sorted(log.read_text().split(";")) == ["", "a", "b"]


def test_an_early_worker_not_adopted_is_stopped():
    with started_early(True):
        proc = _EARLY[0]._proc
        with CampaignExecutor(1, plots=True) as ex:  # one worker: plots drawn here
            assert ex._plotter is None
    assert not proc.is_alive() and not _EARLY
    with started_early(False):
        assert adopt() is None
