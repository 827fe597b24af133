"""Step-1 training resumed from its checkpoint: a run stopped at any epoch (here by SIGKILL,
in a real subprocess) and started again ends with the weights of a run that never stopped."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

import pytest
import torch

from wrenchd.models.errors import DataError
from wrenchd.models.estimator.free_space import FreeSpaceConfig
from wrenchd.models.estimator.free_space_training import fit_free_space
from wrenchd.models.estimator.training import recipe

SMALL = FreeSpaceConfig(hidden_size=8, seal_hidden_size=8)


def _recipe(epochs: int, **kw):
    return recipe("free-space", epochs=epochs, window=20, lane_windows=2, batch_size=8,
                  seed=7, lr_halving_epochs=2, patience=None, **kw)


def _same_weights(a, b) -> None:
    sa, sb = a.model.state_dict(), b.model.state_dict()
    assert sa.keys() == sb.keys()
    for k in sa:
        assert torch.equal(sa[k], sb[k]), k


@pytest.fixture(scope="module")
def series(free_space_session):
    return [free_space_session.joint_states.slice(0, 2000)]


def test_a_run_resumed_at_its_checkpoint_ends_as_one_that_never_stopped(series, tmp_path):
    torch.set_num_threads(1)
    straight = fit_free_space(series, SMALL, _recipe(5))
    path = tmp_path / "step1.pt"
    first = fit_free_space(series, SMALL, _recipe(2), checkpoint=path)
    assert first.validation["epochs_run"] == 2 and path.is_file()
    # a higher epoch ceiling goes on from the third epoch (the schedule halves at 2 and 4)
    resumed = fit_free_space(series, SMALL, _recipe(5), checkpoint=path)
    assert resumed.history == straight.history and len(resumed.history) == 5
    _same_weights(resumed, straight)
    # started again at its ceiling, it only rebuilds the result
    again = fit_free_space(series, SMALL, _recipe(5), checkpoint=path)
    assert again.history == straight.history
    _same_weights(again, straight)
    # its training time is the epochs' of both sittings, not the rebuild's
    spent = [r.validation["train_seconds"] for r in (first, resumed, again)]
    assert 0.0 < spent[0] < spent[1] == spent[2]


def test_a_run_stopped_early_stays_stopped_and_another_runs_file_is_refused(series, tmp_path):
    torch.set_num_threads(1)
    path = tmp_path / "step1.pt"
    # patience 1: stops at the first epoch that improves no group (or at the ceiling)
    first = fit_free_space(series, SMALL, _recipe(40, lr=0.5).model_copy(
        update={"patience": 1}), checkpoint=path)
    assert first.validation["epochs_run"] < 40
    again = fit_free_space(series, SMALL, _recipe(40, lr=0.5).model_copy(
        update={"patience": 1}), checkpoint=path)
    assert again.history == first.history
    with pytest.raises(DataError, match="another training run"):
        fit_free_space(series, SMALL, _recipe(40).model_copy(update={"seed": 8}),
                       checkpoint=path)
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(DataError, match="not a readable training checkpoint"):
        fit_free_space(series, SMALL, _recipe(3), checkpoint=tmp_path / "junk.pt")


def _training_process(tmp_path, epochs: int, stop_request: bool):
    """A subprocess training a small step-1 net to ``epochs`` with a checkpoint, writing each
    finished epoch to a marker file and pausing after it (room for a signal to land
    mid-run); with ``stop_request``, under the command line's stop handling, each epoch ends
    with the reproduction's stop check and a stop exits 128 + the signal. Returns the
    process, the checkpoint and the marker, once two epochs are saved."""
    path, marker = tmp_path / "step1.pt", tmp_path / "epochs.txt"
    check = "stop_between_epochs(epoch, loss)" if stop_request else "pass"
    script = textwrap.dedent(f"""
        import sys, time, torch
        torch.set_num_threads(1)
        from wrenchd.adapters.sim.scenarios import run_scenario
        from wrenchd.models.estimator.free_space import FreeSpaceConfig
        from wrenchd.models.estimator.free_space_training import fit_free_space
        from wrenchd.models.estimator.training import recipe
        from wrenchd.service.runtime.stopping import StopSignals, Stopped
        from wrenchd.service.studies.reproduction_training import stop_between_epochs
        js = run_scenario("free-space", 60.0, 1).joint_states.slice(0, 2000)
        cfg = recipe("free-space", epochs={epochs}, window=20, lane_windows=2, batch_size=8,
                     seed=7, lr_halving_epochs=2, patience=None)
        def on_epoch(epoch, loss):
            open({str(marker)!r}, "a").write(f"{{epoch}}\\n")
            time.sleep(0.4)
            {check}
        try:
            with StopSignals():
                fit_free_space([js], FreeSpaceConfig(hidden_size=8, seal_hidden_size=8), cfg,
                               on_epoch=on_epoch, checkpoint={str(path)!r})
        except Stopped as stop:
            sys.exit(128 + stop.signum)
        """)
    proc = subprocess.Popen([sys.executable, "-c", script])
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if marker.is_file() and len(marker.read_text().split()) >= 2:
            return proc, path, marker
        if proc.poll() is not None:
            pytest.fail(f"the training process ended early ({proc.returncode})")
        time.sleep(0.05)
    proc.kill()
    pytest.fail("the training process saved no two epochs in 120 s")


def test_a_killed_training_process_resumes_where_it_stopped(series, tmp_path):
    """SIGKILL a training subprocess after its second epoch's checkpoint; train again here
    from the file: the weights of an uninterrupted run."""
    torch.set_num_threads(1)
    proc, path, marker = _training_process(tmp_path, 6, stop_request=False)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    done = len(marker.read_text().split())
    assert 2 <= done < 6
    resumed = fit_free_space(series, SMALL, _recipe(6), checkpoint=path)
    straight = fit_free_space(series, SMALL, _recipe(6))
    assert resumed.history == straight.history
    _same_weights(resumed, straight)


def test_sigterm_stops_a_training_after_its_saved_epoch_and_it_resumes(series, tmp_path):
    """SIGTERM to a training run as the paper-scale reproduction runs it (the command's stop
    request, checked after each saved epoch): it exits with 128 + 15 at once, the checkpoint
    holds every epoch it began, and training again from the file ends as an unbroken run."""
    torch.set_num_threads(1)
    proc, path, marker = _training_process(tmp_path, 40, stop_request=True)
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=30)
    assert proc.returncode == 128 + signal.SIGTERM
    done = len(marker.read_text().split())
    assert 2 <= done < 40
    resumed = fit_free_space(series, SMALL, _recipe(done + 2), checkpoint=path)
    straight = fit_free_space(series, SMALL, _recipe(done + 2))
    assert len(resumed.history) == done + 2
    assert resumed.history == straight.history
    _same_weights(resumed, straight)
