"""Model bundles: written, read back whole (physics model, torch weights, reports), verified
by their digests, and refused when the format, a version or a file is not what was written."""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from wrenchd.adapters.bundle import (
    FORMAT, bundle_digest, check_data, file_sha256, read_bundle, write_bundle,
)
from wrenchd.adapters.csv_psm import read_wpi_csv, write_paper_csv
from wrenchd.adapters.rosbag import write_joint_states_bag
from wrenchd.models.errors import AdapterError, ConfigError, DataError
from wrenchd.models.physics.model import PhysicsModel


class Opaque:
    """Not a tensor: a pickled instance of it must never be loaded."""


@pytest.fixture
def data_files(tmp_path, wpi_data):
    js, _ = read_wpi_csv(wpi_data / "two.csv")
    csv = tmp_path / "inputs" / "two.csv"
    csv.parent.mkdir()
    write_paper_csv(csv, js.slice(0, 400))
    bag = write_joint_states_bag(tmp_path / "inputs" / "session_bag", js.slice(0, 200))
    return [csv, bag]


def _write(path: Path, files, **extra):
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(12, 8), torch.nn.Tanh(), torch.nn.Linear(8, 6))
    values = dict(arm="PSM1", origin="robot", physics=PhysicsModel().to_dict(),
                  report_md="# Fit\n\nheld-out RMS per joint\n",
                  report={"heldout_rms": np.array([0.1, 0.2, 0.3, 0.01, 0.02, 0.03]),
                          "samples": np.int64(5999)},
                  data_files=files, weights=net.state_dict(),
                  weights_config={"layers": [12, 8, 6]})
    values.update(extra)
    return write_bundle(path, **values), net


def test_round_trip(tmp_path, data_files):
    bundle, net = _write(tmp_path / "psm1", data_files, created_utc="2025-01-02T03:04:05Z")
    again = read_bundle(tmp_path / "psm1")
    assert again == bundle
    assert (again.arm, again.origin, again.created_utc) == ("PSM1", "robot", "2025-01-02T03:04:05Z")
    assert again.wrenchd_version == importlib.metadata.version("wrenchd")
    assert again.report == {"heldout_rms": [0.1, 0.2, 0.3, 0.01, 0.02, 0.03], "samples": 5999}
    assert again.report_md.startswith("# Fit")
    assert again.data == {"two.csv": hashlib.sha256(data_files[0].read_bytes()).hexdigest(),
                          "session_bag": file_sha256(data_files[1])}
    # the physics model rebuilds and predicts the same torques
    model = PhysicsModel.from_dict(again.physics)
    rng = np.random.default_rng(0)
    q = rng.uniform(-0.5, 0.5, (5, 6))
    q[:, 2] = 0.1
    dq, ddq = rng.normal(0, 0.3, (2, 5, 6))
    t = np.arange(5) * 0.005
    np.testing.assert_array_equal(model.torque(model.motion(t, q, dq, ddq)),
                                  PhysicsModel().torque(PhysicsModel().motion(t, q, dq, ddq)))
    # the weights load into a fresh network and give the same outputs
    clone = torch.nn.Sequential(torch.nn.Linear(12, 8), torch.nn.Tanh(), torch.nn.Linear(8, 6))
    clone.load_state_dict(again.weights)
    x = torch.randn(4, 12)
    assert torch.equal(clone(x), net(x))
    assert again.weights_config == {"layers": [12, 8, 6]}


def test_digest_covers_every_file(tmp_path, data_files):
    bundle, _ = _write(tmp_path / "b", data_files)
    files = sorted(p for p in (tmp_path / "b").iterdir())
    assert [p.name for p in files] == ["manifest.json", "physics.json", "report.json",
                                      "report.md", "step1.pt"]
    lines = "".join(f"{p.name}\0{hashlib.sha256(p.read_bytes()).hexdigest()}\n" for p in files)
    assert bundle.digest == hashlib.sha256(lines.encode()).hexdigest() == bundle_digest(
        tmp_path / "b")
    manifest = json.loads((tmp_path / "b" / "manifest.json").read_text())
    assert manifest["format"] == FORMAT and manifest["version"] == 1
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", manifest["created_utc"])
    other, _ = _write(tmp_path / "c", data_files, origin="simulator")
    assert other.digest != bundle.digest and other.origin == "simulator"


