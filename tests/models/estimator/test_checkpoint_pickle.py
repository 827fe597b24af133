"""A checkpoint in torch's own zip format whose pickle would run code is refused unexecuted.

``test_training.test_tampered_checkpoints_are_refused`` covers a bare (legacy) pickle; a file
written by ``torch.save`` takes torch's other loader path (zip archive, ``data.pkl`` inside),
which is how a tampered ``.pt`` found on the web or swapped in a models directory looks.
"""

import os

import pytest
import torch

from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.checkpoint import load_checkpoint


class _RunsOnLoad:
    """Unpickling this calls os.system: what a malicious checkpoint would carry."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.mark.parametrize("where", ["top", "state_dict"])
def test_zip_checkpoint_with_code_is_refused(tmp_path, where):
    marker = tmp_path / "executed"
    evil = tmp_path / "evil.pt"
    payload = {"format": "wrenchd.estimator", "version": 1, "kind": "free_space",
               "state_dict": {"w": torch.zeros(2)}}
    if where == "top":
        payload["config"] = _RunsOnLoad(marker)
    else:
        payload["state_dict"] = {"w": _RunsOnLoad(marker)}
    torch.save(payload, evil)
    assert not marker.exists()
    # the same file does run code through a plain unpickling load: the test is meaningful
    torch.load(evil, weights_only=False)
    assert marker.exists()
    marker.unlink()
    with pytest.raises(ConfigError, match="refused"):
        load_checkpoint(evil)
    assert not marker.exists()