def test_without_weights(tmp_path, data_files):
    bundle, _ = _write(tmp_path / "b", data_files[:1], weights=None, weights_config=None)
    assert bundle.weights is None and not (tmp_path / "b" / "step1.pt").exists()
    assert read_bundle(tmp_path / "b").weights is None


def test_check_data(tmp_path, data_files):
    bundle, _ = _write(tmp_path / "b", data_files)
    check_data(bundle, data_files)
    with pytest.raises(DataError, match="is not among the data"):
        check_data(bundle, [Path(__file__)])
    data_files[0].write_text(data_files[0].read_text().replace("0.", "1.", 1))
    with pytest.raises(DataError, match="two.csv: sha256 .* differs"):
        check_data(bundle, data_files)


def _edit_manifest(path: Path, change) -> None:
    manifest = json.loads((path / "manifest.json").read_text())
    change(manifest)
    (path / "manifest.json").write_text(json.dumps(manifest))


@pytest.mark.parametrize("change, pattern", [
    (lambda m: m.pop("version"), "no format version; this wrenchd reads version 1"),
    (lambda m: m.update(version=2), "format version 2 is unknown"),
    (lambda m: m.update(format="wrenchd.physics/1"), "format is 'wrenchd.physics/1'"),
    (lambda m: m.update(origin="lab"), "origin 'lab' is not one of"),
    (lambda m: m.update(data={}), "records no data files"),
    (lambda m: m.pop("files"), "missing \\['files'\\]"),
])
def test_bad_manifest_is_refused(tmp_path, data_files, change, pattern):
    _write(tmp_path / "b", data_files)
    _edit_manifest(tmp_path / "b", change)
    with pytest.raises(ConfigError, match=pattern):
        read_bundle(tmp_path / "b")


def test_changed_missing_or_extra_files_are_refused(tmp_path, data_files):
    path = tmp_path / "b"
    _write(path, data_files)
    physics = json.loads((path / "physics.json").read_text())
    physics["description"] = "edited by hand"
    (path / "physics.json").write_text(json.dumps(physics))
    with pytest.raises(ConfigError, match="physics.json has sha256 .* the file changed"):
        read_bundle(path)
    (path / "physics.json").unlink()
    with pytest.raises(ConfigError, match=r"\['physics.json'\] listed in the manifest but missing"):
        read_bundle(path)
    path2 = tmp_path / "c"
    _write(path2, data_files)
    (path2 / "notes.txt").write_text("x")
    with pytest.raises(ConfigError, match=r"\['notes.txt'\] not listed in the manifest"):
        read_bundle(path2)
    with pytest.raises(ConfigError, match="has no manifest.json"):
        read_bundle(tmp_path)
    with pytest.raises(AdapterError, match="no bundle directory"):
        read_bundle(tmp_path / "absent")


def test_pickled_object_in_weights_is_never_loaded(tmp_path, data_files):
    path = tmp_path / "b"
    _write(path, data_files)
    torch.save({"layer.weight": Opaque()}, path / "step1.pt")
    _edit_manifest(path, lambda m: m["files"].update({"step1.pt": file_sha256(path / "step1.pt")}))
    with pytest.raises(ConfigError, match="step1.pt is not a plain state dict"):
        read_bundle(path)


@pytest.mark.parametrize("extra, error, pattern", [
    ({"origin": "lab"}, DataError, "origin must be one of"),
    ({"arm": "PSM 1"}, DataError, "arm must be a name like 'PSM1'"),
    ({"report": {"rms": float("nan")}}, DataError, "report must be JSON-serialisable"),
    ({"physics": [1, 2]}, DataError, "physics must be a JSON object"),
    ({"data_files": []}, DataError, "give data_files"),
    ({"weights": {"w": [1.0]}}, ConfigError, "must be a state dict"),
    ({"weights": None}, DataError, "weights_config given without weights"),
])
def test_bad_content_is_refused_on_writing(tmp_path, data_files, extra, error, pattern):
    with pytest.raises(error, match=pattern):
        _write(tmp_path / "b", data_files, **extra)
    assert not (tmp_path / "b").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".b-")]


def test_existing_path_and_missing_data_are_refused(tmp_path, data_files):
    (tmp_path / "taken").mkdir()
    with pytest.raises(AdapterError, match="exists"):
        _write(tmp_path / "taken", data_files)
    with pytest.raises(AdapterError, match="does not exist"):
        _write(tmp_path / "b", [tmp_path / "nowhere.csv"])
